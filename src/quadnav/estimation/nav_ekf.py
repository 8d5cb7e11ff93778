"""The 3-D navigation EKF (PX4 EKF2-class) on the delayed-horizon core.

Error-state (multiplicative) filter. Nominal state: position ``p`` and velocity ``v`` in the
world (ENU), attitude ``R_W_B`` (FLU body), gyro bias ``b_g`` and accelerometer bias ``b_a``.
Error state (15): ``dtheta`` (body-frame attitude error, ``R_true = R Exp(dtheta)``), ``dv``,
``dp``, ``db_g``, ``db_a``.

Prediction with one IMU sample (rate ``w`` and specific force ``f``, biases removed), the
same semi-implicit step as the planar filter::

    R' = R Exp(w dt);  v' = v + dt (R' f + g_W);  p' = p + dt v'

Observations: world position, external pose (position and yaw), external odometry (PX4's
``ODOMETRY`` from a VIO: position, world velocity and yaw with the message's covariance; with
``odometry_mode="relative"`` the odometry frame's drift, position and yaw, is four random-walk
states beside the 15, so a drifting odometry's motion is taken and its drift not averaged),
height, range, heading, velocity, optical flow (PX4's model,
:mod:`quadnav.estimation.flow_model`), each fused by the model registered for its sample type
(:mod:`quadnav.estimation.nav_observations`; :meth:`NavEkf.register` adds one). Each update is gated
with a chi-square test on its innovation, applied in Joseph form and injected into the nominal
state with the covariance reset ``P <- G P G^T``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import EstimationError
from quadnav.estimation.bias_estimator import BiasEstimator
from quadnav.estimation.chi2 import chi2_isf, chi2_ppf, chi2_sf
from quadnav.estimation.horizon import FusionResult, NavState, _pi_correct, require_positive
from quadnav.estimation.imu_clipping import (
    BADACC_NOISE_M_S2,
    BiasLearningGate,
    Releveller,
    clip_axes,
)
from quadnav.estimation.layout import NAV_ERROR, NAV_NOISE, NAV_NOMINAL, NAV_OUTPUT, StateLayout
from quadnav.estimation.nav_observations import (
    ObservationModel,
    Stamped,
    builtin_observations,
    mag_heading_jacobian,
    range_jacobian,
    world_yaw_jacobian,
    yaw_jacobian,
)
from quadnav.geometry.navsat import GeoDatum, NavSatTransform
from quadnav.geometry.rotations import (
    quat_xyzw_from_matrix,
    quat_xyzw_one,
    rotation_matrix_xyzw,
    skew,
    so3_exp,
    so3_exp_one,
    so3_log,
    so3_log_one,
    yaw_of,
)
from quadnav.jit import njit
from quadnav.messages import (
    GpsSample,
    ImuSample,
    MagSample,
    OdometrySample,
    PoseSample,
    PositionSample,
    RangeSample,
    Sample,
    StateEstimate,
)
from quadnav.units import GRAVITY_M_S2, s_to_ns

__all__ = [
    "ODOMETRY_MODES",
    "ODOMETRY_PARTS",
    "NavEkf",
    "NavEkfConfig",
    "NavKinematics",
    "gate_thresholds",
    "mag_heading_jacobian",
    "nav_jacobians",
    "range_jacobian",
    "skew",
    "world_yaw_jacobian",
    "yaw_jacobian",
]

FloatArray = NDArray[np.float64]
# Error-state blocks and entries, by name (quadnav.estimation.layout), bound once for the hot path
_ATT, _VEL, _POS, _BG, _BA = (
    NAV_ERROR[b] for b in ("att", "vel", "pos", "gyro_bias", "accel_bias")
)
_N = NAV_ERROR.size
_Z = NAV_ERROR.index("z")
_YAW = NAV_ERROR.index("dtheta_z")  # the heading resets turn the attitude about this axis
# Noise inputs of G (columns): gyro and accelerometer white noise, their biases' random walks
_N_G, _N_A, _N_BG, _N_BA = (NAV_NOISE[b] for b in ("gyro", "accel", "gyro_bias", "accel_bias"))


_I3 = np.eye(3)
_H_POSE_YAW = np.zeros((4, _N))  # a pose's rows: its position (the yaw's are the attitude's)
_H_POSE_YAW[0:3, _POS] = _I3
# An odometry observation's rows (position, velocity, yaw) by part
_ODO_ROWS = {"pos": np.arange(0, 3), "vel": np.arange(3, 6), "yaw": np.arange(6, 7)}
# The odometry frame's drift (odometry_mode="relative"), after the 15: its position offset and
# its yaw, ``p_odo = p + d_p``, ``yaw_odo = yaw + d_yaw``, ``v_odo = Rz(d_yaw) v``
_DP = slice(_N, _N + 3)
_DYAW = _N + 3
_DSCALE = _N + 4  # the odometry's scale error: its motion is (1 + s) times the true one
_N_DRIFT = 5


@dataclass(frozen=True, slots=True)
class NavKinematics:
    """3-D strapdown integration (batched over leading axes). The attitude travels as a
    flattened rotation matrix ``R_W_B`` (9,) so the output predictor's hot loop needs no
    quaternion conversions."""

    gravity_m_s2: float = GRAVITY_M_S2

    def integrate(
        self,
        pos: FloatArray,
        vel: FloatArray,
        att: FloatArray,
        gyro: FloatArray,
        accel: FloatArray,
        dt_s: FloatArray | float,
        dtheta_corr: FloatArray | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        if isinstance(dt_s, float) and att.ndim == 1:
            # One state (the output predictor's hot path): one compiled step.
            corr = _NO_CORRECTION if dtheta_corr is None else dtheta_corr
            return _strapdown_one(pos, vel, att, gyro, accel, dt_s, corr, self.gravity_m_s2)
        dt = np.asarray(dt_s, dtype=np.float64)
        dtv = dt[..., None] if dt.ndim else dt
        dtheta = np.asarray(gyro, dtype=np.float64) * dtv
        if dtheta_corr is not None:
            dtheta = dtheta + dtheta_corr
        R = np.asarray(att, dtype=np.float64).reshape(*np.shape(att)[:-1], 3, 3)
        R_new = R @ so3_exp(dtheta)
        a_W = np.einsum("...ij,...j->...i", R_new, np.asarray(accel, dtype=np.float64))
        a_W[..., 2] -= self.gravity_m_s2
        vel_new = vel + dtv * a_W
        pos_new = pos + dtv * vel_new
        return pos_new, vel_new, R_new.reshape(*R_new.shape[:-2], 9)

    def integrate_ring(
        self, ring: tuple[FloatArray, FloatArray, FloatArray], src: int, dst: int,
        imu: ImuSample, biases: tuple[FloatArray, FloatArray], dt_s: float,
        dtheta_corr: FloatArray,
    ) -> None:  # fmt: skip
        """:meth:`integrate` of the ring's row ``src`` into its row ``dst``, in one kernel."""
        _strapdown_ring(ring, src, dst, imu.gyro_rad_s, imu.accel_m_s2, biases, dt_s,
                        dtheta_corr, self.gravity_m_s2)  # fmt: skip

    @property
    def output_names(self) -> tuple[str, ...]:
        return _OUTPUT_NAMES

    def attitude_error(self, att_target: FloatArray, att: FloatArray) -> FloatArray:
        """Body-frame rotation vector taking ``att`` onto ``att_target``."""
        return _rotation_error(att_target, att)

    def correct_ring(
        self, ring: tuple[FloatArray, FloatArray, FloatArray], ring_t: NDArray[np.int64],
        oldest: int, nav: NavState, integrals: tuple[FloatArray, FloatArray],
        gains: tuple[float, float, float], propagate: bool,
    ) -> FloatArray:  # fmt: skip
        """:func:`~quadnav.estimation.horizon.correct_ring` in one kernel."""
        dtheta = np.empty(3)
        _correct_ring(ring, ring_t, oldest, nav.pos, nav.vel, nav.att, integrals, gains,
                      propagate, dtheta)  # fmt: skip
        return dtheta

    def to_estimate(
        self,
        nav: NavState,
        x: FloatArray,
        names: tuple[str, ...],
        P: FloatArray | None,
        w_B: FloatArray | None = None,
    ) -> StateEstimate:
        p, v, q = np.empty(3), np.empty(3), np.empty(4)
        _estimate_parts(nav.pos, nav.vel, nav.att, p, v, q)
        return StateEstimate(
            t_ns=nav.t_ns,
            p_W_B=p,
            v_W_B=v,
            q_W_B_xyzw=q,
            x=x,
            names=names,
            P=P,
            w_B=w_B,
        )

    def output_estimate(
        self, nav: NavState, gyro: FloatArray | None, bias_g: FloatArray
    ) -> StateEstimate:
        """:meth:`to_estimate` of the output predictor's state, its arrays (copies, the
        quaternion, ``x``, the body rate) from one kernel (hundreds of times a second)."""
        pos, vel, att = nav.pos, nav.vel, nav.att
        p, v, q = np.empty(3), np.empty(3), np.empty(4)
        x = np.empty(len(pos) + len(vel) + len(att))
        if gyro is None or gyro.shape != bias_g.shape:
            _output_parts(pos, vel, att, _NO_CORRECTION, _NO_CORRECTION, p, v, q, x, None)
            return StateEstimate.from_checked(nav.t_ns, p, v, q, x, _OUTPUT_NAMES, None, None)
        w = np.empty(3)
        _output_parts(pos, vel, att, gyro, bias_g, p, v, q, x, w)
        return StateEstimate.from_checked(nav.t_ns, p, v, q, x, _OUTPUT_NAMES, None, w)


