from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import SimError
from quadnav.messages import PositionSample, VehicleState
from quadnav.sim import DelayLine, ImuSensor, PositionSensor
from quadnav.units import GRAVITY_M_S2


def state(
    *, theta: float = 0.0, a=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0), p=(0.0, 0.0, 0.0)
) -> VehicleState:
    return VehicleState(
        t_ns=0,
        p_W_B=np.array(p),
        v_W_B=np.zeros(3),
        a_W_B=np.array(a),
        q_W_B_xyzw=Rotation.from_euler("y", theta).as_quat(),
        w_B=np.array(w),
    )


def test_specific_force_reads_plus_g_at_rest_and_kinematic_reads_zero() -> None:
    rng = np.random.default_rng(0)
    real = ImuSensor(accel_sigma_m_s2=0.0, gyro_sigma_rad_s=0.0, gravity_m_s2=9.81)
    kin = ImuSensor(accel_sigma_m_s2=0.0, gyro_sigma_rad_s=0.0, accel_model="kinematic")
    np.testing.assert_allclose(real.sample(state(), 0, rng).accel_m_s2, [0, 0, 9.81], atol=1e-12)
    np.testing.assert_allclose(kin.sample(state(), 0, rng).accel_m_s2, [0, 0, 0], atol=1e-12)


def test_tilted_accelerometer_sees_gravity_in_body_axes() -> None:
    """Pitched by +theta about +y at rest: f_B = R^T (0, 0, g) = (-g sin, 0, g cos)."""
    imu = ImuSensor(accel_sigma_m_s2=0.0, gyro_sigma_rad_s=0.0, gravity_m_s2=9.8)
    f = imu.sample(state(theta=0.4, w=(0.0, 0.2, 0.0)), 0, np.random.default_rng(0))
    np.testing.assert_allclose(
        f.accel_m_s2, [-9.8 * np.sin(0.4), 0.0, 9.8 * np.cos(0.4)], atol=1e-12
    )
    np.testing.assert_allclose(f.gyro_rad_s, [0.0, 0.2, 0.0], atol=1e-12)


def test_imu_noise_has_the_configured_spread() -> None:
    imu = ImuSensor(accel_sigma_m_s2=0.25, gyro_sigma_rad_s=0.03)
    rng = np.random.default_rng(1)
    s = [imu.sample(state(), 0, rng) for _ in range(4000)]
    acc = np.array([x.accel_m_s2 for x in s])
    gyr = np.array([x.gyro_rad_s for x in s])
    # 4000 samples: the sample std is within ~3% of sigma with overwhelming probability.
    np.testing.assert_allclose(acc.std(axis=0), 0.25, rtol=0.06)
    np.testing.assert_allclose(gyr.std(axis=0), 0.03, rtol=0.06)
    np.testing.assert_allclose(acc.mean(axis=0), [0, 0, 9.8], atol=0.02)


def test_same_seed_same_noise() -> None:
    imu = ImuSensor(accel_sigma_m_s2=0.25, gyro_sigma_rad_s=0.03)
    a = imu.sample(state(), 0, np.random.default_rng(5)).accel_m_s2
    b = imu.sample(state(), 0, np.random.default_rng(5)).accel_m_s2
    np.testing.assert_array_equal(a, b)


def test_position_sensor_period_not_a_multiple_of_the_step() -> None:
    gps = PositionSensor(sigma_m=0.01, period_ns=25_000_000)  # 25 ms on a 10 ms step
    rng = np.random.default_rng(0)
    times = [
        t for t in range(0, 200_000_001, 10_000_000) if gps.sample(state(), t, rng) is not None
    ]
    # Due at 0, 25, 50, 75... ms: taken at the first step at or after each due time.
    assert times[:5] == [0, 30_000_000, 50_000_000, 80_000_000, 100_000_000]
    assert len(times) == 9


def test_delay_line_releases_in_arrival_order_with_jitter() -> None:
    line: DelayLine[PositionSample] = DelayLine(delay_ns=1_000, jitter_ns=5_000)
    rng = np.random.default_rng(3)
    arrivals = []
    for t in range(0, 100_000, 1_000):
        arrivals.append(line.push(PositionSample(t_ns=t, p_W_B=[0, 0, 0], sigma_m=1.0), rng))
    out = line.pop_arrived(10**9)
    got = [a for a, _ in out]
    assert got == sorted(arrivals)
    valid = [s.t_ns for _, s in out]
    assert valid != sorted(valid), "jitter this large must reorder some samples"
    assert all(a - s.t_ns >= 1_000 for a, s in out)
    assert line.pop_arrived(10**9) == []


def test_delay_line_holds_until_due() -> None:
    line: DelayLine[PositionSample] = DelayLine(delay_ns=255)
    line.push(PositionSample(t_ns=100, p_W_B=[0, 0, 0], sigma_m=1.0))
    assert line.pop_arrived(354) == []
    assert [a for a, _ in line.pop_arrived(355)] == [355]


def test_bad_sensor_settings() -> None:
    with pytest.raises(SimError):
        DelayLine(delay_ns=-1)
    with pytest.raises(SimError):
        PositionSensor(sigma_m=0.0, period_ns=1)
    with pytest.raises(SimError):
        ImuSensor(accel_sigma_m_s2=-1.0, gyro_sigma_rad_s=0.0)
    with pytest.raises(SimError, match="rng"):
        DelayLine(delay_ns=0, jitter_ns=10).push(
            PositionSample(t_ns=0, p_W_B=[0, 0, 0], sigma_m=1.0)
        )


