"""External odometry (PX4's ODOMETRY from a VIO) in the navigation EKF, over seeded Monte Carlo
flights: a smooth 3-D flight, its IMU (250 Hz, with noise and biases) and odometry made from
the truth plus noise (20 Hz, 60 ms late), with the covariance the noise has."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import SampleError
from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig, yaw_of
from quadnav.messages import OdometrySample, Sample
from quadnav.rig import ImuNoiseModel
from quadnav.sim.motion import SplineMotion, synthesize_imu

RATE_HZ = 250.0
NOISE = ImuNoiseModel(
    gyro_noise_density=2.4e-4,
    gyro_random_walk=2.0e-5,
    accel_noise_density=2.8e-3,
    accel_random_walk=4.0e-4,
)
SIGMA_P, SIGMA_V, SIGMA_ATT = 0.05, 0.05, 0.02
DELAY_NS = 60_000_000
ODO_PERIOD_NS = 48_000_000  # 20.8 Hz, on the IMU ticks


def _motion(seconds: float) -> SplineMotion:
    t = np.arange(0.0, seconds + 2.0, 0.02)
    p = np.column_stack(
        [2.0 * np.sin(0.4 * t), 1.5 * (1 - np.cos(0.4 * t)), 1.0 + 0.3 * np.sin(0.7 * t)]
    )
    ypr = np.column_stack([0.5 * np.sin(0.3 * t), 0.05 * np.cos(0.8 * t), 0.05 * np.sin(0.9 * t)])
    q = Rotation.from_euler("ZYX", ypr).as_quat()
    return SplineMotion.from_arrays((t * 1e9).astype(np.int64), p, q, trim_s=1.0)


def odometry_config(**kw: object) -> NavEkfConfig:
    """The filter with the IMU's noise per sample and 1 cm (1 cm/s, 5 mrad) floors."""
    fields: dict[str, object] = dict(
        gyro_sigma_rad_s=NOISE.gyro_noise_density * math.sqrt(RATE_HZ),
        accel_sigma_m_s2=NOISE.accel_noise_density * math.sqrt(RATE_HZ),
        odometry_pos_noise_m=0.01,
        odometry_vel_noise_m_s=0.01,
        odometry_yaw_noise_rad=0.005,
    )
    fields.update(kw)
    return NavEkfConfig(**fields)  # type: ignore[arg-type]


@dataclass
class Run:
    ekf: NavEkf
    est: DelayedHorizonEstimator
    motion: SplineMotion
    errors_m: list[float]  # delayed position error after each odometry fusion window


def odometry_of(
    motion: SplineMotion, t_ns: int, rng: np.random.Generator, **kw: object
) -> OdometrySample:
    """The truth at ``t_ns`` plus noise of the sigmas above, with that covariance."""
    p, q = motion.pose(np.array([t_ns]))
    v = motion.velocity(np.array([t_ns]))[0]
    R = Rotation.from_rotvec(rng.normal(0, SIGMA_ATT, 3)) * Rotation.from_quat(q[0])
    cov_pose = np.diag([SIGMA_P**2] * 3 + [SIGMA_ATT**2] * 3)
    fields: dict[str, object] = dict(
        t_ns=t_ns,
        p_W_B=p[0] + rng.normal(0, SIGMA_P, 3),
        q_W_B_xyzw=R.as_quat(),
        v_W_B=v + rng.normal(0, SIGMA_V, 3),
        cov_pose=cov_pose,
        cov_v=np.eye(3) * SIGMA_V**2,
    )
    fields.update(kw)
    return OdometrySample(**fields)  # type: ignore[arg-type]


