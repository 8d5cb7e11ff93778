"""The KITTI drive of GTSAM's wheel through the navigation EKF: IMU plus GPS position fixes.

The drive (:mod:`quadnav.io.gtsam_kitti`) is a car: no magnetometer, no barometer, already
moving when the data starts. So the filter starts at a fix, with its heading the course
between that fix and the one before it (the car drives forward: its x axis along its motion)
and its velocity their difference over their time; roll and pitch level (a city street).
Every ``gps_every``-th fix after that is fused as a position of the body in the world frame
(:class:`~quadnav.messages.PositionSample`: the file's local frame, z up, is the world frame;
with no compass, where its x axis points does not matter); the others are held out. With
``gps_every=0`` no fix is fused after the start: IMU-only dead reckoning.

The noise comes from the drive's metadata (GTSAM's continuous-time densities) made per-sample
for the EKF at the average period, times ``*_noise_inflation`` (see :class:`KittiGpsConfig`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import ExperimentError
from quadnav.estimation.horizon import DelayedHorizonEstimator, HorizonConfig
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.estimation.nav_filter import InitialSigmas, NavFilterSetup, build_nav_filter
from quadnav.io.gtsam_kitti import GtsamKitti
from quadnav.messages import ImuSample, PositionSample
from quadnav.units import s_to_ns

__all__ = [
    "KittiGpsConfig",
    "KittiGpsResult",
    "horizontal_errors_at",
    "interpolated_imu",
    "run_kitti_gps",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiGpsConfig:
    """How the drive is run.

    * ``gps_every``: fuse the fixes whose index is a multiple of this (GTSAM's example's
      ``gps_skip`` is 10: its fixes 10, 20, ...); 1: every fix; 0: none (dead reckoning).
    * ``gps_sigma_m``: a fix's sigma per axis; sqrt(0.07) m is GTSAM's example's (its GPS
      factor's precision 1/0.07).
    * ``start_fix``: the fix the filter starts at (its heading from the course from the fix
      before); 2, since GTSAM's example starts at fix 1 and fix 0 is 2.9 s before fix 1.
    * ``duration_s``: run this long after the start (None: to the end of the data).
    * ``accel_noise_inflation``, ``gyro_noise_inflation``: the metadata's white noise times
      these. With the metadata's own values the filter is sure of itself to a few centimetres
      and its gate refuses the fixes after the drive's first turn (see the results page).
    """

    gps_every: int = 10
    gps_sigma_m: float = math.sqrt(0.07)
    start_fix: int = 2
    duration_s: float | None = None
    accel_noise_inflation: float = 10.0
    gyro_noise_inflation: float = 30.0
    init_vel_sigma_m_s: float = 1.0
    init_tilt_sigma_rad: float = 0.05
    init_accel_bias_sigma_m_s2: float = 0.1  # GTSAM's example's bias prior
    init_gyro_bias_sigma_rad_s: float = 0.01

    def __post_init__(self) -> None:
        if self.gps_every < 0 or self.start_fix < 1:
            raise ExperimentError("KittiGpsConfig: gps_every must be >= 0 and start_fix >= 1")
        positive = (self.gps_sigma_m, self.accel_noise_inflation, self.gyro_noise_inflation,
                    self.init_vel_sigma_m_s, self.init_tilt_sigma_rad,
                    self.init_accel_bias_sigma_m_s2, self.init_gyro_bias_sigma_rad_s)  # fmt: skip
        if not all(math.isfinite(v) and v > 0 for v in positive):
            raise ExperimentError("KittiGpsConfig: sigmas and inflations must be finite and > 0")
        if self.duration_s is not None and not self.duration_s > 0:
            raise ExperimentError("KittiGpsConfig.duration_s must be > 0 or None")


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiGpsResult:
    """The filter's estimate at every IMU step after the start (world frame, ENU-like, z up),
    its position variances, and what became of the fixes (``fused``: the indices of the
    drive's fixes the filter was given; ``refused`` of those, the ones its gate refused)."""

    t_ns: IntArray
    p: FloatArray  # (N, 3)
    pos_var_m2: FloatArray  # (N, 3), the delayed horizon's (no delay here: the same time)
    yaw_rad: FloatArray
    given: IntArray
    refused: IntArray
    events: tuple[tuple[int, str], ...]
    interpolated_imu: int
    wall_s: float


def interpolated_imu(data: GtsamKitti, *, tol: float = 1e-6) -> NDArray[np.bool_]:
    """IMU rows on a straight line through their neighbours in all six channels: samples
    the data's maker filled in by linear interpolation (real readings are never that smooth)."""
    x = np.hstack([data.accel_m_s2, data.gyro_rad_s])
    out = np.zeros(len(x), dtype=bool)
    if len(x) >= 3:
        out[1:-1] = np.abs(np.diff(x, 2, axis=0)).max(axis=1) < tol
    return out


def _filter(data: GtsamKitti, cfg: KittiGpsConfig, t0_ns: int) -> DelayedHorizonEstimator:
    """The EKF at the start fix: heading and velocity from the motion since the fix before."""
    m, k = data.metadata, cfg.start_fix
    if k >= len(data.gps_t_ns):
        raise ExperimentError(f"start_fix {k}: the drive has {len(data.gps_t_ns)} fixes")
    sq = math.sqrt(m.average_dt_s)  # continuous densities (GTSAM's) to per-sample sigmas
    ekf = NavEkfConfig(
        gyro_sigma_rad_s=m.gyro_sigma / sq * cfg.gyro_noise_inflation,
        accel_sigma_m_s2=m.accel_sigma / sq * cfg.accel_noise_inflation,
        # GTSAM's example grows its bias sigma by the metadata's value per IMU sample
        gyro_bias_rw_rad_s_sqrt_s=m.gyro_bias_sigma / sq,
        accel_bias_rw_m_s2_sqrt_s=m.accel_bias_sigma / sq,
    )
    dt_s = (int(data.gps_t_ns[k]) - int(data.gps_t_ns[k - 1])) * 1e-9
    v0 = (data.gps_p_m[k] - data.gps_p_m[k - 1]) / dt_s
    yaw0 = math.atan2(float(v0[1]), float(v0[0]))
    dist = float(np.hypot(v0[0], v0[1])) * dt_s
    # the course's own uncertainty: two fixes' sigmas across the distance between them
    yaw_sigma = max(0.05, math.sqrt(2.0) * cfg.gps_sigma_m / max(dist, 1e-3))
    sigmas = InitialSigmas(
        tilt_rad=cfg.init_tilt_sigma_rad,
        yaw_rad=min(yaw_sigma, math.pi),
        vel_m_s=cfg.init_vel_sigma_m_s,
        pos_xy_m=cfg.gps_sigma_m,
        pos_z_m=cfg.gps_sigma_m,
        gyro_bias_rad_s=cfg.init_gyro_bias_sigma_rad_s,
        accel_bias_m_s2=cfg.init_accel_bias_sigma_m_s2,
    )
    horizon = HorizonConfig(imu_period_ns=s_to_ns(m.average_dt_s), max_delay_ns=0)
    setup = NavFilterSetup(ekf=ekf, horizon=horizon, sigmas=sigmas)
    q0 = Rotation.from_euler("Z", yaw0).as_quat()
    return build_nav_filter(setup, t0_ns=t0_ns, p0=data.gps_p_m[k], q0_xyzw=q0, v0=v0)


def _fixes(data: GtsamKitti, cfg: KittiGpsConfig, t_end_ns: int) -> list[PositionSample]:
    if cfg.gps_every == 0:
        return []
    k = np.arange(len(data.gps_t_ns))
    sel = (k > cfg.start_fix) & (k % cfg.gps_every == 0) & (data.gps_t_ns <= t_end_ns)
    return [
        PositionSample(t_ns=int(data.gps_t_ns[i]), p_W_B=data.gps_p_m[i], sigma_m=cfg.gps_sigma_m)
        for i in np.flatnonzero(sel).tolist()
    ]


def run_kitti_gps(data: GtsamKitti, cfg: KittiGpsConfig = KittiGpsConfig()) -> KittiGpsResult:
    """Run the drive through the EKF from ``cfg.start_fix``: see the module's docstring."""
    t_start = int(data.gps_t_ns[min(cfg.start_fix, len(data.gps_t_ns) - 1)])
    i0 = int(np.searchsorted(data.imu_t_ns, t_start, side="right"))
    t_end = int(data.imu_t_ns[-1])
    if cfg.duration_s is not None:
        t_end = min(t_end, t_start + s_to_ns(cfg.duration_s))
    i1 = int(np.searchsorted(data.imu_t_ns, t_end, side="right"))
    if i1 - i0 < 2:
        raise ExperimentError("the drive has no IMU data after the start fix")
    est = _filter(data, cfg, t_start)
    ekf = est.filter
    assert isinstance(ekf, NavEkf)
    fixes = _fixes(data, cfg, t_end)
    t_wall = time.perf_counter()
    n = i1 - i0
    p, var, yaw = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
    j = 0
    for i in range(i0, i1):
        t = int(data.imu_t_ns[i])
        while j < len(fixes) and fixes[j].t_ns <= t:
            est.push(fixes[j])
            j += 1
        est.push(ImuSample(t_ns=t, gyro_rad_s=data.gyro_rad_s[i], accel_m_s2=data.accel_m_s2[i]))
        nav = est.output_nav()
        p[i - i0] = nav.pos
        var[i - i0] = np.diag(ekf.P)[6:9]
        R = nav.att.reshape(3, 3)
        yaw[i - i0] = math.atan2(R[1, 0], R[0, 0])
    wall = time.perf_counter() - t_wall
    return _result(data, est, ekf, fixes, (p, var, yaw), (i0, i1), wall)


def _result(
    data: GtsamKitti,
    est: DelayedHorizonEstimator,
    ekf: NavEkf,
    fixes: list[PositionSample],
    rows: tuple[FloatArray, FloatArray, FloatArray],
    span: tuple[int, int],
    wall: float,
) -> KittiGpsResult:
    index = {int(t): k for k, t in enumerate(data.gps_t_ns.tolist())}
    given = np.array([index[f.t_ns] for f in fixes], dtype=np.int64)
    refused = np.array(
        [index[r.t_obs_ns] for r in est.fusion_log if not r.result.accepted], dtype=np.int64
    )
    i0, i1 = span
    return KittiGpsResult(
        t_ns=data.imu_t_ns[i0:i1].copy(),
        p=rows[0],
        pos_var_m2=rows[1],
        yaw_rad=rows[2],
        given=given,
        refused=refused,
        events=tuple(ekf.events),
        interpolated_imu=int(interpolated_imu(data)[i0:i1].sum()),
        wall_s=wall,
    )


def horizontal_errors_at(
    t_ns: IntArray, p: FloatArray, fix_t_ns: IntArray, fix_p: FloatArray
) -> FloatArray:
    """The horizontal distance (m) from each fix to a trajectory interpolated linearly at the
    fix's time; fixes outside the trajectory's span are NaN."""
    t = (np.asarray(t_ns, dtype=np.int64) - int(t_ns[0])) * 1e-9
    tf = (np.asarray(fix_t_ns, dtype=np.int64) - int(t_ns[0])) * 1e-9
    at = np.column_stack([np.interp(tf, t, p[:, k]) for k in range(2)])
    err = np.hypot(at[:, 0] - fix_p[:, 0], at[:, 1] - fix_p[:, 1])
    err[(tf < t[0]) | (tf > t[-1])] = np.nan
    return err
