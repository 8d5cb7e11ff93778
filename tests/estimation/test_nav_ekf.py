from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import EstimationError
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig, nav_jacobians, yaw_jacobian, yaw_of

from .differences import central_differences

G = 9.81


def step(R, v, p, bg, ba, w_m, f_m, dt, n=None):
    """The filter's nominal prediction, with optional IMU noise n = (n_g, n_a)."""
    n = np.zeros(6) if n is None else n
    w = w_m - bg - n[0:3]
    f = f_m - ba - n[3:6]
    R2 = R @ Rotation.from_rotvec(w * dt).as_matrix()
    v2 = v + dt * (R2 @ f + [0, 0, -G])
    return R2, v2, p + dt * v2


def boxminus(a, b):
    """Error-state difference a - b (attitude as Log(R_b^T R_a))."""
    Ra, va, pa, bga, baa = a
    Rb, vb, pb, bgb, bab = b
    return np.concatenate(
        [Rotation.from_matrix(Rb.T @ Ra).as_rotvec(), va - vb, pa - pb, bga - bgb, baa - bab]
    )


def attitude_derivative(fun, R, eps: float = 1e-7):
    """Central differences of a scalar ``fun(R Exp(dtheta))`` with respect to dtheta (3,)."""
    return central_differences(lambda d: fun(R @ Rotation.from_rotvec(d).as_matrix()), 3, eps)


@pytest.mark.parametrize("seed", range(4))
def test_transition_jacobians_match_finite_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    v, p = rng.normal(size=3), rng.normal(size=3)
    bg, ba = 0.01 * rng.normal(size=3), 0.1 * rng.normal(size=3)
    w_m, f_m = rng.normal(0, 1.0, 3), rng.normal([0, 0, G], 2.0)
    dt = 0.004
    R2, v2, p2 = step(R, v, p, bg, ba, w_m, f_m, dt)
    nominal_after = (R2, v2, p2, bg, ba)
    F, Gm = nav_jacobians(R2, f_m - ba, w_m - bg, dt)

    def after_perturbed_state(d):
        Rt = R @ Rotation.from_rotvec(d[0:3]).as_matrix()
        st = step(Rt, v + d[3:6], p + d[6:9], bg + d[9:12], ba + d[12:15], w_m, f_m, dt)
        return boxminus((*st, bg + d[9:12], ba + d[12:15]), nominal_after)

    F_num = central_differences(after_perturbed_state, 15)
    # First-order model of the step (right Jacobian of Exp taken as I): error O(|w| dt) relative.
    np.testing.assert_allclose(F, F_num, atol=2e-5)
    G_num = central_differences(
        lambda n: boxminus((*step(R, v, p, bg, ba, w_m, f_m, dt, n), bg, ba), nominal_after), 6
    )
    np.testing.assert_allclose(Gm[:, 0:6], G_num, atol=2e-5)


@pytest.mark.parametrize("seed", range(5))
def test_yaw_jacobian_matches_finite_differences(seed: int) -> None:
    R = Rotation.from_euler(
        "ZYX", np.random.default_rng(seed).uniform([-3, -0.6, -0.6], [3, 0.6, 0.6])
    ).as_matrix()
    np.testing.assert_allclose(yaw_jacobian(R), attitude_derivative(yaw_of, R), atol=1e-6)


def test_config_and_covariance_are_validated() -> None:
    with pytest.raises(EstimationError):
        NavEkfConfig(gyro_sigma_rad_s=0.0)
    with pytest.raises(EstimationError, match="P0"):
        NavEkf(NavEkfConfig(), p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=[0, 0, 0, 1], P0=-np.eye(15))


