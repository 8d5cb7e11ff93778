"""The navigation estimator as the closed loop, the log replay and the SITL vehicle see it.

* :func:`build_nav_filter`: the one place the navigation EKF and its delayed horizon are built
  from a configuration (filter settings, horizon timing, initial state and its sigmas).
* :func:`ground_alignment`: attitude and position on the ground before take-off.
* :class:`AligningNavFilter`: an :class:`NavEstimator` that levels itself on the ground from
  what it is pushed during the alignment span, then builds the filter and runs it.
* :class:`TruthEstimator`: perfect knowledge (a run's reference for what estimation costs),
  fed by a ``truth`` channel of :class:`~quadnav.messages.TruthSample`.

Both implement :class:`NavEstimator`: the design's ``Estimator`` (push, output, delayed) plus
``ready`` and a typed :class:`EstimatorReport` of what happened to every source.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import EstimationError
from quadnav.estimation.horizon import (
    DelayedHorizonEstimator,
    HorizonConfig,
    SourceCounters,
    SourceFusion,
    SourceStats,
    fusion_arrays,
)
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig, world_yaw_jacobian
from quadnav.geometry.navsat import GeoDatum, NavSatTransform
from quadnav.messages import (
    GpsSample,
    ImuSample,
    MagSample,
    OdometrySample,
    PoseSample,
    Sample,
    StateEstimate,
    TruthSample,
)

__all__ = [
    "SOURCE_COUNT_KEYS",
    "AligningNavFilter",
    "EstimatorReport",
    "ImuCounts",
    "InitialSigmas",
    "NavEstimator",
    "NavFilterSetup",
    "TruthEstimator",
    "build_nav_filter",
    "counts_json",
    "ground_alignment",
    "pose_sigmas",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class ImuCounts:
    """What became of the IMU samples: taken, out of order, refused as invalid at the driver,
    flagged as clipped (a log's own flags)."""

    received: int
    rejected_out_of_order: int
    rejected_invalid: int
    clipping_flagged: int = 0


def counts_json(
    sources: Mapping[str, SourceStats], imu: ImuCounts, *, imu_keys: Sequence[str]
) -> dict[str, dict[str, int]]:
    """Per-source counters as the ``counts`` mapping of ``metrics.json`` (and the IMU's)."""
    out = {src: {k: getattr(st, k) for k in SOURCE_COUNT_KEYS} for src, st in sources.items()}
    out["imu"] = {k: getattr(imu, k) for k in imu_keys}
    return out


#: The per-source counters a run's ``metrics.json`` reports.
SOURCE_COUNT_KEYS = (
    "received",
    "fused",
    "rejected_gate",
    "rejected_too_old",
    "rejected_unsupported",
)


@dataclass(frozen=True, slots=True, kw_only=True)
class EstimatorReport:
    """What an estimator did with its inputs: fusions and counters per source, its own events."""

    fusion: Mapping[str, SourceFusion]
    sources: Mapping[str, SourceStats]
    imu_received: int = 0
    imu_rejected_out_of_order: int = 0
    rejected_invalid: Mapping[str, int] = field(default_factory=dict)
    events: Sequence[tuple[int, str]] = ()


class NavEstimator(Protocol):
    """An ``Estimator`` (ARCHITECTURE.md, Interfaces) a closed loop can fly on."""

    @property
    def ready(self) -> bool:
        """Whether :meth:`output` and :meth:`delayed` have an estimate (after alignment)."""
        ...

    def push(self, sample: Sample) -> None: ...

    def output(self) -> StateEstimate: ...

    def delayed(self) -> StateEstimate: ...

    def delayed_row(self, row: FloatArray, P: FloatArray) -> int:
        """The delayed horizon for a log without building an estimate: its position, velocity,
        quaternion (xyzw) and gyro and accelerometer biases (NaN where it has none) into
        ``row`` (16), its covariance into ``P`` (15x15, NaN where it has none); its time."""
        ...

    def report(self) -> EstimatorReport: ...


@dataclass(frozen=True, slots=True, kw_only=True)
class InitialSigmas:
    """One-sigma uncertainty of the initial state: the filter's ``P0`` (diagonal)."""

    tilt_rad: float = 0.02
    yaw_rad: float = 1.0
    vel_m_s: float = 0.05
    pos_xy_m: float = 0.1
    pos_z_m: float = 0.1
    gyro_bias_rad_s: float = 0.01
    accel_bias_m_s2: float = 0.05

    def P0(self) -> FloatArray:
        """The 15x15 initial covariance in the EKF's error-state order (att, vel, pos, bg, ba)."""
        sig = np.array(
            [self.tilt_rad, self.tilt_rad, self.yaw_rad]
            + [self.vel_m_s] * 3
            + [self.pos_xy_m, self.pos_xy_m, self.pos_z_m]
            + [self.gyro_bias_rad_s] * 3
            + [self.accel_bias_m_s2] * 3
        )
        if not (np.isfinite(sig).all() and (sig > 0).all()):
            raise EstimationError(f"initial sigmas must be finite and > 0, got {sig.tolist()}")
        return np.diag(sig**2)


@dataclass(frozen=True, slots=True, kw_only=True)
class NavFilterSetup:
    """Everything :func:`build_nav_filter` needs besides the initial state."""

    ekf: NavEkfConfig
    horizon: HorizonConfig
    sigmas: InitialSigmas = InitialSigmas()


def build_nav_filter(
    setup: NavFilterSetup,
    *,
    t0_ns: int,
    p0: FloatArray,
    q0_xyzw: FloatArray,
    v0: FloatArray | None = None,
    sigmas: InitialSigmas | None = None,
    gyro_bias0: FloatArray | None = None,
) -> DelayedHorizonEstimator:
    """The navigation EKF at the initial state, behind its delayed horizon."""
    ekf = NavEkf(
        setup.ekf,
        p0=np.asarray(p0, dtype=np.float64),
        v0=np.zeros(3) if v0 is None else np.asarray(v0, dtype=np.float64),
        q0_xyzw=np.asarray(q0_xyzw, dtype=np.float64),
        P0=(sigmas or setup.sigmas).P0(),
        bg0=gyro_bias0,
    )
    return DelayedHorizonEstimator(ekf, setup.horizon, t0_ns=t0_ns)


ExternalPose = PoseSample | OdometrySample


def pose_sigmas(pose: ExternalPose) -> tuple[float, float]:
    """An external pose's one-sigma heading (rad) and position (m, the largest axis): a
    pose's own sigmas, or from an odometry sample's covariance."""
    if isinstance(pose, PoseSample):
        return pose.sigma_yaw_rad, pose.sigma_pos_m
    R = Rotation.from_quat(pose.q_W_B_xyzw).as_matrix()
    j = world_yaw_jacobian(R)
    var_pos = float(np.max(np.diag(pose.cov_pose)[0:3]))
    return math.sqrt(float(j @ pose.cov_pose[3:6, 3:6] @ j)), math.sqrt(var_pos)


def ground_alignment(
    imu: Sequence[ImuSample],
    pose: ExternalPose | None,
    *,
    mag: Sequence[MagSample] | None = None,
    declination_rad: float = 0.0,
    gps_enu_m: FloatArray | None = None,
) -> tuple[Rotation, FloatArray]:
    """Initial attitude and position on the ground: roll and pitch from the mean specific
    force (gravity); heading from the external pose (or odometry), else from the magnetometer; position from
    the external pose, else from a GNSS fix (already in ENU), else the origin."""
    if not imu:
        raise EstimationError("alignment needs IMU samples on the ground")
    f = np.mean([s.accel_m_s2 for s in imu], axis=0)
    roll = math.atan2(f[1], f[2])
    pitch = math.atan2(-f[0], math.hypot(f[1], f[2]))
    yaw = 0.0
    if pose is not None:
        yaw = float(Rotation.from_quat(pose.q_W_B_xyzw).as_euler("ZYX")[0])
    elif mag:
        m = Rotation.from_euler("ZYX", [0.0, pitch, roll]).apply(
            np.mean([s.field_B for s in mag], axis=0)
        )
        yaw = math.remainder(math.pi / 2 - declination_rad - math.atan2(m[1], m[0]), 2 * math.pi)
    if pose is not None:
        p0 = pose.p_W_B.copy()
    elif gps_enu_m is not None:
        p0 = np.asarray(gps_enu_m, dtype=np.float64).copy()
    else:
        p0 = np.zeros(3)
    return Rotation.from_euler("ZYX", [yaw, pitch, roll]), p0


@dataclass(frozen=True, slots=True, kw_only=True)
class AlignmentSigmas:
    """How sure the alignment is, by what it levelled from: a pose's own sigmas times
    ``pose_factor``; a GNSS fix's horizontal sigma times ``gps_factor``; a magnetometer heading;
    and the fallbacks when nothing observed the heading or the position."""

    pose_factor: float = 3.0
    gps_factor: float = 2.0
    yaw_from_mag_rad: float = 0.1
    yaw_unknown_rad: float = 1.0
    pos_unknown_m: float = 0.1
    # a surveyed start (x, y, z in the navigation frame, heading in rad): the pose the vehicle
    # stands at while it aligns, with these sigmas; None: from the sensors
    start_pose: tuple[float, float, float, float] | None = None
    start_pos_sigma_m: float = 0.05
    start_yaw_sigma_rad: float = 0.02


@dataclass
class _AlignmentData:
    imu: list[ImuSample] = field(default_factory=list)
    mag: list[MagSample] = field(default_factory=list)
    last_pose: ExternalPose | None = None
    first_fix: GpsSample | None = None


class AligningNavFilter:
    """The navigation EKF, levelled on the ground first.

    Until ``align_ns`` the samples pushed are kept for :func:`ground_alignment` (the IMU's
    gravity, the last external pose, the magnetometer, the first GNSS fix); on the first sample
    at or after it the filter is built by :func:`build_nav_filter` with the initial sigmas of
    what it levelled from, and every later sample goes to it.
    """

    def __init__(
        self,
        setup: NavFilterSetup,
        *,
        align_ns: int,
        alignment: AlignmentSigmas = AlignmentSigmas(),
        heading_from_pose: bool = True,
        gyro_bias_at_rest: bool = False,
    ) -> None:
        self.setup = setup
        self.align_ns = int(align_ns)
        self.alignment = alignment
        # Rotated vision (PX4's): the heading is the magnetometer's, the origin where it stands.
        self.heading_from_pose = heading_from_pose
        # Standing still, the mean gyro reading is its bias (a static initialisation).
        self.gyro_bias_at_rest = gyro_bias_at_rest
        self._data = _AlignmentData()
        self.horizon: DelayedHorizonEstimator | None = None
        self._ekf: NavEkf  # the horizon's filter, once aligned

    @property
    def ready(self) -> bool:
        return self.horizon is not None

    def push(self, sample: Sample) -> None:
        if self.horizon is not None:
            self.horizon.push(sample)
            return
        d = self._data
        if isinstance(sample, ImuSample):
            d.imu.append(sample)
        elif isinstance(sample, PoseSample | OdometrySample):
            d.last_pose = sample
        elif isinstance(sample, MagSample):
            d.mag.append(sample)
        elif isinstance(sample, GpsSample):
            d.first_fix = d.first_fix or sample
        if isinstance(sample, ImuSample) and sample.t_ns >= self.align_ns:
            self.horizon = self._align(sample.t_ns)

    def _align(self, t_ns: int) -> DelayedHorizonEstimator:
        d, a, cfg = self._data, self.alignment, self.setup.ekf
        gps_enu = None
        if d.first_fix is not None:
            gps_enu = _fix_enu(d.first_fix, cfg.datum_lla)
        pose = d.last_pose if self.heading_from_pose else None
        R0, p0 = ground_alignment(
            d.imu, pose, mag=d.mag, declination_rad=cfg.mag_declination_rad, gps_enu_m=gps_enu
        )
        if a.start_pose is not None:  # surveyed: the start's position and heading as given
            x, y, z, heading = a.start_pose
            p0 = np.array([x, y, z])
            R0 = Rotation.from_euler("ZYX", [heading, *R0.as_euler("ZYX")[1:]])
            yaw, pos = a.start_yaw_sigma_rad, a.start_pos_sigma_m
        elif pose is not None:
            yaw, pos = (a.pose_factor * s for s in pose_sigmas(pose))
        else:
            yaw = a.yaw_from_mag_rad if d.mag else a.yaw_unknown_rad
            fix = d.first_fix
            pos = a.gps_factor * fix.sigma_h_m if fix is not None else a.pos_unknown_m
        s = self.setup.sigmas
        sigmas = InitialSigmas(
            tilt_rad=s.tilt_rad,
            yaw_rad=yaw,
            vel_m_s=s.vel_m_s,
            pos_xy_m=pos,
            pos_z_m=pos,
            gyro_bias_rad_s=s.gyro_bias_rad_s,
            accel_bias_m_s2=s.accel_bias_m_s2,
        )
        bg0 = np.mean([x.gyro_rad_s for x in d.imu], axis=0) if self.gyro_bias_at_rest else None
        horizon = build_nav_filter(
            self.setup, t0_ns=t_ns, p0=p0, q0_xyzw=R0.as_quat(), sigmas=sigmas, gyro_bias0=bg0
        )
        assert isinstance(horizon.filter, NavEkf)  # (build_nav_filter's)
        self._ekf = horizon.filter
        return horizon

    def _ready(self) -> DelayedHorizonEstimator:
        if self.horizon is None:
            raise EstimationError("the navigation filter has no estimate before its alignment")
        return self.horizon

    def output(self) -> StateEstimate:
        return self._ready().output()

    def delayed(self) -> StateEstimate:
        return self._ready().delayed()

    def delayed_row(self, row: FloatArray, P: FloatArray) -> int:
        h = self._ready()
        self._ekf.state_row(row, P)  # (the filter is at the delayed horizon)
        return h.t_delayed_ns

    def report(self) -> EstimatorReport:
        if self.horizon is None:
            return EstimatorReport(fusion={}, sources={})
        h = self.horizon
        ekf = h.filter
        return EstimatorReport(
            fusion=fusion_arrays(h.fusion_log),
            sources={src: h.stats(src) for src in h.sources},
            imu_received=h.imu_received,
            imu_rejected_out_of_order=h.imu_rejected_out_of_order,
            rejected_invalid=h.rejected_invalid,
            events=list(ekf.events) if isinstance(ekf, NavEkf) else [],
        )


def _fix_enu(fix: GpsSample, datum: tuple[float, float, float] | None) -> FloatArray | None:
    if datum is None:
        return None
    p_E: FloatArray = NavSatTransform(GeoDatum(*datum)).enu(
        GeoDatum(fix.lat_deg, fix.lon_deg, fix.alt_m)
    )[0]
    return p_E


class TruthEstimator:
    """Perfect knowledge: the newest :class:`~quadnav.messages.TruthSample` pushed, at both
    horizons, with no covariance. Other samples are counted and ignored."""

    names = ("x", "y", "z", "vx", "vy", "vz", "qx", "qy", "qz", "qw")

    def __init__(self) -> None:
        self._last: TruthSample | None = None
        self._ignored: dict[str, SourceCounters] = {}
        self._imu = 0

    @property
    def ready(self) -> bool:
        return self._last is not None

    def push(self, sample: Sample) -> None:
        if isinstance(sample, TruthSample):
            self._last = sample
            return
        if isinstance(sample, ImuSample):
            self._imu += 1
            return
        src = getattr(sample, "source", type(sample).__name__)
        stats = self._ignored.setdefault(src, SourceCounters())
        stats.received += 1
        stats.rejected_unsupported += 1

    def output(self) -> StateEstimate:
        if self._last is None:
            raise EstimationError("the truth estimator has been given no truth yet")
        s = self._last.state
        x = np.concatenate([s.p_W_B, s.v_W_B, s.q_W_B_xyzw])
        return StateEstimate(
            t_ns=s.t_ns,
            p_W_B=s.p_W_B,
            v_W_B=s.v_W_B,
            q_W_B_xyzw=s.q_W_B_xyzw,
            x=x,
            names=self.names,
            P=None,
            w_B=s.w_B,
        )

    def delayed(self) -> StateEstimate:
        return self.output()

    def delayed_row(self, row: FloatArray, P: FloatArray) -> int:
        s = self.output()
        row[0:3], row[3:6], row[6:10], row[10:16] = s.p_W_B, s.v_W_B, s.q_W_B_xyzw, np.nan
        P[:] = np.nan
        return s.t_ns

    def report(self) -> EstimatorReport:
        sources = {src: c.snapshot() for src, c in self._ignored.items()}
        return EstimatorReport(fusion={}, sources=sources, imu_received=self._imu)