def fly(
    seed: int,
    *,
    seconds: float = 10.0,
    config: NavEkfConfig | None = None,
    odometry: bool = True,
    yaw0_error_rad: float = 0.0,
    edit=None,
) -> Run:
    """Fly the motion with the EKF started at the truth (heading off by ``yaw0_error_rad``);
    ``edit(k, sample)`` may change or drop (None) the k-th odometry sample."""
    rng = np.random.default_rng(seed)
    motion = _motion(seconds)
    imu = list(synthesize_imu(motion, rate_hz=RATE_HZ, noise=NOISE, rng=rng).samples())
    t0 = imu[0].t_ns
    p0, q0 = motion.pose(np.array([t0]))
    q0 = (Rotation.from_euler("z", yaw0_error_rad) * Rotation.from_quat(q0[0])).as_quat()
    cfg = config or odometry_config()
    P0 = np.diag([0.02**2] * 2 + [max(yaw0_error_rad, 0.02) ** 2] + [0.05**2] * 6 + [1e-3**2] * 6)
    ekf = NavEkf(cfg, p0=p0[0], v0=motion.velocity(np.array([t0]))[0], q0_xyzw=q0, P0=P0)
    est = DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=100_000_000), t0_ns=t0
    )
    pending: list[tuple[int, Sample]] = []
    errors: list[float] = []
    k = 0
    for s in imu[1:]:
        if odometry and (s.t_ns - t0) % ODO_PERIOD_NS == 0:
            o: OdometrySample | None = odometry_of(motion, s.t_ns, rng)
            o = edit(k, o) if edit is not None else o
            k += 1
            if o is not None:
                pending.append((s.t_ns + DELAY_NS, o))
        while pending and pending[0][0] <= s.t_ns:
            est.push(pending.pop(0)[1])
        est.push(s)
        if (s.t_ns - t0) % ODO_PERIOD_NS == 0:
            p_true = motion.pose(np.array([est.t_delayed_ns]))[0][0]
            errors.append(float(np.linalg.norm(ekf.p - p_true)))
    return Run(ekf, est, motion, errors)