def hover_stream(jump_at_s: float, *, with_reset: bool, seconds: float = 6.0):
    """A vehicle hovering still at the origin: IMU (250 Hz) and vision poses (30 Hz). From
    ``jump_at_s`` the vision frame moves by (1, 0.5, 0) m and 0.3 rad of yaw."""
    from quadnav.messages import ImuSample, PoseSample

    rng = np.random.default_rng(0)
    out = []
    t, next_v = 0, 0
    while t < seconds * 1e9:
        t += 4_000_000
        if t >= next_v:
            next_v += 33_333_333
            jumped = t >= jump_at_s * 1e9
            p = np.array([1.0, 0.5, 0.0]) if jumped else np.zeros(3)
            q = Rotation.from_euler("z", 0.3 if jumped else 0.0).as_quat()
            out.append(PoseSample(t_ns=t, p_W_B=p + rng.normal(0, 0.005, 3), q_W_B_xyzw=q, sigma_pos_m=0.01, sigma_yaw_rad=0.01,
                                  reset_counter=1 if (jumped and with_reset) else 0))  # fmt: skip
        out.append(
            ImuSample(
                t_ns=t,
                gyro_rad_s=rng.normal(0, 0.002, 3),
                accel_m_s2=[0.0, 0.0, G] + rng.normal(0, 0.02, 3),
            )
        )
    return out


def hover_estimator():
    from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig

    ekf = NavEkf(
        NavEkfConfig(), p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=[0, 0, 0, 1.0], P0=np.eye(15) * 1e-4
    )
    return ekf, DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=100_000_000), t0_ns=0
    )


def test_a_vision_frame_jump_with_a_reset_counter_is_not_motion() -> None:
    ekf, est = hover_estimator()
    worst = 0.0
    for s in hover_stream(2.0, with_reset=True):
        est.push(s)
        worst = max(worst, float(np.linalg.norm(est.output_nav().pos)))
    assert worst < 0.03  # no jump in the output
    assert est.stats("vision").rejected_gate == 0
    assert any("re-anchored" in e for _, e in ekf.events)


def test_a_persistently_rejected_source_resets_the_state_and_says_so() -> None:
    ekf, est = hover_estimator()
    for s in hover_stream(2.0, with_reset=False):
        est.push(s)
    stats = est.stats("vision")
    assert stats.rejected_gate >= 50  # about 2 s of 30 Hz poses were gated out first
    assert any("position and heading reset" in e for _, e in ekf.events)
    np.testing.assert_allclose(
        ekf.p[0:2], [1.0, 0.5], atol=0.05
    )  # then it follows the sensor again


def test_gps_and_magnetometer_pull_position_and_heading_onto_the_truth() -> None:
    """A still vehicle at (3, -2, 1) m facing 0.4 rad; the filter starts at the origin facing
    0.2 rad and must find both from GNSS fixes and the magnetometer."""
    import pymap3d

    from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig
    from quadnav.messages import GpsSample, ImuSample
    from quadnav.sim.sensors import MagSensor

    datum = (47.397742, 8.545594, 488.0)
    p_true, yaw_true = np.array([3.0, -2.0, 1.0]), 0.4
    R_true = Rotation.from_euler("z", yaw_true)
    ekf = NavEkf(
        NavEkfConfig(datum_lla=datum, mag_declination_rad=0.05),
        p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=Rotation.from_euler("z", 0.2).as_quat(),
        P0=np.diag([1e-4, 1e-4, 0.3**2] + [0.1**2] * 3 + [5.0**2] * 3 + [1e-4] * 3 + [1e-3] * 3),
    )  # fmt: skip
    est = DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=200_000_000), t0_ns=0
    )
    mag = MagSensor(period_ns=20_000_000, declination_rad=0.05, noise_sigma=0.002)
    rng = np.random.default_rng(1)
    from quadnav.messages import VehicleState

    truth = VehicleState(
        t_ns=0,
        p_W_B=p_true,
        v_W_B=np.zeros(3),
        a_W_B=np.zeros(3),
        q_W_B_xyzw=R_true.as_quat(),
        w_B=np.zeros(3),
    )
    f_B = R_true.apply([0.0, 0.0, G], inverse=True)
    for k in range(1, 2500):  # 10 s
        t = k * 4_000_000
        if k % 50 == 0:
            lat, lon, alt = pymap3d.enu2geodetic(*(p_true + rng.normal(0, 0.3, 3)), *datum)
            est.push(GpsSample(t_ns=t, lat_deg=lat, lon_deg=lon, alt_m=alt, v_enu_m_s=rng.normal(0, 0.05, 3),
                               sigma_h_m=0.3, sigma_v_m=0.3, sigma_vel_m_s=0.05))  # fmt: skip
        m = mag.sample(truth, t, rng)
        if m is not None:
            est.push(m)
        est.push(
            ImuSample(
                t_ns=t, gyro_rad_s=rng.normal(0, 0.001, 3), accel_m_s2=f_B + rng.normal(0, 0.01, 3)
            )
        )
    np.testing.assert_allclose(ekf.p, p_true, atol=0.25)
    assert (
        abs(math.remainder(Rotation.from_matrix(ekf.R).as_euler("ZYX")[0] - yaw_true, 2 * math.pi))
        < 0.02
    )
    assert est.stats("gps").fused >= 45 and est.stats("mag").fused >= 450