def _state(t_ns: int, p, yaw: float = 0.0, roll: float = 0.0, w=(0.0, 0.0, 0.0)) -> VehicleState:
    return VehicleState(
        t_ns=t_ns,
        p_W_B=np.asarray(p, dtype=float),
        v_W_B=np.zeros(3),
        a_W_B=np.zeros(3),
        q_W_B_xyzw=Rotation.from_euler("ZYX", [yaw, 0.0, roll]).as_quat(),
        w_B=np.asarray(w, dtype=float),
    )


def test_vision_pose_is_expressed_in_its_rotated_offset_frame_and_jumps_bump_the_counter() -> None:
    from quadnav.sim.channels import Dropouts, FrameJump, FrameJumps
    from quadnav.sim.sensors import VisionPoseSensor

    pose = VisionPoseSensor(
        period_ns=10, sigma_m=1e-9, yaw_sigma_rad=1e-9, frame_yaw_rad=np.pi / 2,
        frame_offset_m=(1.0, 2.0, 0.0),
    )  # fmt: skip
    jumps = FrameJumps(pose, [FrameJump(t_ns=300, yaw_rad=0.0, offset_m=(0.5, 0.0, 0.0))])
    sensor = Dropouts(jumps, [(100, 200)])
    rng = np.random.default_rng(0)
    s = sensor.sample(_state(0, [1.0, 3.0, 1.0], yaw=np.pi / 2), 0, rng)
    assert s is not None
    # world (1,3,1) is (0,1,1) from the frame origin; the frame's x points world north
    np.testing.assert_allclose(s.p_W_B, [1.0, 0.0, 1.0], atol=1e-6)
    assert abs(Rotation.from_quat(s.q_W_B_xyzw).as_euler("ZYX")[0]) < 1e-6
    assert s.reset_counter == 0
    assert sensor.sample(_state(150, [0, 0, 0]), 150, rng) is None  # dropout
    s2 = sensor.sample(_state(300, [1.0, 3.0, 1.0], yaw=np.pi / 2), 300, rng)
    assert s2 is not None and s2.reset_counter == 1
    np.testing.assert_allclose(s2.p_W_B, [0.5, 0.0, 1.0], atol=1e-6)


def test_range_finder_reads_along_the_tilted_body_axis_and_respects_its_span() -> None:
    from quadnav.sim.sensors import RangeFinder

    rf = RangeFinder(period_ns=1, sigma_m=1e-9, max_m=4.0, max_tilt_rad=0.5)
    rng = np.random.default_rng(0)
    s = rf.sample(_state(0, [0, 0, 2.0], roll=0.3), 0, rng)
    assert s is not None
    assert s.range_m == pytest.approx(2.0 / np.cos(0.3), abs=1e-6)
    assert rf.sample(_state(10, [0, 0, 5.0]), 10, rng) is None  # beyond max_m
    assert rf.sample(_state(20, [0, 0, 1.0], roll=0.6), 20, rng) is None  # too tilted


def test_barometer_drift_grows_like_a_random_walk() -> None:
    from quadnav.sim.sensors import BaroSensor

    finals = []
    for seed in range(200):
        b = BaroSensor(period_ns=40_000_000, sigma_m=1e-6, drift_m_sqrt_s=0.01)
        rng = np.random.default_rng(seed)
        for k in range(100):  # 4 s at 25 Hz
            s = b.sample(_state(k * 40_000_000, [0, 0, 1.0]), k * 40_000_000, rng)
        assert s is not None
        finals.append(s.z_m - 1.0)
    # after 4 s the offset's spread is 0.01 * sqrt(4) = 0.02 m
    assert np.std(finals) == pytest.approx(0.02, rel=0.15)


def test_imu_lever_arm_adds_the_centripetal_acceleration() -> None:
    from quadnav.sim.sensors import IntegratingImu

    imu = IntegratingImu(
        period_ns=4_000_000, gyro_sigma_rad_s=0.0, accel_sigma_m_s2=0.0, lever_arm_m=(0.1, 0.0, 0.0)
    )
    rng = np.random.default_rng(0)
    out = None
    for k in range(1, 5):  # spinning at a constant 2 rad/s about z
        out = imu.accumulate(_state(k * 1_000_000, [0, 0, 0], w=(0, 0, 2.0)), 1e-3, rng) or out
    assert out is not None
    # w x (w x r) = -|w|^2 r: 0.4 m/s^2 towards the centre, on top of gravity
    np.testing.assert_allclose(out.accel_m_s2, [-0.4, 0.0, GRAVITY_M_S2], atol=1e-9)


def test_a_delay_lines_next_arrival_follows_its_queue() -> None:
    """``next_arrival_ns`` (what a channel looks at each step) is the earliest queued arrival,
    after pushes out of order and pops, and later than any time once the line is empty."""
    line: DelayLine[PositionSample] = DelayLine(delay_ns=100)
    never = line.next_arrival_ns
    assert not line.due(2**62)

    def fix(t_ns: int) -> PositionSample:
        return PositionSample(t_ns=t_ns, p_W_B=np.zeros(3), sigma_m=0.1)

    line.push(fix(50))
    line.push(fix(20), extra_delay_ns=200)  # arrives at 320, after the first (150)
    line.push(fix(10))
    assert line.next_arrival_ns == 110 and line.due(110) and not line.due(109)
    assert [a for a, _ in line.pop_arrived(150)] == [110, 150]
    assert line.next_arrival_ns == 320
    assert [a for a, _ in line.pop_arrived(10_000)] == [320]
    assert line.next_arrival_ns == never and not line.pop_arrived(2**62)