def _rms(x: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def test_odometry_bounds_the_position_error_over_seeds() -> None:
    """Position, velocity and yaw fused with the message's covariance: the delayed position
    error stays well under the odometry's own noise, and the yaw the filter started 0.3 rad
    off is pulled onto the truth."""
    rms, yaw_err = [], []
    for seed in range(5):
        run = fly(seed, yaw0_error_rad=0.3)
        rms.append(_rms(run.errors_m[40:]))  # after the first 2 s
        q_true = run.motion.pose(np.array([run.est.t_delayed_ns]))[1][0]
        yaw_true = yaw_of(Rotation.from_quat(q_true).as_matrix())
        yaw_err.append(abs(math.remainder(yaw_of(run.ekf.R) - yaw_true, 2 * math.pi)))
        assert run.est.stats("vio").fused >= 180
        assert run.est.stats("vio").rejected_gate == 0
    # the odometry's 5 cm per axis (8.7 cm in 3-D) averaged down by the IMU's prediction
    assert np.mean(rms) < 0.04, rms
    assert max(yaw_err) < 0.03, yaw_err


def test_velocity_only_odometry_keeps_the_position_drift_bounded() -> None:
    """With the odometry's velocity alone the position is dead-reckoned from a velocity that
    is observed: over 10 s it drifts a few centimetres, several times less than the IMU alone
    (started at the same truth)."""
    cfg = NavEkfConfig(
        gyro_sigma_rad_s=NOISE.gyro_noise_density * math.sqrt(RATE_HZ),
        accel_sigma_m_s2=NOISE.accel_noise_density * math.sqrt(RATE_HZ),
        odometry_fuse=("vel",),
        odometry_vel_noise_m_s=0.01,
    )
    ends, free = [], []
    for seed in range(5):
        run = fly(seed, config=cfg)
        assert run.est.stats("vio").fused >= 180
        ends.append(run.errors_m[-1])
        free.append(fly(seed, config=cfg, odometry=False).errors_m[-1])
    assert max(ends) < 0.1, ends
    assert np.mean(free) > 3 * np.mean(ends), (free, ends)


def _jump(at_k: int, *, bump: bool):
    """From the ``at_k``-th sample on, the source's frame is moved 1.2 m and turned 0.4 rad
    (its reset counter bumped with ``bump``)."""
    Rj = Rotation.from_euler("z", 0.4)
    dp = np.array([1.2, -0.6, 0.2])

    def edit(k: int, o: OdometrySample) -> OdometrySample:
        if k < at_k:
            return o
        J = np.zeros((6, 6))
        J[0:3, 0:3] = J[3:6, 3:6] = Rj.as_matrix()
        return OdometrySample(
            t_ns=o.t_ns,
            p_W_B=Rj.as_matrix() @ o.p_W_B + dp,
            q_W_B_xyzw=(Rj * Rotation.from_quat(o.q_W_B_xyzw)).as_quat(),
            v_W_B=Rj.as_matrix() @ o.v_W_B,
            cov_pose=J @ o.cov_pose @ J.T,
            cov_v=Rj.as_matrix() @ o.cov_v @ Rj.as_matrix().T,
            reset_counter=1 if bump else 0,
        )

    return edit


@pytest.mark.parametrize("mode", ["absolute", "relative"])
def test_a_reset_counter_jump_does_not_jump_the_filter(mode: str) -> None:
    cfg = odometry_config(odometry_mode=mode)
    for seed in range(2):
        run = fly(seed, config=cfg, edit=_jump(100, bump=True))
        assert run.est.stats("vio").rejected_gate == 0
        assert any("reset counter 1, frame re-anchored" in e for _, e in run.ekf.events)
        # the frame moved 1.3 m at 4.8 s: the filter's position did not
        assert max(run.errors_m[40:]) < 0.12, max(run.errors_m[40:])
    # the same jump without the counter is refused by the gate, sample after sample
    bad = fly(0, config=cfg, edit=_jump(100, bump=False))
    assert bad.est.stats("vio").rejected_gate >= 30


def test_an_outlier_is_rejected_and_counted() -> None:
    def edit(k: int, o: OdometrySample) -> OdometrySample:
        if k != 150:
            return o
        return odometry_of(run_motion, o.t_ns, np.random.default_rng(9), p_W_B=o.p_W_B + [0, 2, 0])

    run_motion = _motion(10.0)
    run = fly(3, edit=edit)
    stats = run.est.stats("vio")
    assert stats.rejected_gate == 1
    assert stats.fused == stats.received - 1 - run.est.pending("vio")
    assert max(run.errors_m[40:]) < 0.1  # the 2 m outlier moved nothing
    rejected = [r for r in run.est.fusion_log if not r.result.accepted]
    assert len(rejected) == 1 and rejected[0].result.test_ratio > 1.0
    assert len(rejected[0].result.innovation) == 7  # position, velocity and yaw together


def test_a_nan_odometry_sample_is_rejected_at_the_boundary() -> None:
    rng = np.random.default_rng(0)
    motion = _motion(4.0)
    good = odometry_of(motion, motion.t_start_ns, rng)
    with pytest.raises(SampleError, match=r"OdometrySample\.v_W_B holds a non-finite value"):
        odometry_of(motion, motion.t_start_ns, rng, v_W_B=[0.0, math.nan, 0.0])
    run = fly(1, seconds=4.0)
    est = run.est
    fields = dict(
        t_ns=est.t_now_ns, p_W_B=good.p_W_B, q_W_B_xyzw=good.q_W_B_xyzw,
        v_W_B=good.v_W_B, cov_pose=good.cov_pose, cov_v=np.full((3, 3), math.nan),
    )  # fmt: skip
    before = est.stats("vio").received
    assert est.push_raw(OdometrySample, **fields) is False
    assert est.rejected_invalid == {"OdometrySample": 1}
    assert est.stats("vio").received == before  # never reached the filter
    assert np.isfinite(run.ekf.P).all()


def test_odometry_below_the_quality_floor_is_refused_and_counted() -> None:
    cfg = NavEkfConfig(odometry_quality_min=50)
    run = fly(2, seconds=4.0, config=cfg, edit=lambda k, o: _with_quality(o, 10 if k % 2 else 90))
    stats = run.est.stats("vio")
    assert stats.rejected_unsupported == stats.received // 2
    waiting = run.est.pending("vio")
    assert (
        stats.fused + stats.rejected_gate + waiting == stats.received - stats.rejected_unsupported
    )


def _with_quality(o: OdometrySample, quality: int) -> OdometrySample:
    return OdometrySample(
        t_ns=o.t_ns, p_W_B=o.p_W_B, q_W_B_xyzw=o.q_W_B_xyzw, v_W_B=o.v_W_B,
        cov_pose=o.cov_pose, cov_v=o.cov_v, quality=quality,
    )  # fmt: skip


def test_odometry_settings_are_validated_by_name() -> None:
    from quadnav.errors import EstimationError

    with pytest.raises(EstimationError, match="odometry_fuse must name some of pos, vel, yaw"):
        NavEkfConfig(odometry_fuse=("pos", "attitude"))
    with pytest.raises(EstimationError, match="odometry_gate_sigma must be finite and > 0"):
        NavEkfConfig(odometry_gate_sigma=0.0)
    with pytest.raises(EstimationError, match="odometry_mode must be one of absolute, relative"):
        NavEkfConfig(odometry_mode="delta")
    with pytest.raises(EstimationError, match="odometry_drift_m_sqrt_s must be finite and > 0"):
        NavEkfConfig(odometry_mode="relative", odometry_drift_m_sqrt_s=-1.0)
    with pytest.raises(EstimationError, match="needs vision_frame='world'"):
        NavEkfConfig(odometry_mode="relative", vision_frame="rotate")


# The drifting odometry's frame: random walks of its origin and its yaw
DRIFT_M_SQRT_S, DRIFT_YAW_RAD_SQRT_S = 0.02, 0.004


def _error_state(ekf: NavEkf, motion: SplineMotion, imu: object, t_ns: int) -> np.ndarray:
    """The delayed error state (15), true minus estimate, the attitude as a body rotation."""
    p, q = motion.pose(np.array([t_ns]))
    v = motion.velocity(np.array([t_ns]))[0]
    k = int(np.searchsorted(imu.t_ns, t_ns))  # type: ignore[attr-defined]
    dth = Rotation.from_matrix(ekf.R.T @ Rotation.from_quat(q[0]).as_matrix()).as_rotvec()
    bg, ba = imu.gyro_bias_rad_s[k], imu.accel_bias_m_s2[k]  # type: ignore[attr-defined]
    return np.concatenate([dth, v - ekf.v, p[0] - ekf.p, bg - ekf.bg, ba - ekf.ba])


def drifting_nees(seed: int, mode: str, *, seconds: float = 10.0) -> float:
    """The mean NEES (15 states) of the filter fed an odometry whose frame drifts, its origin
    and its yaw as random walks (a VIO's position and yaw are unobservable to it), and whose
    message states only its white noise, as a VIO's does; sampled each odometry period after
    2 s."""
    rng = np.random.default_rng(100 + seed)
    motion = _motion(seconds)
    series = synthesize_imu(motion, rate_hz=RATE_HZ, noise=NOISE, rng=rng)
    imu = list(series.samples())
    t0 = imu[0].t_ns
    p0, q0 = motion.pose(np.array([t0]))
    cfg = odometry_config(
        gyro_bias_rw_rad_s_sqrt_s=NOISE.gyro_random_walk * 3,  # (as nav's bias_rw_inflation)
        accel_bias_rw_m_s2_sqrt_s=NOISE.accel_random_walk * 3,
        odometry_mode=mode,
        odometry_drift_m_sqrt_s=DRIFT_M_SQRT_S,
        odometry_drift_yaw_rad_sqrt_s=DRIFT_YAW_RAD_SQRT_S,
    )
    P0 = np.diag([0.02**2] * 3 + [0.05**2] * 6 + [1e-3**2] * 3 + [0.02**2] * 3)
    ekf = NavEkf(cfg, p0=p0[0], v0=motion.velocity(np.array([t0]))[0], q0_xyzw=q0[0], P0=P0)
    est = DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=100_000_000), t0_ns=t0
    )
    pending: list[tuple[int, Sample]] = []
    drift, nees = np.zeros(4), []
    step = np.array([DRIFT_M_SQRT_S] * 3 + [DRIFT_YAW_RAD_SQRT_S]) * math.sqrt(ODO_PERIOD_NS * 1e-9)
    for s in imu[1:]:
        if (s.t_ns - t0) % ODO_PERIOD_NS == 0:
            drift += rng.normal(0, 1, 4) * step
            o = odometry_of(motion, s.t_ns, rng)
            pending.append((s.t_ns + DELAY_NS, _moved(o, drift, p0[0])))
        while pending and pending[0][0] <= s.t_ns:
            est.push(pending.pop(0)[1])
        est.push(s)
        if (s.t_ns - t0) % ODO_PERIOD_NS == 0 and s.t_ns - t0 > 2_000_000_000:
            e = _error_state(ekf, motion, series, est.t_delayed_ns)
            nees.append(float(e @ np.linalg.solve(ekf.P, e)))
    return float(np.mean(nees))