@pytest.mark.parametrize("seed", range(5))
def test_range_jacobian_matches_finite_differences(seed: int) -> None:
    from quadnav.estimation.nav_ekf import range_jacobian

    rng = np.random.default_rng(seed)
    R = Rotation.from_euler("ZYX", rng.uniform([-3, -0.5, -0.5], [3, 0.5, 0.5])).as_matrix()
    h = float(rng.uniform(0.3, 5.0))
    pred, J = range_jacobian(R, h)
    # the range is the distance along body -z to the plane h below
    assert pred == pytest.approx(h / (R @ [0, 0, 1])[2])
    num = attitude_derivative(lambda Rp: range_jacobian(Rp, h)[0], R)
    np.testing.assert_allclose(J, num, atol=1e-6)


@pytest.mark.parametrize("seed", range(5))
def test_range_finder_corrects_height_of_a_tilted_vehicle(seed: int) -> None:
    """A still vehicle 2 m above the ground, rolled 0.3 rad; the filter starts 0.5 m too low
    and must find the height from the tilted range readings alone."""
    from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig
    from quadnav.messages import ImuSample, RangeSample

    rng = np.random.default_rng(seed)
    R_true = Rotation.from_euler("x", 0.3)
    f_B = R_true.apply([0, 0, G], inverse=True)
    P0 = np.diag([1e-4] * 3 + [1e-4] * 3 + [1e-2, 1e-2, 0.5**2] + [1e-8] * 6)
    ekf = NavEkf(
        NavEkfConfig(),
        p0=np.array([0.0, 0.0, 1.5]),
        v0=np.zeros(3),
        q0_xyzw=R_true.as_quat(),
        P0=P0,
    )
    est = DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=40_000_000), t0_ns=0
    )
    true_range = 2.0 / math.cos(0.3)
    for k in range(1, 1500):
        t = k * 4_000_000
        if k % 5 == 0:
            est.push(RangeSample(t_ns=t, range_m=true_range + rng.normal(0, 0.02), sigma_m=0.02))
        est.push(
            ImuSample(
                t_ns=t, gyro_rad_s=rng.normal(0, 0.002, 3), accel_m_s2=f_B + rng.normal(0, 0.02, 3)
            )
        )
    assert ekf.p[2] == pytest.approx(2.0, abs=0.03)
    assert est.stats("range").fused > 250