_OUTPUT_NAMES = NAV_OUTPUT.names
_NO_CORRECTION = np.zeros(3)


@njit
def _strapdown_one(
    pos: FloatArray, vel: FloatArray, att: FloatArray, gyro: FloatArray, accel: FloatArray,
    dt: float, dtheta_corr: FloatArray, g: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:  # fmt: skip
    """One state's :meth:`NavKinematics.integrate`: ``R' = R Exp(gyro dt + corr)`` (Rodrigues,
    as :func:`so3_exp`), ``v' = v + dt (R' accel - g z)``, ``p' = p + dt v'``; ``att`` and the
    returned attitude are flattened rotation matrices."""
    p1, v1, R1 = np.empty(3), np.empty(3), np.empty(9)
    _strapdown_into(pos, vel, att, gyro, accel, dt, dtheta_corr, g, p1, v1, R1)
    return p1, v1, R1


@njit
def _strapdown_ring(
    ring: tuple[FloatArray, FloatArray, FloatArray], src: int, dst: int, gyro: FloatArray,
    accel: FloatArray, biases: tuple[FloatArray, FloatArray], dt: float,
    dtheta_corr: FloatArray, g: float,
) -> None:  # fmt: skip
    """:func:`_strapdown_one` of the ring's row ``src`` (positions, velocities, attitudes)
    into its row ``dst``, with the readings less the ``biases`` (gyro, accelerometer)."""
    pos, vel, att = ring
    w, f = np.empty(3), np.empty(3)
    for k in range(3):
        w[k] = gyro[k] - biases[0][k]
        f[k] = accel[k] - biases[1][k]
    _strapdown_into(
        pos[src], vel[src], att[src], w, f, dt, dtheta_corr, g, pos[dst], vel[dst], att[dst]
    )


@njit
def _strapdown_into(
    pos: FloatArray, vel: FloatArray, att: FloatArray, gyro: FloatArray, accel: FloatArray,
    dt: float, dtheta_corr: FloatArray, g: float, p1: FloatArray, v1: FloatArray,
    R1: FloatArray,
) -> None:  # fmt: skip
    """:func:`_strapdown_one`'s step into ``p1``, ``v1``, ``R1`` (not the inputs' arrays)."""
    dth = np.empty(3)
    for k in range(3):
        dth[k] = gyro[k] * dt + dtheta_corr[k]
    E = so3_exp_one(dth)
    for i in range(3):
        for j in range(3):
            R1[3 * i + j] = (
                att[3 * i] * E[0, j] + att[3 * i + 1] * E[1, j] + att[3 * i + 2] * E[2, j]
            )
    for i in range(3):
        a = R1[3 * i] * accel[0] + R1[3 * i + 1] * accel[1] + R1[3 * i + 2] * accel[2]
        if i == 2:
            a -= g
        v1[i] = vel[i] + dt * a
        p1[i] = pos[i] + dt * v1[i]


@njit
def _estimate_parts(
    pos: FloatArray, vel: FloatArray, att: FloatArray, p: FloatArray, v: FloatArray,
    q: FloatArray,
) -> None:  # fmt: skip
    """:meth:`NavKinematics.to_estimate`'s arrays: copies of ``pos`` and ``vel`` into ``p`` and
    ``v``, the quaternion of the flattened rotation matrix ``att`` into ``q``."""
    R = np.empty((3, 3))
    for k in range(3):
        p[k], v[k] = pos[k], vel[k]
        R[k, 0], R[k, 1], R[k, 2] = att[3 * k], att[3 * k + 1], att[3 * k + 2]
    q[:] = quat_xyzw_one(R)


@njit
def _output_parts(
    pos: FloatArray, vel: FloatArray, att: FloatArray, gyro: FloatArray, bias_g: FloatArray,
    p: FloatArray, v: FloatArray, q: FloatArray, x: FloatArray, w: FloatArray | None,
) -> None:  # fmt: skip
    """:meth:`NavKinematics.output_estimate`'s arrays: :func:`_estimate_parts`' ``p``, ``v``,
    ``q``, ``x = concatenate([pos, vel, att])`` and (unless None) ``w = gyro - bias_g``."""
    _estimate_parts(pos, vel, att, p, v, q)
    if w is not None:
        for k in range(3):
            w[k] = gyro[k] - bias_g[k]
    n_p, n_v = pos.shape[0], vel.shape[0]
    for k in range(n_p):
        x[k] = pos[k]
    for k in range(n_v):
        x[n_p + k] = vel[k]
    for k in range(att.shape[0]):
        x[n_p + n_v + k] = att[k]


@njit
def _state_row(
    R: FloatArray, v: FloatArray, p: FloatArray, bg: FloatArray, ba: FloatArray,
    P_all: FloatArray, row: FloatArray, P: FloatArray,
) -> None:  # fmt: skip
    """:meth:`NavEkf.state_row`."""
    q = quat_xyzw_one(R)
    for k in range(3):
        row[k], row[3 + k], row[10 + k], row[13 + k] = p[k], v[k], bg[k], ba[k]
    for k in range(4):
        row[6 + k] = q[k]
    for i in range(_N):
        for j in range(_N):
            P[i, j] = P_all[i, j]


@njit
def _correct_ring(
    ring: tuple[FloatArray, FloatArray, FloatArray], ring_t: NDArray[np.int64], oldest: int,
    pos: FloatArray, vel: FloatArray, att: FloatArray, integrals: tuple[FloatArray, FloatArray],
    gains: tuple[float, float, float], propagate: bool, dtheta: FloatArray,
) -> None:  # fmt: skip
    """:meth:`NavKinematics.correct_ring`: the attitude error of the ring's ``oldest`` row
    times the attitude gain into ``dtheta``, and :func:`_pi_correct` of the ring."""
    err = _rotation_error(att, ring[2][oldest])
    for k in range(3):
        dtheta[k] = err[k] * gains[0]
    _pi_correct(ring_t, ring[0], ring[1], oldest, pos, vel, integrals[0], integrals[1],
                gains[1], gains[2], propagate)  # fmt: skip


@njit
def _rotation_error(att_target: FloatArray, att: FloatArray) -> FloatArray:
    """``so3_log(R^T R_target)`` of two flattened rotation matrices (as :func:`so3_log`)."""
    M = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            M[i, j] = (
                att[i] * att_target[j]
                + att[3 + i] * att_target[3 + j]
                + att[6 + i] * att_target[6 + j]
            )
    return so3_log_one(M)


def nav_jacobians(
    R_new: FloatArray, f: FloatArray, w: FloatArray, dt: float
) -> tuple[FloatArray, FloatArray]:
    """Error-state transition ``F`` (15x15) and noise input ``G`` (15x12, inputs n_g, n_a, n_bg,
    n_ba) of one prediction step, for ``R' = R Exp(w dt)``, ``v' = v + dt (R' f + g)``."""
    A = so3_exp(w * dt).T  # Exp(-w dt)
    Rf = R_new @ skew(f)
    F = np.eye(_N)
    F[_ATT, _ATT] = A
    F[_ATT, _BG] = -dt * _I3
    F[_VEL, _ATT] = -dt * Rf @ A
    F[_VEL, _BG] = dt * dt * Rf
    F[_VEL, _BA] = -dt * R_new
    F[_POS, _ATT] = dt * F[_VEL, _ATT]
    F[_POS, _VEL] = dt * _I3
    F[_POS, _BG] = dt * F[_VEL, _BG]
    F[_POS, _BA] = dt * F[_VEL, _BA]
    G = np.zeros((_N, NAV_NOISE.size))
    G[_ATT, _N_G] = -dt * _I3
    G[_VEL, _N_G] = dt * dt * Rf
    G[_VEL, _N_A] = -dt * R_new
    G[_POS, _N_G] = dt * G[_VEL, _N_G]
    G[_POS, _N_A] = dt * G[_VEL, _N_A]
    G[_BG, _N_BG] = _I3
    G[_BA, _N_BA] = _I3
    return F, G


def gate_thresholds(gate_sigma: float, dims: tuple[int, ...]) -> dict[int, float]:
    """Chi-square thresholds of a gate of ``gate_sigma`` standard deviations: ``gate_sigma**2``
    in one dimension (PX4's test ratio ``innov^2 / (gate^2 var)``), and in ``k`` dimensions the
    threshold with the same tail probability. The probability is carried as a tail (never as
    ``1 - tail``, which rounds to 1 from 8.5 sigma); where even the tail underflows (beyond
    about 37 sigma) the tail's asymptote ``x + (k - 1) ln x`` stands in."""
    x = float(gate_sigma) ** 2
    tail = float(chi2_sf(x, 1))
    out: dict[int, float] = {}
    for k in dims:
        if k == 1:
            out[k] = x
        elif tail > 0.0:
            out[k] = float(chi2_isf(tail, k))
        else:
            out[k] = x + (k - 1) * math.log(x)
    return out


#: What of an :class:`~quadnav.messages.OdometrySample` the filter can fuse (PX4's
#: ``EKF2_EV_CTRL`` bits): its position, its world velocity, its yaw.
ODOMETRY_PARTS = ("pos", "vel", "yaw")
#: How the filter takes an odometry (:attr:`NavEkfConfig.odometry_mode`).
ODOMETRY_MODES = ("absolute", "relative")


@dataclass(slots=True)
class _FrameAnchor:
    """An external source's frame in the filter's: ``p_W = p_W0 + Rz(yaw) (p_V - p_V0)``."""

    counter: int
    yaw: float
    p_V0: FloatArray
    p_W0: FloatArray
    n: int  # poses averaged into the anchor so far


@dataclass(frozen=True, slots=True, kw_only=True)
class NavEkfConfig:
    """IMU noise per sample (``*_sigma``) and bias random walk per sqrt(second)."""

    gyro_sigma_rad_s: float = 0.005
    accel_sigma_m_s2: float = 0.05
    gyro_bias_rw_rad_s_sqrt_s: float = 1e-4
    accel_bias_rw_m_s2_sqrt_s: float = 1e-3
    gravity_m_s2: float = GRAVITY_M_S2
    gate_probability: float = 0.9999
    # The innovation gate in standard deviations, as PX4 sets it (``EKF2_*_GATE``); when given it
    # replaces ``gate_probability`` (which cannot express gates of 8.5 sigma and more: the
    # probability rounds to 1). A k-dimensional test keeps the 1-D gate's tail probability.
    gate_sigma: float | None = None
    reset_after_s: float = 2.0  # a source rejected this long resets the states it observes
    datum_lla: tuple[float, float, float] | None = (
        None  # GNSS origin of the world frame; None: first fix
    )
    mag_declination_rad: float = 0.0  # east of true north
    # External vision frame: "world" fuses its position and yaw as the navigation frame's;
    # "rotate" is PX4's rotated external vision (thesis 000 eqs 3.7-3.8): the heading comes from
    # elsewhere (the magnetometer), the yaw between the vision frame and the filter's is
    # estimated from the two attitudes and the vision position is rotated by it.
    vision_frame: str = "world"
    vision_rotation_gain: float = 0.05  # low-pass gain per sample of the estimated frame yaw
    vision_anchor_samples: int = 30  # poses averaged to anchor a vision frame after a reset
    # A barometer bias estimated beside the state, as PX4's EKF2 does (its ``baro_bias_nsd``,
    # 0.13 m/s/sqrt(Hz)); None: barometer heights are taken as they come.
    baro_bias_nsd_m_s: float | None = None
    baro_bias_var0_m2: float = 0.1  # the bias's initial variance (PX4's: 0.1)
    # Clipped accelerometer axes (a ClippedImuSample) get this process noise (PX4's 4.9).
    clipped_accel_sigma_m_s2: float = BADACC_NOISE_M_S2
    # PX4's accelerometer-bias learning gate (EKF2_ABL_GYRLIM, _ACCLIM, _TAU); None: always learn.
    accel_bias_learn_gyro_limit_rad_s: float | None = None
    accel_bias_learn_accel_limit_m_s2: float = 25.0
    accel_bias_learn_tau_s: float = 0.5
    # After clipping, re-level once at rest this long (Releveller); None: never.
    relevel_at_rest_s: float | None = None
    terrain_z_m: float = 0.0  # height of the flat ground the range finder sees
    range_max_tilt_rad: float = 0.7  # range (and flow) readings at larger tilts are not fused
    # Optical flow (PX4 EKF2's defaults): noise from the sample's quality, EKF2_OF_N_MIN at 255
    # and EKF2_OF_N_MAX at EKF2_OF_QMIN; samples below that quality or above the sensor's
    # largest rate (SENS_FLOW_MAXR) are refused and counted; its own innovation gate
    # (EKF2_OF_GATE, sigma) over the 2-D innovation; fused only at heights above the floor
    # (terrain_z_m) of at least flow_min_height_m (PX4FLOW's sonar: 0.3 m).
    flow_noise_min_rad_s: float = 0.15
    flow_noise_max_rad_s: float = 0.5
    flow_quality_min: int = 1
    flow_max_rate_rad_s: float = 8.0
    flow_gate_sigma: float = 3.0
    flow_min_height_m: float = 0.3
    # External odometry (PX4's external vision ODOMETRY): the parts fused (EKF2_EV_CTRL), the
    # floors under the message's own variances (EKF2_EVP_NOISE, EKF2_EVV_NOISE,
    # EKF2_EVA_NOISE: each variance is at least the floor squared), the innovation gate in
    # standard deviations over the fused parts together (EKF2_EVP_GATE) and the least quality
    # taken (EKF2_EV_QMIN). Its frame is anchored as an external pose's (``vision_frame``).
    odometry_fuse: tuple[str, ...] = ODOMETRY_PARTS
    odometry_pos_noise_m: float = 0.1
    odometry_vel_noise_m_s: float = 0.1
    odometry_yaw_noise_rad: float = 0.05
    odometry_gate_sigma: float = 5.0
    odometry_quality_min: int = 0
    # How the odometry is taken. "absolute" (PX4's): its position and yaw as fixes of the
    # navigation frame's. "relative": a VIO's position and yaw drift (they are unobservable to
    # it), so its frame's offset (position and yaw) is four states beside the 15, a random walk
    # of these rates from where the frame was anchored: the filter takes the odometry's
    # motion, its absolute position and yaw only as far as the drift allows.
    odometry_mode: str = "absolute"
    odometry_drift_m_sqrt_s: float = 0.02
    odometry_drift_yaw_rad_sqrt_s: float = 0.004
    # Relative mode: the odometry's scale error ``s`` as a fifth state (its motion is (1 + s)
    # times the true motion, as a monocular VIO's scale is off by a few per cent and wanders):
    # its sigma where the frame is anchored and its random walk. 0 and 0: no scale error (the
    # state stays at zero, exactly).
    odometry_scale_sigma: float = 0.0
    odometry_scale_rw_sqrt_s: float = 0.0
    # Relative mode: the frame's drift also grows by what the odometry says its own uncertainty
    # grew by from one sample to the next (its position covariance and yaw variance, the rise
    # only), as a VIO's marginal covariance grows with its drift; its measurement noise is then
    # its floors alone (its noise from sample to sample), not its whole covariance, which a
    # white noise would average away at the odometry's rate.
    odometry_drift_from_covariance: bool = False
    # What a change of an external pose's or odometry's ``reset_counter`` means. By default the
    # source started a new frame (a VIO re-initialised at its own origin): the new frame is
    # anchored where the filter is, so the jump is not taken as motion. The sources named in
    # ``follow_resets`` (by their ``source``) correct themselves in the same frame when their
    # counter changes (a loop closure, a relocalization in a saved map): the filter follows
    # them as PX4's EKF2 follows external vision that leads, resetting its position, heading and
    # velocity to the measurement as far as it fuses them (absolute), or restarting the frame's
    # drift from zero (relative).
    follow_resets: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        require_positive(
            self,
            (
                "gyro_sigma_rad_s",
                "accel_sigma_m_s2",
                "gyro_bias_rw_rad_s_sqrt_s",
                "accel_bias_rw_m_s2_sqrt_s",
                "gravity_m_s2",
            ),
        )
        require_positive(
            self,
            (
                "flow_noise_min_rad_s",
                "flow_noise_max_rad_s",
                "flow_max_rate_rad_s",
                "flow_gate_sigma",
                "flow_min_height_m",
            ),
        )
        if not 0 <= self.flow_quality_min <= 255:
            raise EstimationError(
                f"NavEkfConfig.flow_quality_min must lie in 0..255, got {self.flow_quality_min}"
            )
        optional = ("gate_sigma", "baro_bias_nsd_m_s", "baro_bias_var0_m2", "clipped_accel_sigma_m_s2",
                    "accel_bias_learn_gyro_limit_rad_s", "relevel_at_rest_s")  # fmt: skip
        require_positive(self, tuple(n for n in optional if getattr(self, n) is not None))
        if self.gate_sigma is None and not 0 < self.gate_probability < 1:
            raise EstimationError("NavEkfConfig.gate_probability must lie in (0, 1)")
        if self.vision_frame not in ("world", "rotate"):
            raise EstimationError(
                f"NavEkfConfig.vision_frame must be 'world' or 'rotate', got {self.vision_frame!r}"
            )
        if self.vision_anchor_samples < 1:
            raise EstimationError("NavEkfConfig.vision_anchor_samples must be >= 1")
        if not 0 < self.vision_rotation_gain <= 1:
            raise EstimationError("NavEkfConfig.vision_rotation_gain must lie in (0, 1]")
        self._check_odometry()

    def _check_odometry(self) -> None:
        unknown = [p for p in self.odometry_fuse if p not in ODOMETRY_PARTS]
        if (
            unknown
            or not self.odometry_fuse
            or len(set(self.odometry_fuse)) != len(self.odometry_fuse)
        ):
            raise EstimationError(
                f"NavEkfConfig.odometry_fuse must name some of {', '.join(ODOMETRY_PARTS)} "
                f"once each, got {list(self.odometry_fuse)}"
            )
        require_positive(
            self,
            ("odometry_pos_noise_m", "odometry_vel_noise_m_s", "odometry_yaw_noise_rad",
             "odometry_gate_sigma"),
        )  # fmt: skip
        if not 0 <= self.odometry_quality_min <= 100:
            raise EstimationError(
                f"NavEkfConfig.odometry_quality_min must lie in 0..100, got {self.odometry_quality_min}"
            )
        if self.odometry_mode not in ODOMETRY_MODES:
            raise EstimationError(
                f"NavEkfConfig.odometry_mode must be one of {', '.join(ODOMETRY_MODES)}, "
                f"got {self.odometry_mode!r}"
            )
        require_positive(self, ("odometry_drift_m_sqrt_s", "odometry_drift_yaw_rad_sqrt_s"))
        for name in ("odometry_scale_sigma", "odometry_scale_rw_sqrt_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v <= 1.0):
                raise EstimationError(f"NavEkfConfig.{name} must be within [0, 1], got {v}")
        if self.odometry_mode == "relative" and self.vision_frame != "world":
            raise EstimationError(
                "NavEkfConfig.odometry_mode='relative' estimates the odometry frame's yaw drift "
                "and needs vision_frame='world'"
            )


class NavEkf:
    """The error-state navigation EKF; a :class:`~quadnav.estimation.horizon.DelayedFilter`."""

    #: ``x`` (the nominal state) is laid out as ``layout``; ``P`` and the Jacobians as
    #: ``error_layout``.
    layout: StateLayout = NAV_NOMINAL
    error_layout: StateLayout = NAV_ERROR
    names: tuple[str, ...] = NAV_NOMINAL.names

    def __init__(
        self,
        config: NavEkfConfig,
        *,
        p0: FloatArray,
        v0: FloatArray,
        q0_xyzw: FloatArray,
        P0: FloatArray,
        bg0: FloatArray | None = None,
        ba0: FloatArray | None = None,
    ) -> None:
        P0 = np.asarray(P0, dtype=np.float64)
        if (
            P0.shape != (_N, _N)
            or not np.isfinite(P0).all()
            or np.min(np.linalg.eigvalsh(0.5 * (P0 + P0.T))) < 0
        ):
            raise EstimationError("NavEkf: P0 must be a finite positive semi-definite 15x15 matrix")
        self.config = config
        self.kinematics = NavKinematics(config.gravity_m_s2)
        self.p = np.asarray(p0, dtype=np.float64).copy()
        self.v = np.asarray(v0, dtype=np.float64).copy()
        self.R = Rotation.from_quat(q0_xyzw).as_matrix()
        self.bg = np.zeros(3) if bg0 is None else np.asarray(bg0, dtype=np.float64).copy()
        self.ba = np.zeros(3) if ba0 is None else np.asarray(ba0, dtype=np.float64).copy()
        self._P = 0.5 * (P0 + P0.T)
        # The odometry frame's drift (relative mode): d_p (3), d_yaw and the scale error, zero
        # where the frame is anchored; its covariance extends P (the 15 first, as the P the
        # filter reports).
        self.odometry_drift = np.zeros(_N_DRIFT)
        self._relative = config.odometry_mode == "relative"
        # per odometry source: its counter, position and yaw (co)variance when last fused
        self._odometry_cov: dict[str, tuple[int, FloatArray, float]] = {}
        if self._relative:
            self._P = np.pad(self._P, (0, _N_DRIFT))
            self._P[_DSCALE, _DSCALE] = config.odometry_scale_sigma**2
        self._gates = (
            {k: float(chi2_ppf(config.gate_probability, k)) for k in (1, 2, 3, 4, 6)}
            if config.gate_sigma is None
            else gate_thresholds(config.gate_sigma, (1, 2, 3, 4, 6))
        )
        self._odometry_gates = gate_thresholds(config.odometry_gate_sigma, tuple(range(1, 8)))
        # the observation models by sample type (quadnav.estimation.nav_observations)
        self.observations = builtin_observations(gate_thresholds(config.flow_gate_sigma, (2,))[2])
        # the body rate and the specific force (biases removed) of the last prediction
        self._w_B, self._f_B = np.zeros(3), np.zeros(3)
        # GNSS fixes in the world frame (ENU): about the datum given, or the first fix put
        # where the filter is then
        self._navsat: NavSatTransform | None = (
            None if config.datum_lla is None else NavSatTransform(GeoDatum(*config.datum_lla))
        )
        self._g_W = np.array([0.0, 0.0, -config.gravity_m_s2])
        self._jac_dt = math.nan
        self._n_predict = 0
        self._F, self._G = np.eye(_N), np.zeros((_N, NAV_NOISE.size))
        self._q = np.zeros(NAV_NOISE.size)
        # External-pose frames: per source, the last reset counter and the transform
        # (yaw, offset) that maps its frame onto the filter's, re-anchored on each reset.
        self._ev_anchor: dict[str, _FrameAnchor] = {}
        self._follow_pending: set[str] = set()  # sources whose next pose resets the filter
        self._last_accepted_ns: dict[str, int] = {}
        self._position_fused_ns: dict[str, int] = {}  # per source, its last position accepted
        self.events: list[tuple[int, str]] = []
        nsd = config.baro_bias_nsd_m_s
        self.baro_bias: BiasEstimator | None = (
            None if nsd is None else BiasEstimator(nsd, var=config.baro_bias_var0_m2)
        )
        lim = config.accel_bias_learn_gyro_limit_rad_s
        self.bias_gate: BiasLearningGate | None = (
            None
            if lim is None
            else BiasLearningGate(
                gyro_limit_rad_s=lim,
                accel_limit_m_s2=config.accel_bias_learn_accel_limit_m_s2,
                tau_s=config.accel_bias_learn_tau_s,
            )
        )
        self.n_clipped = 0
        rl = config.relevel_at_rest_s
        self.releveller: Releveller | None = None if rl is None else Releveller(window_s=rl)

    # -- the DelayedFilter protocol --------------------------------------------------------
    @property
    def x(self) -> FloatArray:
        rv = so3_log(self.R)
        return np.concatenate([rv, self.v, self.p, self.bg, self.ba])

    @property
    def P(self) -> FloatArray:
        """The covariance of the 15 error states (without the odometry drift's)."""
        return self._P[:_N, :_N]

    @property
    def q_xyzw(self) -> FloatArray:
        return quat_xyzw_from_matrix(self.R)

    def nav(self, t_ns: int, *, copy: bool = True) -> NavState:
        if not copy:
            return NavState(t_ns, self.p, self.v, self.R.ravel())
        return NavState(t_ns, self.p.copy(), self.v.copy(), self.R.ravel().copy())

    def state_row(self, row: FloatArray, P: FloatArray) -> None:
        """The state for a log, in one kernel: ``p``, ``v``, the quaternion (xyzw, as
        :func:`quat_xyzw_from_matrix`), ``b_g``, ``b_a`` into ``row`` (16); the 15 error
        states' covariance into ``P`` (15x15)."""
        _state_row(self.R, self.v, self.p, self.bg, self.ba, self._P, row, P)

    def can_fuse(self, obs: Sample) -> bool:
        """Whether a model is registered for the sample's type (or a base of it) and accepts
        this sample (PX4's quality checks of a flow or an odometry sample)."""
        model = self._model(obs)
        return model is not None and model.accepts(self, obs)

    def register(self, kind: type, model: ObservationModel) -> None:  # type: ignore[type-arg]
        """Fuse samples of ``kind`` (and of its subclasses without a model of their own) with
        ``model``: a new sensor joins the filter so, with no edit of the filter."""
        self.observations[kind] = model

    def _model(self, obs: object) -> ObservationModel | None:  # type: ignore[type-arg]
        for kind in type(obs).__mro__:
            model = self.observations.get(kind)
            if model is not None:
                return model
        return None

    def imu_biases(self) -> tuple[FloatArray, FloatArray]:
        return self.bg, self.ba

    def _set_step(self, dt: float) -> None:
        """The blocks of ``F`` and ``G`` that depend only on the step, and the inputs' noise,
        set when the step size changes (the rest is filled every step by :func:`_propagate`)."""
        F, G = nav_jacobians(np.eye(3), np.zeros(3), np.zeros(3), dt)
        self._F, self._G, self._jac_dt = F, G, dt
        c = self.config
        self._q = np.array(
            [c.gyro_sigma_rad_s**2] * 3
            + [c.accel_sigma_m_s2**2] * 3
            + [c.gyro_bias_rw_rad_s_sqrt_s**2 * dt] * 3
            + [c.accel_bias_rw_m_s2_sqrt_s**2 * dt] * 3
        )

    def predict(self, imu: ImuSample, dt_s: float) -> None:
        if dt_s != self._jac_dt:
            self._set_step(dt_s)
        clipped = clip_axes(imu)
        q = self._q
        if clipped:  # PX4: a saturated axis's reading is as uncertain as BADACC_BIAS_PNOISE
            self.n_clipped += 1
            q = q.copy()
            for k in range(3):
                if clipped >> k & 1:
                    i = _N_A.start + k
                    q[i] = max(q[i], self.config.clipped_accel_sigma_m_s2**2)
        # The biases removed, the mean, F and G's state-dependent blocks, and (without the
        # drift states) P, in one compiled kernel, into new arrays (what was read before
        # stays as it was).
        w, f, R, v, p = np.empty(3), np.empty(3), np.empty((3, 3)), np.empty(3), np.empty(3)
        P = self._P if self._relative else np.empty_like(self._P)
        _propagate(
            self.R, self.v, self.p, imu.gyro_rad_s, imu.accel_m_s2, self.bg, self.ba, dt_s,
            self._g_W, self._F, self._G, q, self._P, not self._relative, (w, f, R, v, p, P),
        )  # fmt: skip
        self._w_B, self._f_B, self.R, self.v, self.p = w, f, R, v, p
        if self._relative:
            P = self._predict_with_drift(self._F, self._G, q, dt_s)
        if self.bias_gate is not None:
            self.bias_gate.apply(P, _BA.start, self.bias_gate.update(w, f, clipped, dt_s))
        self._n_predict += 1
        if self._n_predict % 32 == 0:  # rounding makes P drift from symmetry, slowly
            P = 0.5 * (P + P.T)
        self._P = P
        if self.releveller is not None:
            if clipped:
                self.releveller.on_clip(self.ba, np.diag(P)[_BA].copy())
            f_rest = self.releveller.update(
                w, imu.accel_m_s2, dt_s, self.config.gravity_m_s2, self.p
            )
            if f_rest is not None:
                self._relevel(imu.t_ns, f_rest, self.releveller)
        if self.baro_bias is not None:
            self.baro_bias.predict(dt_s)

    def _predict_with_drift(
        self, F: FloatArray, G: FloatArray, q: FloatArray, dt_s: float
    ) -> FloatArray:
        """The covariance predicted with the odometry frame's drift beside the 15 states: a
        random walk, its position offset also growing as the frame's yaw error turns the motion
        and its scale error stretches it (``d_p' = d_p + dt (d_yaw z x v + s v)``)."""
        c = self.config
        zxv = np.array([-self.v[1], self.v[0], 0.0])
        d = self.odometry_drift
        d[0:3] += dt_s * (d[3] * zxv + d[4] * self.v)
        Fa = np.eye(_N + _N_DRIFT)
        Fa[:_N, :_N] = F
        Fa[_DP, _DYAW] = dt_s * zxv
        Fa[_DP, _DSCALE] = dt_s * self.v
        P = Fa @ self._P @ Fa.T
        P[:_N, :_N] += (G * q) @ G.T
        P[_DP, _DP] += np.eye(3) * c.odometry_drift_m_sqrt_s**2 * dt_s
        P[_DYAW, _DYAW] += c.odometry_drift_yaw_rad_sqrt_s**2 * dt_s
        P[_DSCALE, _DSCALE] += c.odometry_scale_rw_sqrt_s**2 * dt_s
        return P

    def _relevel(self, t_ns: int, f_mean: FloatArray, rl: Releveller) -> None:
        """Roll and pitch from the mean specific force at rest (less the bias from before the
        clipping), the heading kept; velocity zero; the bias back; their covariances reset; the
        position back to where the rest began (what it moved since was velocity error)."""
        f = f_mean - rl.bias_before
        roll, pitch = math.atan2(f[1], f[2]), math.atan2(-f[0], math.hypot(f[1], f[2]))
        R_new = Rotation.from_euler("ZYX", [yaw_of(self.R), pitch, roll]).as_matrix()
        # how far gravity's direction in the body moved (not the body's z axis in the world,
        # which also turns with the heading kept at a large tilt)
        moved_deg = math.degrees(math.acos(min(1.0, float(self.R[2, :] @ R_new[2, :]))))
        j = yaw_jacobian(self.R)
        var_yaw = float(j @ self._P[_ATT, _ATT] @ j)
        P = self._P
        for blk in (_ATT, _VEL, _BA):
            P[blk, :] = 0.0
            P[:, blk] = 0.0
        P[_ATT, _ATT] = R_new.T @ np.diag([0.02**2, 0.02**2, var_yaw]) @ R_new  # world tilt, yaw
        P[_VEL, _VEL] = np.eye(3) * 0.1**2
        P[_BA, _BA] = np.diag(rl.bias_var_before)
        back_m = float(np.linalg.norm(self.p - rl.p_rest))
        self.R, self.v, self.ba = R_new, np.zeros(3), rl.bias_before.copy()
        self.p = rl.p_rest.copy()
        self.events.append(
            (
                t_ns,
                f"re-levelled at rest after accelerometer clipping: tilt moved {moved_deg:.1f} deg, "
                f"velocity zeroed, position moved back {back_m:.2f} m to where the rest began",
            )
        )

    def fuse(self, obs: Sample) -> FusionResult:
        """The sample fused by its type's model (:mod:`quadnav.estimation.nav_observations`)."""
        model = self._model(obs)
        if model is None:
            raise EstimationError(f"the navigation EKF cannot fuse {type(obs).__name__}")
        return model.fuse(self, obs)

    # -- what the observation models use -------------------------------------------------
    @property
    def body_rate_rad_s(self) -> FloatArray:
        """The body rate, biases removed, of the last prediction."""
        return self._w_B

    @property
    def specific_force_m_s2(self) -> FloatArray:
        """The specific force, bias removed, of the last prediction (body frame)."""
        return self._f_B

    def update(
        self, r: FloatArray, H: FloatArray, Rn: FloatArray, *, gate: float | None = None
    ) -> FusionResult:
        """One update: innovation ``r``, Jacobian ``H`` over the 15 error states (or with the
        odometry drift's after them), noise ``Rn``; refused beyond the chi-square gate of its
        size (or ``gate``)."""
        return self._update(r, H, Rn, gate=gate)

    def reset_velocity(self, t_ns: int, v: FloatArray, var: FloatArray, source: str) -> None:
        """Set the velocity to ``v`` with variances ``var``, its correlations forgotten, and
        say so: what a zero-velocity update does when the velocity is too far off to fuse (a
        hard touchdown), so that the position is not dragged along through them."""
        off = float(np.linalg.norm(self.v - v))
        self.v = np.asarray(v, dtype=np.float64).copy()
        self._reset_entries(_VEL, np.asarray(var, dtype=np.float64))
        self._last_accepted_ns[source] = t_ns
        self.events.append((t_ns, f"{source}: velocity {off:.2f} m/s off, reset to it"))

    def gated_update(
        self,
        obs: Stamped,
        r: FloatArray,
        H: FloatArray,
        Rn: FloatArray,
        p_meas: FloatArray | None,
        *,
        gate: float | None = None,
    ) -> FusionResult:
        """:meth:`update`, and when the sample's source has been refused ``reset_after_s``,
        the states it observes reset to it (``p_meas``: the position it measures; else the
        height, or a magnetometer's heading)."""
        return self._gated(obs, r, H, Rn, p_meas, gate=gate)

    def gps_to_enu(self, obs: GpsSample) -> FloatArray:
        """A fix in the world frame: ENU about the datum (the first fix when none was given)."""
        fix = GeoDatum(obs.lat_deg, obs.lon_deg, obs.alt_m)
        if self._navsat is None:
            p = self.p
            self._navsat = NavSatTransform(fix, p_W_E_m=(float(p[0]), float(p[1]), float(p[2])))
        p_W: FloatArray = self._navsat.to_world(fix)[0]
        return p_W

    def vision_frame_yaw(self, source: str = "vision") -> float | None:
        """The estimated yaw of the vision frame in the filter's (None before its first pose)."""
        anchor = self._ev_anchor.get(source)
        return None if anchor is None else anchor.yaw

    def _vision_anchor(self, obs: PoseSample | OdometrySample, R_meas: FloatArray) -> _FrameAnchor:
        """The transform from the source's frame to the filter's, re-anchored on a reset (an
        external pose's and an external odometry's alike)."""
        src = obs.source
        rotate = self.config.vision_frame == "rotate"
        anchor = self._ev_anchor.get(src)
        reset = anchor is not None and obs.reset_counter != anchor.counter
        yaw_now = math.remainder(yaw_of(self.R) - yaw_of(R_meas), 2 * math.pi)
        n_avg = self.config.vision_anchor_samples
        # A relative odometry's frame is wherever it started (a VIO's first keyframe, in the
        # air if it started there). While another source holds the position (GNSS), it is
        # anchored where the filter is, as after a reset, as PX4's EKF2 starts its external
        # vision's position bias beside GNSS; alone, its frame is the navigation frame.
        relative = self._relative and isinstance(obs, OdometrySample)
        first_own = anchor is None and relative and self._held_by_another(src, obs.t_ns)
        if anchor is None and not rotate and not first_own:
            # The first frame of an absolute source is the navigation frame itself.
            anchor = _FrameAnchor(obs.reset_counter, 0.0, np.zeros(3), np.zeros(3), n_avg)
        elif anchor is not None and reset and src in self.config.follow_resets:
            anchor.counter = obs.reset_counter  # the same frame, corrected: reset to it
            self._follow_pending.add(src)
        elif anchor is None or reset:
            # (a relative odometry's frame on its first sample: its noise then joins the
            # frame's drift, which the filter estimates, rather than being averaged out)
            n0 = n_avg if first_own else 0
            anchor = _FrameAnchor(obs.reset_counter, yaw_now, obs.p_W_B.copy(), self.p.copy(), n0)
            if reset:
                self.events.append(
                    (obs.t_ns, f"{src}: reset counter {obs.reset_counter}, frame re-anchored")
                )
            if relative and (reset or first_own):
                self._reanchor_drift(first_sample=first_own)
        self._ev_anchor[src] = anchor
        if anchor.n < n_avg:
            # A single noisy pose would freeze its noise into the frame for good: average the
            # frame's yaw and origin over the first poses after (re-)anchoring.
            anchor.n += 1
            anchor.yaw += math.remainder(yaw_now - anchor.yaw, 2 * math.pi) / anchor.n
            Rz = so3_exp(np.array([0.0, 0.0, anchor.yaw]))
            p_V0_i = obs.p_W_B - Rz.T @ (self.p - anchor.p_W0)
            anchor.p_V0 += (p_V0_i - anchor.p_V0) / anchor.n
        elif rotate:
            g = self.config.vision_rotation_gain
            anchor.yaw = math.remainder(
                anchor.yaw + g * math.remainder(yaw_now - anchor.yaw, 2 * math.pi), 2 * math.pi
            )
        return anchor

    def _frame_yaw_spread(self, d_W: FloatArray, sigma_yaw_rad: float) -> FloatArray:
        """Rotated external vision: the frame's yaw is only as good as the filter's heading and
        the source's yaw; its error turns a vector ``d_W`` of the source (the displacement from
        the anchor, a velocity), which the noise must cover (3x3)."""
        J = np.array([-d_W[1], d_W[0], 0.0])
        return (float(self._P[_YAW, _YAW]) + sigma_yaw_rad**2) * np.outer(J, J)

    def fuse_frame_pose(self, obs: PoseSample) -> FusionResult:
        """External vision. ``world``: its position and yaw, in its frame (the navigation frame
        until a reset re-anchors it). ``rotate``: PX4's rotated external vision (thesis 000 eq.
        3.7: ``R_ekf_ev = R_ekf_body R_ev_body^T``, yaw part, low-pass filtered; eq. 3.8: the
        vision position rotated into the filter's axes), position only, the heading coming from
        elsewhere. Either way the frame's origin is anchored on the filter's position at the
        first pose and at every reset, so a jump flagged by the reset counter is not motion."""
        R_meas = rotation_matrix_xyzw(obs.q_W_B_xyzw)
        anchor = self._vision_anchor(obs, R_meas)
        Rz = so3_exp_one(np.array([0.0, 0.0, anchor.yaw]))
        d_W = Rz @ (obs.p_W_B - anchor.p_V0)
        p_W = anchor.p_W0 + d_W
        C = _I3 * obs.sigma_pos_m**2 if obs.cov_p_m2 is None else obs.cov_p_m2
        if self.config.vision_frame == "rotate":
            H = np.zeros((3, _N))
            H[:, _POS] = np.eye(3)
            Rn = Rz @ C @ Rz.T + self._frame_yaw_spread(d_W, obs.sigma_yaw_rad)
            if obs.source in self._follow_pending:
                return self._follow(obs, np.diag(Rn), p=p_W)
            return self._gated(obs, p_W - self.p, H, Rn, p_W)
        H = _H_POSE_YAW.copy()
        H[3, _ATT] = yaw_jacobian(self.R)
        r_yaw = math.remainder(yaw_of(R_meas) + anchor.yaw - yaw_of(self.R), 2 * math.pi)
        r = np.empty(4)
        np.subtract(p_W, self.p, out=r[0:3])
        r[3] = r_yaw
        Rn = np.zeros((4, 4))
        Rn[0:3, 0:3] = Rz @ C @ Rz.T  # (a full covariance, a marker pose's, into the world)
        Rn[3, 3] = obs.sigma_yaw_rad**2
        if obs.source in self._follow_pending:
            return self._follow(obs, np.diag(Rn), p=p_W, dyaw=r_yaw)
        return self._gated(obs, r, H, Rn, p_W, yaw_row=3)

    def fuse_frame_odometry(self, obs: OdometrySample) -> FusionResult:
        """External odometry (PX4's external vision ``ODOMETRY``): the parts of
        ``odometry_fuse`` (position, world velocity, yaw) as one observation with the message's
        covariance (its position-yaw correlation kept), each variance raised to its floor, and
        one gate over them. The frame is anchored as an external pose's: the navigation frame
        (``world``) or rotated onto it (``rotate``: no yaw fused, the frame's yaw error in the
        noise), re-anchored when ``reset_counter`` changes."""
        c = self.config
        R_meas = rotation_matrix_xyzw(obs.q_W_B_xyzw)
        anchor = self._vision_anchor(obs, R_meas)
        Rz = so3_exp(np.array([0.0, 0.0, anchor.yaw]))
        d_W = Rz @ (obs.p_W_B - anchor.p_V0)
        v_W = Rz @ obs.v_W_B
        r_yaw = math.remainder(yaw_of(R_meas) + anchor.yaw - yaw_of(self.R), 2 * math.pi)
        r = np.concatenate([anchor.p_W0 + d_W - self.p, v_W - self.v, [r_yaw]])
        H = np.zeros((7, _N))
        H[0:3, _POS] = np.eye(3)
        H[3:6, _VEL] = np.eye(3)
        H[6, _ATT] = yaw_jacobian(self.R)
        j = world_yaw_jacobian(R_meas)
        Rn = np.zeros((7, 7))
        Rn[0:3, 0:3] = Rz @ obs.cov_pose[0:3, 0:3] @ Rz.T
        Rn[0:3, 6] = Rn[6, 0:3] = Rz @ obs.cov_pose[0:3, 3:6] @ j
        Rn[3:6, 3:6] = Rz @ obs.cov_v @ Rz.T
        Rn[6, 6] = float(j @ obs.cov_pose[3:6, 3:6] @ j)
        floors = [c.odometry_pos_noise_m] * 3 + [c.odometry_vel_noise_m_s] * 3
        if self._relative and c.odometry_drift_from_covariance:
            self._grow_drift(obs, Rn[0:3, 0:3], Rn[6, 6])
            Rn[0:3, 0:3] = Rn[0:3, 6] = Rn[6, 0:3] = Rn[6, 6] = 0.0
        Rn += np.diag(np.maximum(np.square(floors + [c.odometry_yaw_noise_rad]) - np.diag(Rn), 0))
        rotate = c.vision_frame == "rotate"
        parts = [p for p in ODOMETRY_PARTS if p in c.odometry_fuse and not (p == "yaw" and rotate)]
        if rotate:
            sigma_yaw = math.sqrt(Rn[6, 6])
            Rn[0:3, 0:3] += self._frame_yaw_spread(d_W, sigma_yaw)
            Rn[3:6, 3:6] += self._frame_yaw_spread(v_W, sigma_yaw)
        gate = self._odometry_gates[sum(len(_ODO_ROWS[p]) for p in parts)]
        if obs.source in self._follow_pending and not self._relative:
            return self._follow(
                obs, np.diag(Rn),
                p=anchor.p_W0 + d_W if "pos" in parts else None,
                v=v_W if "vel" in parts else None,
                dyaw=float(r[6]) if "yaw" in parts else None,
            )  # fmt: skip
        if obs.source in self._follow_pending:
            self._restart_drift(obs)
            gate = math.inf  # (the correction, taken whole)
        if self._relative:
            r, H = self._drift_terms(r, H)
        rows = np.concatenate([_ODO_ROWS[p] for p in parts])
        Rn = Rn[np.ix_(rows, rows)]
        yaw_row = len(rows) - 1 if "yaw" in parts else None  # (the parts in their order)
        # (what a reset after persistent rejections sets: the odometry less its frame's drift)
        d = self.odometry_drift
        p_meas = anchor.p_W0 + d_W - d[0:3] if "pos" in parts else None
        v_W = so3_exp(np.array([0.0, 0.0, -d[3]])) @ v_W / (1.0 + d[4])
        v_meas = v_W if "vel" in parts and p_meas is None else None
        return self._gated(
            obs, r[rows], H[rows], Rn, p_meas, yaw_row=yaw_row, v_meas=v_meas, gate=gate
        )

    def _follow(
        self, obs: PoseSample | OdometrySample, var: FloatArray, *, p: FloatArray | None = None,
        v: FloatArray | None = None, dyaw: float | None = None,
    ) -> FusionResult:  # fmt: skip
        """A source of ``follow_resets``: its reset counter changed and it corrected
        itself in its frame; reset what it observes (``p``, ``v``, the heading turned by
        ``dyaw``) to it with its variances ``var`` (position 0-2, velocity 3-5, yaw 6 of an
        odometry; position 0-2, yaw 3 of a pose), as PX4's EKF2 does. A relative odometry's
        frame drift starts again from zero. Counted as accepted, with a zero test ratio."""
        src = obs.source
        self._follow_pending.discard(src)
        what = []
        if p is not None:
            self.p = p.copy()
            self._reset_entries(_POS, var[0:3])
            what.append("position")
        if v is not None:
            self.v = v.copy()
            self._reset_entries(_VEL, var[3:6])
            what.append("velocity")
        if dyaw is not None:
            self.R = so3_exp(np.array([0.0, 0.0, dyaw])) @ self.R
            self._reset_entries(slice(_YAW, _YAW + 1), var[-1:])
            what.append("heading")
        if self._relative:
            self._reanchor_drift()
        self._last_accepted_ns[src] = obs.t_ns
        self.events.append(
            (obs.t_ns, f"{src}: reset counter {obs.reset_counter}, "
             f"{', '.join(what) or 'nothing'} reset to it")
        )  # fmt: skip
        return FusionResult(accepted=True, innovation=np.zeros(len(var)), nis=0.0, test_ratio=0.0)

    def _restart_drift(self, obs: OdometrySample) -> None:
        """A relative odometry of ``follow_resets``: its frame was corrected, so its
        drift starts again from zero, known to the odometry's noise floors; the filter then
        takes the corrected odometry through an ungated update (and the next ones), as far as
        its own position is uncertain. (A hard reset to one sample would freeze that sample's
        noise into the position: nothing after it averages it out.)"""
        c = self.config
        self._follow_pending.discard(obs.source)
        self.odometry_drift[:] = 0.0
        var = [c.odometry_pos_noise_m**2] * 3 + [c.odometry_yaw_noise_rad**2]
        var.append(c.odometry_scale_sigma**2)
        self._reset_entries(slice(_N, _N + _N_DRIFT), np.array(var))
        self._last_accepted_ns[obs.source] = obs.t_ns
        self.events.append(
            (obs.t_ns, f"{obs.source}: reset counter {obs.reset_counter}, frame drift restarted")
        )

    def _grow_drift(self, obs: OdometrySample, cov_pos: FloatArray, var_yaw: float) -> None:
        """``odometry_drift_from_covariance``: the frame's drift covariance grows by the rise of
        the odometry's own position covariance ``cov_pos`` (navigation frame) and yaw variance
        ``var_yaw`` since its previous sample of the same frame (its reset counter); a fall
        (the odometry more certain) moves nothing."""
        prev = self._odometry_cov.get(obs.source)
        self._odometry_cov[obs.source] = (obs.reset_counter, cov_pos.copy(), var_yaw)
        if prev is None or prev[0] != obs.reset_counter:
            return
        w, U = np.linalg.eigh(0.5 * (cov_pos - prev[1] + (cov_pos - prev[1]).T))
        self._P[_DP, _DP] += (U * np.maximum(w, 0.0)) @ U.T
        self._P[_DYAW, _DYAW] += max(var_yaw - prev[2], 0.0)

    def _drift_terms(self, r: FloatArray, H: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Relative mode: an odometry's innovation ``r`` (position, velocity, yaw) and its
        Jacobian ``H`` (7x15) with the frame's drift: ``p_odo = p + d_p``, ``v_odo = (1 + s)
        Rz(d_yaw) v``, ``yaw_odo = yaw + d_yaw`` (H becomes 7x20)."""
        d = self.odometry_drift
        Rd = so3_exp(np.array([0.0, 0.0, d[3]]))
        v_turned = Rd @ self.v
        v_pred = (1.0 + d[4]) * v_turned
        r = r.copy()
        r[0:3] -= d[0:3]
        r[3:6] += self.v - v_pred
        r[6] = math.remainder(r[6] - d[3], 2 * math.pi)
        H[3:6, _VEL] = (1.0 + d[4]) * Rd
        Hd = np.zeros((7, _N_DRIFT))
        Hd[0:3, 0:3] = np.eye(3)
        Hd[3:6, 3] = [-v_pred[1], v_pred[0], 0.0]
        Hd[3:6, 4] = v_turned
        Hd[6, 3] = 1.0
        return r, np.hstack([H, Hd])

    def _reanchor_drift(self, *, first_sample: bool = False) -> None:
        """A re-anchored odometry frame starts where the filter is: its drift is zero, its error
        the filter's position and heading error (so the new frame adds no information), and,
        anchored on one ``first_sample``, that sample's noise (the odometry's floors)."""
        P = self._P
        self.odometry_drift[:] = 0.0
        src = np.r_[np.arange(_POS.start, _POS.stop), _YAW]
        dst = np.r_[np.arange(_DP.start, _DP.stop), _DYAW]
        P[dst, :] = -P[src, :]
        P[:, dst] = -P[:, src]  # (the drift block becomes P[src, src])
        if first_sample:
            c = self.config
            P[dst, dst] += np.array([c.odometry_pos_noise_m**2] * 3 + [c.odometry_yaw_noise_rad**2])
        # a new frame's scale is its own: known only as well as at the start
        self._reset_entries(
            slice(_DSCALE, _DSCALE + 1), np.array([self.config.odometry_scale_sigma**2])
        )

    def _gated(
        self,
        obs: Stamped,
        r: FloatArray,
        H: FloatArray,
        Rn: FloatArray,
        p_meas: FloatArray | None,
        *,
        yaw_row: int | None = None,
        v_meas: FloatArray | None = None,
        gate: float | None = None,
    ) -> FusionResult:
        """Update, and reset the observed position (with ``yaw_row``, the heading: a pose in
        the navigation frame; with ``v_meas`` and no position, the velocity) if the source has
        been rejected too long."""
        src = getattr(obs, "source", type(obs).__name__)
        res = self._update(r, H, Rn, gate=gate)
        if res.accepted:
            self._last_accepted_ns[src] = obs.t_ns
            if p_meas is not None:
                self._position_fused_ns[src] = obs.t_ns
            return res
        since = self._last_accepted_ns.setdefault(src, obs.t_ns)
        if p_meas is not None and self._held_by_another(src, obs.t_ns):
            return res  # (PX4: another source keeps the position; this one is refused, no reset)
        if (obs.t_ns - since) * 1e-9 >= self.config.reset_after_s:
            # Persistently rejected: trust the sensor again. Reset what it observes to the
            # measurement, with the measurement's uncertainty, and say so.
            what = self._reset_to(obs, r, Rn, p_meas, yaw_row, v_meas)
            widened = (
                self._widen_velocity(r, (obs.t_ns - since) * 1e-9)
                if isinstance(obs, PositionSample)
                else ""
            )
            self._last_accepted_ns[src] = obs.t_ns
            self.events.append(
                (
                    obs.t_ns,
                    f"{src}: rejected for {self.config.reset_after_s:g} s, {what} reset to it{widened}",
                )
            )
        return res

    def _held_by_another(self, src: str, t_ns: int) -> bool:
        """Whether a source other than ``src`` had a position accepted within the last
        ``reset_after_s``: then a persistently rejected position (a GNSS glitch beside a VIO)
        is the sensor's fault, not the filter's, and resets nothing (PX4's EKF2 resets to the
        GNSS only when no horizontal position has been fused for its time-out)."""
        window = s_to_ns(self.config.reset_after_s)
        return any(t_ns - t < window for s, t in self._position_fused_ns.items() if s != src)

    def _reset_to(
        self,
        obs: Stamped,
        r: FloatArray,
        Rn: FloatArray,
        p_meas: FloatArray | None,
        yaw_row: int | None,
        v_meas: FloatArray | None,
    ) -> str:
        """Reset the states a persistently rejected source observes; what was reset."""
        if p_meas is not None:
            self.p = p_meas.copy()
            self._reset_entries(_POS, np.diag(Rn)[0:3])
            if yaw_row is None:
                return "position"
            # a pose in the navigation frame: its heading too, turning the attitude about z
            self.R = so3_exp(np.array([0.0, 0.0, float(r[yaw_row])])) @ self.R
            self._reset_entries(slice(_YAW, _YAW + 1), Rn[yaw_row, yaw_row : yaw_row + 1])
            return "position and heading"
        if v_meas is not None:
            self.v = v_meas.copy()
            self._reset_entries(_VEL, np.diag(Rn)[0:3])
            return "velocity"
        if isinstance(obs, MagSample):
            self.R = so3_exp(np.array([0.0, 0.0, float(r[0])])) @ self.R
            self._reset_entries(slice(_YAW, _YAW + 1), Rn[0, 0:1])
            return "heading"
        # a range is measured along the tilted body axis: its height is range x R22
        scale = float(self.R[2, 2]) if isinstance(obs, RangeSample) else 1.0
        self.p[2] += float(r[0]) * scale
        self._reset_entries(slice(_Z, _Z + 1), Rn[0, 0:1] * scale**2)
        return "height"

    def _widen_velocity(self, r_pos: FloatArray, refused_s: float) -> str:
        """After a position-only fix reset the position: the position ran away from the fixes
        while they were refused because the velocity was wrong, and the filter was sure of it
        (which is why it refused them). The velocity's variance grows, per axis, to at least
        the error that drift implies (the innovation over the time refused), so the next fixes
        correct the velocity instead of being refused and resetting the position again.
        Returns what it did, for the event ("" when the velocity was already that uncertain)."""
        drift_m_s = np.abs(r_pos[0:3]) / max(refused_s, self.config.reset_after_s)
        var = np.diag(self._P)[_VEL].copy()
        if (drift_m_s**2 <= var).all():
            return ""
        self._reset_entries(_VEL, np.maximum(var, drift_m_s**2))
        sigma = float(np.sqrt(np.max(np.diag(self._P)[_VEL])))
        return f" (velocity sigma widened to {sigma:.2g} m/s)"

    def _reset_entries(self, block: slice, var: FloatArray) -> None:
        """Forget the covariance of a block of the error state and set its variances."""
        self._P[block, :] = 0.0
        self._P[:, block] = 0.0
        self._P[block, block] = np.diag(var)

    def _update(
        self, r: FloatArray, H: FloatArray, Rn: FloatArray, *, gate: float | None = None
    ) -> FusionResult:
        P = self._P
        if H.shape[1] < P.shape[0]:  # (an observation of the 15 alone, beside the drift)
            H = np.pad(H, ((0, 0), (0, P.shape[0] - H.shape[1])))
        limit = self._gates[len(r)] if gate is None else gate
        # The gain, the gate, P - K S K^T and the attitude reset, in one compiled kernel.
        nis, dx, P_new = _kalman_update(
            P, np.ascontiguousarray(H, dtype=np.float64), np.ascontiguousarray(Rn, dtype=np.float64),
            np.ascontiguousarray(r, dtype=np.float64), float(limit),
        )  # fmt: skip
        nis = float(nis)
        ratio = nis / limit
        if ratio > 1.0:
            return FusionResult(accepted=False, innovation=r, nis=nis, test_ratio=ratio)
        # Inject the error into the nominal state (new arrays).
        v, p, bg, ba, R = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty((3, 3))
        _inject(dx, self.R, self.v, self.p, self.bg, self.ba, (v, p, bg, ba, R))
        self.R, self.v, self.p, self.bg, self.ba = R, v, p, bg, ba
        if self._relative:
            self.odometry_drift += dx[_N:]
        self._P = P_new
        return FusionResult(accepted=True, innovation=r, nis=nis, test_ratio=ratio)


# -- the compiled prediction (quadnav.jit) -----------------------------------------------------
_I_ATT, _I_VEL, _I_POS, _I_BG, _I_BA = _ATT.start, _VEL.start, _POS.start, _BG.start, _BA.start
_I_NG, _I_NA = _N_G.start, _N_A.start


@njit
def _propagate(
    R: FloatArray, v: FloatArray, p: FloatArray, gyro: FloatArray, accel: FloatArray,
    bg: FloatArray, ba: FloatArray, dt: float, g_W: FloatArray, F: FloatArray, G: FloatArray,
    q: FloatArray, P: FloatArray, with_cov: bool,
    out: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray],
) -> None:  # fmt: skip
    """One prediction into ``out`` = (w, f, R', v', p', P'): the rate ``w = gyro - bg`` and
    the specific force ``f = accel - ba``; with ``E = Exp(w dt)``, ``R' = R E``,
    ``v' = v + dt (R' f + g)``, ``p' = p + dt v'``; the state-dependent blocks of
    :func:`nav_jacobians`' ``F`` and ``G`` written into them; and, ``with_cov``,
    ``P' = F P F^T + G diag(q) G^T`` (else ``P'`` is not written)."""
    w, f, R1, v1, p1, P1 = out
    for k in range(3):
        w[k] = gyro[k] - bg[k]
        f[k] = accel[k] - ba[k]
    E = so3_exp_one(w * dt)
    for i in range(3):
        for j in range(3):
            R1[i, j] = 0.0
            for k in range(3):
                R1[i, j] += R[i, k] * E[k, j]
    Rf = np.empty((3, 3))  # R' skew(f)
    for i in range(3):
        Rf[i, 0] = R1[i, 1] * f[2] - R1[i, 2] * f[1]
        Rf[i, 1] = R1[i, 2] * f[0] - R1[i, 0] * f[2]
        Rf[i, 2] = R1[i, 0] * f[1] - R1[i, 1] * f[0]
    for i in range(3):
        a = R1[i, 0] * f[0] + R1[i, 1] * f[1] + R1[i, 2] * f[2] + g_W[i]
        v1[i] = v[i] + dt * a
        p1[i] = p[i] + dt * v1[i]
    for i in range(3):
        for j in range(3):
            F[_I_ATT + i, _I_ATT + j] = E[j, i]  # Exp(-w dt)
            RfA = 0.0
            for k in range(3):
                RfA += Rf[i, k] * E[j, k]
            F[_I_VEL + i, _I_ATT + j] = -dt * RfA
            F[_I_VEL + i, _I_BG + j] = dt * dt * Rf[i, j]
            F[_I_VEL + i, _I_BA + j] = -dt * R1[i, j]
            F[_I_POS + i, _I_ATT + j] = dt * F[_I_VEL + i, _I_ATT + j]
            F[_I_POS + i, _I_BG + j] = dt * F[_I_VEL + i, _I_BG + j]
            F[_I_POS + i, _I_BA + j] = dt * F[_I_VEL + i, _I_BA + j]
            G[_I_VEL + i, _I_NG + j] = F[_I_VEL + i, _I_BG + j]
            G[_I_VEL + i, _I_NA + j] = F[_I_VEL + i, _I_BA + j]
            G[_I_POS + i, _I_NG + j] = F[_I_POS + i, _I_BG + j]
            G[_I_POS + i, _I_NA + j] = F[_I_POS + i, _I_BA + j]
    if not with_cov:
        return
    n, m = F.shape[0], G.shape[1]
    # Row by row of F and G, over their nonzero entries (a step's F is mostly identity and
    # zeros, G mostly zeros): the terms of the dense sums in their order, a third of the work.
    FP = _matmul(F, P)
    row = np.empty(n)
    for j in range(n):
        row[:] = 0.0
        for k in range(n):
            a = F[j, k]
            if a != 0.0:
                for i in range(n):
                    row[i] += a * FP[i, k]
        for k in range(m):
            b = G[j, k]
            if b != 0.0:
                qk = q[k]
                for i in range(n):
                    row[i] += G[i, k] * qk * b
        for i in range(j + 1):
            P1[i, j] = row[i]
            P1[j, i] = row[i]


@njit
def _kalman_update(
    P: FloatArray, H: FloatArray, Rn: FloatArray, r: FloatArray, limit: float
) -> tuple[float, FloatArray, FloatArray]:
    """One EKF update's linear algebra: the innovation's covariance ``S = H P H^T + Rn``, its
    NIS ``r^T S^-1 r``; when the NIS is within ``limit``, the correction ``dx = K r`` and
    ``P - K S K^T`` (= P - K H P; cheaper than Joseph's form at 15 states and as well behaved
    with the symmetrisation and the positive noise of every update), with the attitude error's
    reset ``P <- Gr P Gr^T`` (``Gr`` = I but its attitude block ``B = I - [dtheta/2]x``),
    symmetrised. Beyond ``limit``, ``dx`` is empty and ``P`` comes back untouched."""
    n, m = P.shape[0], H.shape[0]
    # (in loops over H's nonzero entries: an observation sees a few of the states, and BLAS's
    # calls cost more than these small products)
    PHt = _matmul(H, P.T).T
    S = _matmul(H, PHt) + Rn
    S_inv = np.empty_like(S)
    if m == 1:  # scalar observations (height, range, heading) need no matrix inverse
        S_inv[0, 0] = 1.0 / S[0, 0]
    else:
        S_inv[:, :] = np.linalg.inv(S)
    Sr = np.zeros(m)
    nis = 0.0
    for a in range(m):
        for b in range(m):
            Sr[a] += S_inv[a, b] * r[b]
        nis += r[a] * Sr[a]
    if nis / limit > 1.0:
        return nis, np.empty(0), P
    K = np.zeros((n, m))
    dx = np.zeros(n)
    for i in range(n):
        for a in range(m):
            acc = 0.0
            for b in range(m):
                acc += PHt[i, b] * S_inv[b, a]
            K[i, a] = acc
        for a in range(m):
            dx[i] += PHt[i, a] * Sr[a]
    P1 = P.copy()
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for a in range(m):
                acc += K[i, a] * PHt[j, a]
            P1[i, j] -= acc
    hx, hy, hz = 0.5 * dx[_I_ATT], 0.5 * dx[_I_ATT + 1], 0.5 * dx[_I_ATT + 2]
    B = np.eye(3)
    B[0, 1], B[0, 2], B[1, 2] = hz, -hy, hx  # I - [h]x
    B[1, 0], B[2, 0], B[2, 1] = -hz, hy, -hx
    n = P1.shape[0]
    rows = np.empty((3, n))  # B P[att, :]
    for i in range(3):
        for j in range(n):
            rows[i, j] = (
                B[i, 0] * P1[_I_ATT, j] + B[i, 1] * P1[_I_ATT + 1, j] + B[i, 2] * P1[_I_ATT + 2, j]
            )
    P1[_I_ATT : _I_ATT + 3, :] = rows
    cols = np.empty((n, 3))  # P[:, att] B^T
    for i in range(n):
        for j in range(3):
            cols[i, j] = (
                P1[i, _I_ATT] * B[j, 0] + P1[i, _I_ATT + 1] * B[j, 1] + P1[i, _I_ATT + 2] * B[j, 2]
            )
    P1[:, _I_ATT : _I_ATT + 3] = cols
    return nis, dx, 0.5 * (P1 + P1.T)


@njit
def _inject(
    dx: FloatArray, R: FloatArray, v: FloatArray, p: FloatArray, bg: FloatArray, ba: FloatArray,
    out: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray],
) -> None:  # fmt: skip
    """An update's correction ``dx`` into ``out`` = (v', p', b_g', b_a', R'): the velocity,
    position and biases plus their parts of ``dx``, and the attitude turned by its part,
    ``R' = R Exp(dx_att)``."""
    v1, p1, bg1, ba1, R1 = out
    for k in range(3):
        v1[k] = v[k] + dx[_I_VEL + k]
        p1[k] = p[k] + dx[_I_POS + k]
        bg1[k] = bg[k] + dx[_I_BG + k]
        ba1[k] = ba[k] + dx[_I_BA + k]
    E = so3_exp_one(dx[_I_ATT : _I_ATT + 3])
    for i in range(3):
        for j in range(3):
            R1[i, j] = R[i, 0] * E[0, j] + R[i, 1] * E[1, j] + R[i, 2] * E[2, j]


@njit
def _matmul(A: FloatArray, B: FloatArray) -> FloatArray:
    n, m, r = A.shape[0], A.shape[1], B.shape[1]
    out = np.zeros((n, r))
    for i in range(n):
        for k in range(m):
            a = A[i, k]
            if a != 0.0:
                for j in range(r):
                    out[i, j] += a * B[k, j]
    return out
