"""The IMU propagator (``vio/propagator.py``), the part of the VIO a GPS fusion or a SLAM
reuses: its running propagation, fed sample by sample, is the preintegration of the same span
from scratch; its prediction follows the true motion; its buffer stays bounded."""

from __future__ import annotations

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.messages import ImuSample
from quadnav.units import NS_PER_S
from quadnav.vio.preintegration import imu_params, zero_bias
from quadnav.vio.propagator import ImuPropagator
from tests.vio.synthetic import make_scene


def _state(scene, t_ns: int) -> tuple[gtsam.Pose3, np.ndarray]:  # type: ignore[no-untyped-def]
    p, q = scene.motion.pose(np.array([t_ns]))
    R = Rotation.from_quat(q[0]).as_matrix()
    return gtsam.Pose3(gtsam.Rot3(R), p[0]), scene.motion.velocity(np.array([t_ns]))[0]


def test_running_propagation_is_the_span_from_scratch_and_follows_the_motion() -> None:
    scene = make_scene(1, duration_s=4.0)
    assert scene.rig.imu is not None
    prop = ImuPropagator(imu_params(scene.rig.imu.noise, g_norm=9.80665))
    imu = scene.imu
    t0 = imu[0].t_ns + 1_003_000_000  # between two samples
    bias = gtsam.imuBias.ConstantBias(scene.true_accel_bias, scene.true_gyro_bias)
    n0 = next(i for i, s in enumerate(imu) if s.t_ns > t0)
    for s in imu[:n0]:
        prop.push(s)
    prop.run_from(t0, bias)
    pose0, v0 = _state(scene, t0)
    worst = 0.0
    for s in imu[n0 : n0 + 400]:  # 2 s at 200 Hz
        prop.push(s)
        run = prop.running
        assert run is not None
        fresh = prop.span(t0, s.t_ns, bias)
        assert abs(run.deltaTij() - fresh.deltaTij()) < 1e-9
        assert np.allclose(run.deltaPij(), fresh.deltaPij(), atol=1e-9)
        pr = ImuPropagator.predict(pose0, v0, bias, run, np.eye(6) * 1e-8, np.eye(3) * 1e-8)
        true_pose, _ = _state(scene, s.t_ns)
        worst = max(worst, float(np.linalg.norm(pr.pose.translation() - true_pose.translation())))
        assert np.all(np.linalg.eigvalsh(pr.cov_pose) > 0)
    # EuRoC-grade noise, true biases, 2 s: a few centimetres at most, not metres
    assert worst < 0.05, worst
    prop.stop()
    assert prop.running is None


def test_the_buffer_is_pruned_and_still_covers_what_is_kept() -> None:
    scene = make_scene(2, duration_s=20.0)
    assert scene.rig.imu is not None
    prop = ImuPropagator(imu_params(scene.rig.imu.noise, g_norm=9.80665))
    for s in scene.imu:
        prop.push(s)
        last = prop.last_t_ns
        assert last is not None
        prop.prune(last - 2_000_000_000)
    assert len(prop.samples) < 2 * 200 * 2 + 1000  # 2 s kept, pruned in chunks of 1,000
    last = prop.last_t_ns
    assert last is not None
    pim = prop.span(last - 1_500_000_000, last, zero_bias())
    assert abs(pim.deltaTij() - 1.5) < 1e-9


def _rotation_angle(R: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def test_gyro_rotation_of_a_constant_rate_is_the_rate_times_the_span() -> None:
    """At a constant rate about a fixed axis the rotation is exp(w dt), the bias taken off, for
    a span between samples; the newest sample holds up to ``hold_ns``; a span the buffer does
    not cover has none."""
    prop = ImuPropagator(imu_params(make_scene(0, duration_s=1.0).rig.imu.noise, g_norm=9.80665))  # type: ignore[union-attr]
    w, b = np.array([0.4, -1.1, 2.0]), np.array([0.01, 0.02, -0.03])
    for k in range(41):  # 200 Hz over 0.2 s
        prop.push(ImuSample(t_ns=k * 5_000_000, gyro_rad_s=w + b, accel_m_s2=np.zeros(3)))
    t0, t1 = 12_300_000, 61_700_000
    R = prop.gyro_rotation(t0, t1, b)
    assert R is not None
    want = Rotation.from_rotvec(w * (t1 - t0) / NS_PER_S).as_matrix()
    assert np.allclose(R, want, atol=1e-12)
    held = prop.gyro_rotation(190_000_000, 203_000_000, b, hold_ns=5_000_000)
    assert held is not None
    assert np.allclose(held, Rotation.from_rotvec(w * 0.013).as_matrix(), atol=1e-12)
    assert prop.gyro_rotation(190_000_000, 203_000_000, b) is None  # past the newest sample
    assert prop.gyro_rotation(-1_000_000, 10_000_000, b) is None  # before the first


def test_gyro_rotation_between_frames_follows_the_true_motion() -> None:
    """Over 50 ms spans (a frame at 20 Hz) of three scenes' motion, with EuRoC-grade gyro noise
    and the true bias taken off, the gyro's rotation is the true one to well within a
    milliradian."""
    worst, turned = 0.0, 0.0
    for seed in (1, 2, 3):
        scene = make_scene(seed, duration_s=4.0)
        assert scene.rig.imu is not None
        prop = ImuPropagator(imu_params(scene.rig.imu.noise, g_norm=9.80665))
        for s in scene.imu:
            prop.push(s)
        rng = np.random.default_rng(seed)
        for t0 in rng.integers(scene.imu[0].t_ns, scene.imu[-1].t_ns - 60_000_000, 20).tolist():
            t1 = t0 + 50_000_000
            R = prop.gyro_rotation(t0, t1, scene.true_gyro_bias)
            assert R is not None
            R0 = _state(scene, t0)[0].rotation().matrix()
            R1 = _state(scene, t1)[0].rotation().matrix()
            truth = R0.T @ R1
            worst = max(worst, _rotation_angle(R.T @ truth))
            turned = max(turned, _rotation_angle(truth))
    assert worst < 5e-4, worst
    assert turned > 0.01  # the spans do turn (up to about a degree)