@pytest.mark.parametrize("seed", range(5))
def test_rotated_vision_frame_is_estimated_as_px4_does(seed: int) -> None:
    """Thesis 000 eqs 3.7-3.8: the vision frame is turned 0.8 rad and offset from the world;
    heading comes from the magnetometer. The filter finds the frame's yaw and puts the
    vehicle, which starts at the world origin and moves, where it is."""
    from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig
    from quadnav.messages import ImuSample, MagSample, PoseSample

    rng = np.random.default_rng(seed)
    yaw_V = 0.8
    R_W_V = Rotation.from_euler("z", yaw_V)
    p_W_V = np.array([3.0, -1.0, 0.2])
    heading = 0.5  # the vehicle's true yaw in the world
    R_W_B = Rotation.from_euler("z", heading)
    field_W = np.array([0.0, 0.2, -0.4])  # north and down
    ekf = NavEkf(
        NavEkfConfig(vision_frame="rotate"),
        p0=np.zeros(3),
        v0=np.zeros(3),
        q0_xyzw=Rotation.from_euler("z", heading + 0.1).as_quat(),
        P0=np.diag([1e-4, 1e-4, 0.1**2] + [1e-3] * 3 + [1e-4] * 3 + [1e-8] * 6),
    )
    est = DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=100_000_000), t0_ns=0
    )
    # A slow, constant-velocity drift east (0.1 m/s) from the world origin.
    vel = np.array([0.1, 0.0, 0.0])
    for k in range(1, 5000):
        t = k * 4_000_000
        p_W = vel * t * 1e-9
        if k % 8 == 0:
            p_V = R_W_V.apply(p_W - p_W_V, inverse=True)
            q_V = (R_W_V.inv() * R_W_B).as_quat()
            est.push(PoseSample(t_ns=t, p_W_B=p_V + rng.normal(0, 0.01, 3), q_W_B_xyzw=q_V,
                                sigma_pos_m=0.01, sigma_yaw_rad=0.01))  # fmt: skip
        if k % 5 == 0:
            m = R_W_B.apply(field_W, inverse=True) + rng.normal(0, 0.003, 3)
            est.push(MagSample(t_ns=t, field_B=m, sigma_heading_rad=0.03))
        est.push(ImuSample(t_ns=t, gyro_rad_s=rng.normal(0, 0.002, 3),
                           accel_m_s2=R_W_B.apply([0, 0, G], inverse=True) + rng.normal(0, 0.02, 3)))  # fmt: skip
    yaw = ekf.vision_frame_yaw()
    assert yaw is not None
    assert abs(math.remainder(yaw - yaw_V, 2 * math.pi)) < 0.03
    assert abs(math.remainder(yaw_of(ekf.R) - heading, 2 * math.pi)) < 0.03
    # The position is the world's (the origin where it started), not the vision frame's.
    p_true = vel * est.t_delayed_ns * 1e-9
    assert np.linalg.norm(ekf.p - p_true) < 0.1


def test_raw_readings_with_nan_are_rejected_and_counted() -> None:
    from quadnav.messages import HeightSample, ImuSample

    ekf, est = hover_estimator()
    good = est.push_raw(ImuSample, t_ns=4_000_000, gyro_rad_s=np.zeros(3), accel_m_s2=[0, 0, G])
    bad = est.push_raw(
        ImuSample, t_ns=8_000_000, gyro_rad_s=[0.0, math.nan, 0.0], accel_m_s2=[0, 0, G]
    )
    also_bad = est.push_raw(HeightSample, t_ns=8_000_000, z_m=math.inf, sigma_m=0.1)
    assert (good, bad, also_bad) == (True, False, False)
    assert est.rejected_invalid == {"ImuSample": 1, "HeightSample": 1}
    assert est.t_now_ns == 4_000_000  # the bad sample did not move time
    assert np.isfinite(ekf.P).all()


@pytest.mark.parametrize("seed", range(5))
def test_magnetometer_heading_jacobian_matches_finite_differences(seed: int) -> None:
    from quadnav.estimation.nav_ekf import mag_heading_jacobian

    rng = np.random.default_rng(seed)
    R = Rotation.from_euler("ZYX", rng.uniform([-3, -0.5, -0.5], [3, 0.5, 0.5])).as_matrix()
    m_B = R.T @ np.array([0.0, 0.2, -0.45])  # a field dipping 66 degrees, as at mid latitudes
    h, J = mag_heading_jacobian(R, m_B)
    assert h == pytest.approx(np.pi / 2)
    num = attitude_derivative(lambda Rp: mag_heading_jacobian(Rp, m_B)[0], R)
    np.testing.assert_allclose(J, num, atol=1e-6)
    # tilt matters: with the field dipping, a roll or pitch error moves the heading
    assert np.abs(J[0:2]).max() > 0.1


def test_a_live_loop_can_bound_the_fusion_log() -> None:
    from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig

    ekf = NavEkf(
        NavEkfConfig(), p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=[0, 0, 0, 1.0], P0=np.eye(15) * 1e-4
    )
    cfg = HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=100_000_000, max_fusion_log=50)
    est = DelayedHorizonEstimator(ekf, cfg, t0_ns=0)
    for s in hover_stream(10.0, with_reset=False, seconds=6.0):
        est.push(s)
    assert len(est.fusion_log) == 50  # the newest 50 of about 180 poses
    assert est.stats("vision").fused > 150
    assert est.fusion_log[-1].t_obs_ns > est.fusion_log[0].t_obs_ns
    with pytest.raises(EstimationError, match="max_fusion_log"):
        HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=0, max_fusion_log=0)
