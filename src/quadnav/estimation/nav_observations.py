"""The navigation EKF's observation models, one per kind of sample, as a registry.

A sensor is fused by the model registered for its sample type (:meth:`NavEkf.register
<quadnav.estimation.nav_ekf.NavEkf.register>`), found along the type's bases: a new sensor is
a message type, a sensor model (its channel), an observation model and one registration, with
no edit of the filter or of the loop that pushes samples to it. A model sees the filter through
:class:`NavUpdater`: the nominal state (``p``, ``v``, ``R``, the biases), the 15 states'
covariance ``P``, the configuration, the body rate of the last prediction, and the two updates:
``update`` (the chi-square gate, the error injected) and ``gated_update`` (the same, and the
reset to the measurement of a source rejected for ``reset_after_s``, PX4's).

Built in (:func:`builtin_observations`): world position, height (the barometer with its bias
estimator when configured), GNSS position and velocity, magnetometer heading, downward range,
world velocity, optical flow (PX4's model, its gyro compensation low-passed here), and the two
kinds whose frame the filter itself keeps (an external pose and an external odometry: their
frame's anchor and, relative, its drift states are the filter's state).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from quadnav.estimation.flow_model import (
    compensated_flow_rate,
    flow_noise_sigma,
    predict_flow,
    tilt_cosine_jacobian,
)
from quadnav.estimation.horizon import FusionResult
from quadnav.estimation.layout import NAV_ERROR
from quadnav.geometry.rotations import skew
from quadnav.messages import (
    FlowSample,
    GpsSample,
    HeightSample,
    MagSample,
    OdometrySample,
    PoseSample,
    PositionSample,
    RangeSample,
    VelocitySample,
)

__all__ = [
    "NavUpdater",
    "ObservationModel",
    "Stamped",
    "builtin_observations",
    "mag_heading_jacobian",
    "not_fused",
    "range_jacobian",
    "world_yaw_jacobian",
    "yaw_jacobian",
]

FloatArray = NDArray[np.float64]
S = TypeVar("S", contravariant=True)

_ATT, _VEL, _POS = (NAV_ERROR[b] for b in ("att", "vel", "pos"))
_N = NAV_ERROR.size
_Z = NAV_ERROR.index("z")


class Stamped(Protocol):
    """A sample of any kind: its time of validity (a ``source`` name is read when it has one)."""

    @property
    def t_ns(self) -> int: ...


class NavUpdater(Protocol):
    """What an observation model sees of the navigation EKF."""

    p: FloatArray
    v: FloatArray
    R: FloatArray

    @property
    def P(self) -> FloatArray: ...

    @property
    def config(self) -> _ObservationConfig: ...

    @property
    def body_rate_rad_s(self) -> FloatArray: ...

    @property
    def specific_force_m_s2(self) -> FloatArray: ...

    @property
    def baro_bias(self) -> _BaroBias | None: ...

    def update(
        self, r: FloatArray, H: FloatArray, Rn: FloatArray, *, gate: float | None = None
    ) -> FusionResult: ...

    def gated_update(
        self,
        obs: Stamped,
        r: FloatArray,
        H: FloatArray,
        Rn: FloatArray,
        p_meas: FloatArray | None,
        *,
        gate: float | None = None,
    ) -> FusionResult: ...

    def reset_velocity(self, t_ns: int, v: FloatArray, var: FloatArray, source: str) -> None: ...

    def gps_to_enu(self, obs: GpsSample) -> FloatArray: ...

    def fuse_frame_pose(self, obs: PoseSample) -> FusionResult: ...

    def fuse_frame_odometry(self, obs: OdometrySample) -> FusionResult: ...


class _ObservationConfig(Protocol):
    """The settings the built-in models read (of :class:`~quadnav.estimation.nav_ekf.NavEkfConfig`)."""

    @property
    def gravity_m_s2(self) -> float: ...

    @property
    def mag_declination_rad(self) -> float: ...

    @property
    def range_max_tilt_rad(self) -> float: ...

    @property
    def terrain_z_m(self) -> float: ...

    @property
    def flow_quality_min(self) -> int: ...

    @property
    def flow_max_rate_rad_s(self) -> float: ...

    @property
    def flow_min_height_m(self) -> float: ...

    @property
    def flow_noise_min_rad_s(self) -> float: ...

    @property
    def flow_noise_max_rad_s(self) -> float: ...

    @property
    def flow_gate_sigma(self) -> float: ...

    @property
    def odometry_quality_min(self) -> int: ...


class _BaroBias(Protocol):
    bias: float
    var: float
    var_max: float

    def fuse(self, innovation_m: float, var_m2: float, /) -> object: ...


class ObservationModel(Protocol[S]):
    """How the filter fuses one kind of sample: ``accepts`` (whether this sample can be
    fused at all: PX4's quality checks; a refused one is counted as unsupported) and ``fuse``."""

    def accepts(self, ekf: NavUpdater, obs: S) -> bool: ...

    def fuse(self, ekf: NavUpdater, obs: S) -> FusionResult: ...


def not_fused(rows: int) -> FusionResult:
    """What a model returns for a sample it does not fuse this time (too tilted, too low)."""
    return FusionResult(accepted=False, innovation=np.zeros(rows), nis=0.0, test_ratio=0.0)


def world_yaw_jacobian(R: FloatArray) -> FloatArray:
    """d yaw / d dtheta (3,) for a world-frame perturbation ``Exp(dtheta) R`` (how an
    odometry message's attitude covariance carries to its yaw)."""
    den = R[0, 0] ** 2 + R[1, 0] ** 2
    return np.array([-R[2, 0] * R[0, 0] / den, -R[2, 0] * R[1, 0] / den, 1.0])


def yaw_jacobian(R: FloatArray) -> FloatArray:
    """d yaw / d dtheta (3,) for ``R_true = R Exp(dtheta)``, yaw = atan2(R10, R00)."""
    den = R[0, 0] ** 2 + R[1, 0] ** 2
    return np.array(
        [
            0.0,
            (R[1, 0] * R[0, 2] - R[0, 0] * R[1, 2]) / den,
            (R[0, 0] * R[1, 1] - R[1, 0] * R[0, 1]) / den,
        ]
    )


def mag_heading_jacobian(R: FloatArray, field_B: FloatArray) -> tuple[float, FloatArray]:
    """The heading of the field rotated into the world, ``atan2(m_W y, m_W x)`` with ``m_W = R
    m_B``, and its derivative (3,) for ``R Exp(dtheta)`` (the full attitude: with a steeply
    dipping field a roll or pitch error moves the heading)."""
    m_W = R @ field_B
    den = m_W[0] ** 2 + m_W[1] ** 2
    dh_dm = np.array([-m_W[1], m_W[0], 0.0]) / den
    return math.atan2(m_W[1], m_W[0]), -(dh_dm @ R) @ skew(field_B)


def range_jacobian(R: FloatArray, height_m: float) -> tuple[float, FloatArray]:
    """A downward range ``h = height / R22`` and ``dh / d dtheta`` (3,) for ``R Exp(dtheta)``."""
    c = float(R[2, 2])
    return height_m / c, -height_m / (c * c) * tilt_cosine_jacobian(R)


def _rows(n: int) -> FloatArray:
    return np.zeros((n, _N))


class _Always:
    """A model that fuses every sample of its type it is given."""

    def accepts(self, ekf: NavUpdater, obs: object) -> bool:
        return True


class PositionModel(_Always):
    """A world position (3)."""

    def fuse(self, ekf: NavUpdater, obs: PositionSample) -> FusionResult:
        H = _rows(3)
        H[:, _POS] = np.eye(3)
        Rn = np.eye(3) * obs.sigma_m**2
        return ekf.gated_update(obs, obs.p_W_B - ekf.p, H, Rn, obs.p_W_B)


class HeightModel(_Always):
    """A height (1); the barometer's through its bias estimator when the filter has one, in
    PX4's order: the innovation with the current bias, the bias estimator updated from the
    state before the main update, then the main update."""

    def fuse(self, ekf: NavUpdater, obs: HeightSample) -> FusionResult:
        H = _rows(1)
        H[0, _Z] = 1.0
        bias = ekf.baro_bias if obs.source == "baro" else None
        if bias is None:
            r = np.array([obs.z_m - ekf.p[2]])
            return ekf.gated_update(obs, r, H, np.array([[obs.sigma_m**2]]), None)
        var = obs.sigma_m**2
        r = np.array([obs.z_m - bias.bias - ekf.p[2]])
        Rn = np.array([[var + bias.var]])
        bias.var_max = var
        bias.fuse(obs.z_m - float(ekf.p[2]), var + float(ekf.P[_Z, _Z]))
        return ekf.gated_update(obs, r, H, Rn, None)


class GnssModel(_Always):
    """A GNSS fix: its position in the world frame (ENU about the datum) and its velocity (6)."""

    def fuse(self, ekf: NavUpdater, obs: GpsSample) -> FusionResult:
        p_W = ekf.gps_to_enu(obs)
        H = _rows(6)
        H[0:3, _POS] = np.eye(3)  # (rows: the observation's, position then velocity)
        H[3:6, _VEL] = np.eye(3)
        r = np.concatenate([p_W - ekf.p, obs.v_enu_m_s - ekf.v])
        Rn = np.diag([obs.sigma_h_m**2] * 2 + [obs.sigma_v_m**2] + [obs.sigma_vel_m_s**2] * 3)
        return ekf.gated_update(obs, r, H, Rn, p_W)


class MagHeadingModel(_Always):
    """Heading from the magnetometer: the field rotated into the world by the estimated
    attitude should point at magnetic north (declination east of true north)."""

    def fuse(self, ekf: NavUpdater, obs: MagSample) -> FusionResult:
        # Heading only, as PX4's heading fusion: letting the field's noise correct roll and
        # pitch too made the attitude worse (tried: 1.15 vs 0.51 deg RMSE outdoors). What the
        # tilt uncertainty does to the computed heading (the field dips steeply) is noise here.
        expected = math.pi / 2 - ekf.config.mag_declination_rad
        h, dh = mag_heading_jacobian(ekf.R, obs.field_B)
        r = math.remainder(expected - h, 2 * math.pi)
        H = _rows(1)
        H[0, _ATT] = yaw_jacobian(ekf.R)
        dh_tilt = dh.copy()
        dh_tilt[2] = 0.0  # (the yaw part is the state the update corrects)
        var = obs.sigma_heading_rad**2 + float(dh_tilt @ ekf.P[_ATT, _ATT] @ dh_tilt)
        return ekf.gated_update(obs, np.array([r]), H, np.array([[var]]), None)


class RangeModel(_Always):
    """A downward range finder over a flat floor (1), not fused too tilted."""

    def fuse(self, ekf: NavUpdater, obs: RangeSample) -> FusionResult:
        c = ekf.config
        if ekf.R[2, 2] < math.cos(c.range_max_tilt_rad):
            return not_fused(1)
        pred, d_dtheta = range_jacobian(ekf.R, float(ekf.p[2]) - c.terrain_z_m)
        H = _rows(1)
        H[0, _ATT] = d_dtheta
        H[0, _Z] = 1.0 / ekf.R[2, 2]
        r = np.array([obs.range_m - pred])
        return ekf.gated_update(obs, r, H, np.array([[obs.sigma_m**2]]), None)


#: The zero-velocity update resets a velocity too far off to fuse only while the accelerometer
#: reads the vehicle standing (its specific force within this fraction of gravity): a land
#: detector that cut the motors above the ground (the height estimate low) has it falling.
REST_FORCE_FRACTION = 0.1


class VelocityModel(_Always):
    """A zero-velocity update while the vehicle is known to stand still (3). The flight phase
    says so, not a sensor: where the velocity is too far off to pass the gate (a hard
    touchdown) and the accelerometer reads the vehicle standing, the velocity is reset to it
    rather than refused (PX4 never refuses its zero-velocity update), with a variance per
    axis of what it was off by. Refused, a touchdown's shock that left the velocity 0.5 m/s
    off had every update refused and the landed estimate ran 3-8 m away in 4 s; fused past
    the gate, a velocity 2 m/s off dragged the position 12 m up through their correlation
    (``outdoor_vio_gps_realistic``, 2026-12-05)."""

    def fuse(self, ekf: NavUpdater, obs: VelocitySample) -> FusionResult:
        H = _rows(3)
        H[:, _VEL] = np.eye(3)
        r = obs.v_W_B - ekf.v
        var = np.full(3, obs.sigma_m_s**2)
        res = ekf.update(r, H, np.diag(var))
        g = ekf.config.gravity_m_s2
        standing = abs(float(np.linalg.norm(ekf.specific_force_m_s2)) - g) < REST_FORCE_FRACTION * g
        if res.accepted or not standing:
            return res
        ekf.reset_velocity(obs.t_ns, obs.v_W_B, np.maximum(var, r**2), obs.source)
        return replace(res, accepted=True)  # (taken, as a reset: as sure of it as it was off)


class FlowModel:
    """PX4's optical-flow fusion (:mod:`quadnav.estimation.flow_model`): the flow rate less the
    sensor gyro's rate (its bias against the filter's gyro low-passed as EKF2's
    ``calcBodyRateComp``, kept here, per filter) against the prediction from the velocity and
    the height above the floor, one 2-D observation with its own gate. Accepted from
    ``flow_quality_min`` and up to ``flow_max_rate_rad_s`` (PX4's checks); not fused too
    tilted, too low, or when the compensated rate is beyond that limit."""

    def __init__(self, gate: float) -> None:
        self.gate = gate
        self.gyro_bias = np.zeros(3)  # the flow sensor's gyro against ours (PX4's LPF)

    def accepts(self, ekf: NavUpdater, obs: FlowSample) -> bool:
        c = ekf.config
        rate = float(np.linalg.norm(obs.flow_rate_rad_s))
        return obs.quality >= c.flow_quality_min and rate <= c.flow_max_rate_rad_s

    def fuse(self, ekf: NavUpdater, obs: FlowSample) -> FusionResult:
        c = ekf.config
        h = float(ekf.p[2]) - c.terrain_z_m
        if ekf.R[2, 2] < math.cos(c.range_max_tilt_rad) or h < c.flow_min_height_m:
            return not_fused(2)
        d_bias = np.clip(obs.gyro_rate_rad_s - ekf.body_rate_rad_s, -0.1, 0.1)
        self.gyro_bias = 0.99 * self.gyro_bias + 0.01 * d_bias
        meas = compensated_flow_rate(obs, self.gyro_bias)
        if float(np.linalg.norm(meas)) > c.flow_max_rate_rad_s:  # PX4's magnitude check, too
            return not_fused(2)
        pred = predict_flow(
            ekf.R, ekf.v, float(ekf.p[2]), floor_z_m=c.terrain_z_m, min_height_m=c.flow_min_height_m
        )
        sigma = flow_noise_sigma(
            obs.quality,
            quality_min=c.flow_quality_min,
            sigma_best_rad_s=c.flow_noise_min_rad_s,
            sigma_worst_rad_s=c.flow_noise_max_rad_s,
        )
        r = meas - pred.flow_rate_rad_s
        return ekf.update(r, pred.H, np.eye(2) * sigma**2, gate=self.gate)


class FramePoseModel(_Always):
    """An external pose (a marker pose, a motion-capture pose) in a frame the filter anchors."""

    def fuse(self, ekf: NavUpdater, obs: PoseSample) -> FusionResult:
        return ekf.fuse_frame_pose(obs)


class FrameOdometryModel:
    """An external odometry (PX4's ``ODOMETRY``) in a frame the filter anchors (and, relative,
    whose drift it estimates), accepted from ``odometry_quality_min``."""

    def accepts(self, ekf: NavUpdater, obs: OdometrySample) -> bool:
        return obs.quality >= ekf.config.odometry_quality_min

    def fuse(self, ekf: NavUpdater, obs: OdometrySample) -> FusionResult:
        return ekf.fuse_frame_odometry(obs)


#: The built-in models' makers by sample type, each given the flow gate (a filter's own models
#: are made afresh: the flow model keeps state).
_BUILTIN: dict[type, Callable[[float], ObservationModel]] = {  # type: ignore[type-arg]
    PositionSample: lambda g: PositionModel(),
    PoseSample: lambda g: FramePoseModel(),
    OdometrySample: lambda g: FrameOdometryModel(),
    HeightSample: lambda g: HeightModel(),
    GpsSample: lambda g: GnssModel(),
    MagSample: lambda g: MagHeadingModel(),
    RangeSample: lambda g: RangeModel(),
    VelocitySample: lambda g: VelocityModel(),
    FlowSample: FlowModel,
}


def builtin_observations(flow_gate: float) -> dict[type, ObservationModel]:  # type: ignore[type-arg]
    """A fresh set of the built-in models, by sample type (``flow_gate``: the flow's
    chi-square threshold)."""
    return {kind: make(flow_gate) for kind, make in _BUILTIN.items()}