def _moved(o: OdometrySample, drift: np.ndarray, p0: np.ndarray) -> OdometrySample:
    """The odometry in a frame turned by ``drift[3]`` about the start ``p0`` and moved by
    ``drift[:3]`` (its covariance, the white noise's, as it was)."""
    Rz = Rotation.from_euler("z", drift[3])
    M = Rz.as_matrix()
    return OdometrySample(
        t_ns=o.t_ns, p_W_B=p0 + M @ (o.p_W_B - p0) + drift[:3],
        q_W_B_xyzw=(Rz * Rotation.from_quat(o.q_W_B_xyzw)).as_quat(), v_W_B=M @ o.v_W_B,
        cov_pose=o.cov_pose, cov_v=o.cov_v,
    )  # fmt: skip


def test_relative_odometry_is_consistent_where_absolute_is_not() -> None:
    """A drifting odometry taken as absolute fixes is averaged down below its drift: NEES far
    above its 15 states. Taken as relative (its frame's drift estimated beside the state) the
    NEES, over seeded runs, is within 2x of 15."""
    rel = [drifting_nees(seed, "relative") for seed in range(5)]
    ab = [drifting_nees(seed, "absolute") for seed in range(3)]
    assert 7.5 <= np.median(rel) <= 30 and np.mean(rel) <= 30, rel
    assert np.median(ab) > 30, ab


def _drift_then_correct(at: int, drift_m_per_sample: np.ndarray):  # type: ignore[no-untyped-def]
    """The odometry drifts by ``drift_m_per_sample`` a sample until sample ``at``, where it is
    corrected (a loop closure) and its reset counter raised."""

    def edit(k: int, o: OdometrySample) -> OdometrySample:
        if k >= at:
            return OdometrySample(
                t_ns=o.t_ns, p_W_B=o.p_W_B, q_W_B_xyzw=o.q_W_B_xyzw, v_W_B=o.v_W_B,
                cov_pose=o.cov_pose, cov_v=o.cov_v, reset_counter=1,
            )  # fmt: skip
        return OdometrySample(
            t_ns=o.t_ns, p_W_B=o.p_W_B + k * drift_m_per_sample, q_W_B_xyzw=o.q_W_B_xyzw,
            v_W_B=o.v_W_B, cov_pose=o.cov_pose, cov_v=o.cov_v,
        )  # fmt: skip

    return edit


@pytest.mark.parametrize("mode", ["absolute", "relative"])
def test_following_a_corrected_odometry_takes_its_correction(mode: str) -> None:
    """PX4's EKF2 with external vision leading: a reset counter that changes because the source
    corrected itself in its frame (loop closure) resets the filter to it (absolute), or
    restarts the frame's drift from zero (relative). The odometry has drifted 0.5 m over 4.8 s,
    then jumps back to the truth: following, the filter is on the truth right after (within
    the odometry's 5 cm noise); re-anchoring (the frame taken as new) keeps what it had of the
    drift (all of it absolute; relative, the part the drift states did not explain)."""
    drift = np.array([0.004, -0.003, 0.0])  # 0.5 m after 100 samples
    said = "position, velocity, heading reset to it" if mode == "absolute" else "frame drift"
    for seed in range(3):
        edit = _drift_then_correct(100, drift)
        run = fly(
            seed, config=odometry_config(odometry_mode=mode, follow_resets=("vio",)), edit=edit
        )
        assert any(f"reset counter 1, {said}" in e for _, e in run.ekf.events), run.ekf.events
        assert run.est.stats("vio").rejected_gate == 0
        followed = run.errors_m[105:]
        anchored = fly(seed, config=odometry_config(odometry_mode=mode), edit=edit).errors_m[105:]
        assert max(followed) < 0.1, (seed, max(followed))
        assert np.median(followed) < 0.6 * np.median(anchored), (seed, followed, anchored)
