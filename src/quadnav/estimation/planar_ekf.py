"""The planar EKF of thesis 000 (eqs 2.1-2.13) on the delayed-horizon core.

State ``x = [x, z, vx, vz, theta]``: position and velocity of the body in the world x-z
plane (ENU, z up) and the pitch ``theta`` about +y (a positive angle turns the thrust axis
towards +x). Inputs are an IMU sample: the gyro's y rate and the accelerometer's body x
and z. The prediction is the same semi-implicit Euler step the simulator takes, so with
noise-free inputs the filter reproduces the truth exactly::

    theta' = theta + dt * w
    v'     = v + dt * (R(theta') f + g_W)        (g_W = [0, -g]; omitted for a kinematic accelerometer)
    p'     = p + dt * v'

with ``R(theta) = [[cos, sin], [-sin, cos]]`` mapping body (x, z) into world (x, z).
The thesis's own code takes ``R`` at the previous angle and ignores gravity (its
accelerometer measured kinematic acceleration); ``accel_model="kinematic"`` reproduces the
latter. The covariance follows ``P' = F P F^T + G diag(sa^2, sa^2, sw^2) G^T`` (2.7, 2.12,
2.13, here for this discretisation), and updates use the Joseph form with a chi-square gate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import EstimationError
from quadnav.estimation.chi2 import chi2_ppf
from quadnav.estimation.horizon import (
    FusionResult,
    NavState,
    body_rate,
    correct_ring,
    integrate_ring,
)
from quadnav.messages import ImuSample, PositionSample, Sample, StateEstimate
from quadnav.units import GRAVITY_M_S2

__all__ = [
    "AccelModel",
    "PlanarEkf",
    "PlanarEkfConfig",
    "PlanarKinematics",
    "planar_jacobians",
]

FloatArray = NDArray[np.float64]
AccelModel = Literal["specific_force", "kinematic"]
STATE_NAMES = ("x", "z", "vx", "vz", "theta")
_ZERO3 = np.zeros(3)


def _rot(theta: FloatArray) -> tuple[FloatArray, FloatArray]:
    return np.cos(theta), np.sin(theta)


@dataclass(frozen=True, slots=True)
class PlanarKinematics:
    """Strapdown integration in the x-z plane (arrays may be batched on leading axes)."""

    gravity_m_s2: float = GRAVITY_M_S2
    accel_model: AccelModel = "specific_force"

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
        dt = np.asarray(dt_s, dtype=np.float64)
        dtheta = gyro[..., 1:2] * dt[..., None] if dt.ndim else gyro[..., 1:2] * dt
        if dtheta_corr is not None:
            dtheta = dtheta + dtheta_corr[..., 1:2]
        att_new = att + dtheta
        c, s = _rot(att_new[..., 0])
        fx, fz = accel[..., 0], accel[..., 2]
        a = np.stack([c * fx + s * fz, -s * fx + c * fz], axis=-1)
        if self.accel_model == "specific_force":
            a[..., 1] -= self.gravity_m_s2
        dtv = dt[..., None] if dt.ndim else dt
        vel_new = vel + dtv * a
        pos_new = pos + dtv * vel_new
        return pos_new, vel_new, att_new

    def integrate_ring(
        self, ring: tuple[FloatArray, FloatArray, FloatArray], src: int, dst: int,
        imu: ImuSample, biases: tuple[FloatArray, FloatArray], dt_s: float,
        dtheta_corr: FloatArray,
    ) -> None:  # fmt: skip
        integrate_ring(self, ring, src, dst, imu, biases, dt_s, dtheta_corr)

    @property
    def output_names(self) -> tuple[str, ...]:
        return STATE_NAMES  # the output predictor's [pos, vel, att] is the filter's own order

    def attitude_error(self, att_target: FloatArray, att: FloatArray) -> FloatArray:
        err = math.remainder(float(att_target[0] - att[0]), 2.0 * math.pi)
        return np.array([0.0, err, 0.0])

    def output_estimate(
        self, nav: NavState, gyro: FloatArray | None, bias_g: FloatArray
    ) -> StateEstimate:
        x = np.concatenate((nav.pos, nav.vel, nav.att))
        return self.to_estimate(nav, x, self.output_names, None, body_rate(gyro, bias_g))

    def correct_ring(
        self, ring: tuple[FloatArray, FloatArray, FloatArray], ring_t: NDArray[np.int64],
        oldest: int, nav: NavState, integrals: tuple[FloatArray, FloatArray],
        gains: tuple[float, float, float], propagate: bool,
    ) -> FloatArray:  # fmt: skip
        return correct_ring(self, ring, ring_t, oldest, nav, integrals, gains, propagate)

    def to_estimate(
        self,
        nav: NavState,
        x: FloatArray,
        names: tuple[str, ...],
        P: FloatArray | None,
        w_B: FloatArray | None = None,
    ) -> StateEstimate:
        half = 0.5 * float(nav.att[0])
        return StateEstimate(
            t_ns=nav.t_ns,
            p_W_B=np.array([nav.pos[0], 0.0, nav.pos[1]]),
            v_W_B=np.array([nav.vel[0], 0.0, nav.vel[1]]),
            q_W_B_xyzw=np.array([0.0, math.sin(half), 0.0, math.cos(half)]),
            x=x,
            names=names,
            P=P,
            w_B=w_B,
        )


def planar_jacobians(
    x: FloatArray, gyro_y: float, accel_xz: FloatArray, dt_s: float, *, kin: PlanarKinematics
) -> tuple[FloatArray, FloatArray]:
    """``F = df/dx`` (5x5) and ``G = df/du`` (5x3, ``u = [f_x, f_z, w]``) of the prediction."""
    theta_new = x[4] + dt_s * gyro_y
    c, s = math.cos(theta_new), math.sin(theta_new)
    fx, fz = float(accel_xz[0]), float(accel_xz[1])
    # d(R f)/dtheta at the new angle
    dRf = np.array([-s * fx + c * fz, -c * fx - s * fz])
    R = np.array([[c, s], [-s, c]])
    F = np.eye(5)
    F[0, 2] = F[1, 3] = dt_s
    F[2:4, 4] = dt_s * dRf
    F[0:2, 4] = dt_s * dt_s * dRf
    G = np.zeros((5, 3))
    G[2:4, 0:2] = dt_s * R
    G[0:2, 0:2] = dt_s * dt_s * R
    G[4, 2] = dt_s
    G[2:4, 2] = dt_s * dt_s * dRf
    G[0:2, 2] = dt_s**3 * dRf
    return F, G


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanarEkfConfig:
    """Noise and gating of the planar EKF.

    ``accel_sigma_m_s2`` and ``gyro_sigma_rad_s`` are the standard deviations of one IMU
    sample (the thesis's discrete model). ``gate_probability`` sets the chi-square innovation
    gate; ``None`` fuses everything, as the thesis's filter did.
    """

    accel_sigma_m_s2: float = 0.25
    gyro_sigma_rad_s: float = 0.03
    gravity_m_s2: float = GRAVITY_M_S2
    accel_model: AccelModel = "specific_force"
    gate_probability: float | None = 0.9999

    def __post_init__(self) -> None:
        for name in ("accel_sigma_m_s2", "gyro_sigma_rad_s", "gravity_m_s2"):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0.0:
                raise EstimationError(f"PlanarEkfConfig.{name} must be finite and > 0, got {value}")
        p = self.gate_probability
        if p is not None and not 0.0 < p < 1.0:
            raise EstimationError(f"PlanarEkfConfig.gate_probability must lie in (0, 1), got {p}")


class PlanarEkf:
    """The 5-state planar EKF; a :class:`~quadnav.estimation.horizon.DelayedFilter`."""

    names: tuple[str, ...] = STATE_NAMES

    def __init__(self, config: PlanarEkfConfig, *, x0: FloatArray, P0: FloatArray) -> None:
        x0 = np.asarray(x0, dtype=np.float64)
        P0 = np.asarray(P0, dtype=np.float64)
        if x0.shape != (5,) or P0.shape != (5, 5):
            raise EstimationError(
                f"planar EKF needs x0 (5,) and P0 (5, 5), got {x0.shape}, {P0.shape}"
            )
        if not (np.all(np.isfinite(x0)) and np.all(np.isfinite(P0))):
            raise EstimationError("planar EKF initial state and covariance must be finite")
        if not np.allclose(P0, P0.T) or np.min(np.linalg.eigvalsh(P0)) < 0.0:
            raise EstimationError(
                "planar EKF initial covariance must be symmetric positive semi-definite"
            )
        self.config = config
        self.kinematics = PlanarKinematics(config.gravity_m_s2, config.accel_model)
        self._x = x0.copy()
        self._P = P0.copy()
        self._Qu = np.diag(
            [config.accel_sigma_m_s2**2, config.accel_sigma_m_s2**2, config.gyro_sigma_rad_s**2]
        )
        self._gate = (
            None if config.gate_probability is None else float(chi2_ppf(config.gate_probability, 2))
        )
        self._H = np.zeros((2, 5))
        self._H[0, 0] = self._H[1, 1] = 1.0

    @property
    def x(self) -> FloatArray:
        return self._x

    @property
    def P(self) -> FloatArray:
        return self._P

    def nav(self, t_ns: int, *, copy: bool = True) -> NavState:
        x = self._x
        if not copy:
            return NavState(t_ns, x[0:2], x[2:4], x[4:5])
        return NavState(t_ns, x[0:2].copy(), x[2:4].copy(), x[4:5].copy())

    def predict(self, imu: ImuSample, dt_s: float) -> None:
        x = self._x
        F, G = planar_jacobians(
            x, float(imu.gyro_rad_s[1]), imu.accel_m_s2[[0, 2]], dt_s, kin=self.kinematics
        )
        pos, vel, att = self.kinematics.integrate(
            x[0:2], x[2:4], x[4:5], imu.gyro_rad_s, imu.accel_m_s2, dt_s
        )
        self._x = np.concatenate([pos, vel, att])
        P = F @ self._P @ F.T + G @ self._Qu @ G.T
        self._P = 0.5 * (P + P.T)

    def can_fuse(self, obs: Sample) -> bool:
        return isinstance(obs, PositionSample)

    def imu_biases(self) -> tuple[FloatArray, FloatArray]:
        return _ZERO3, _ZERO3  # the planar filter estimates no biases

    def fuse(self, obs: Sample) -> FusionResult:
        if not isinstance(obs, PositionSample):
            raise EstimationError(
                f"the planar EKF fuses PositionSample only, got {type(obs).__name__}"
            )
        H = self._H
        z = obs.p_W_B[[0, 2]]
        R = np.eye(2) * obs.sigma_m**2
        innov = z - self._x[0:2]
        S = H @ self._P @ H.T + R
        S_inv = np.linalg.inv(S)
        nis = float(innov @ S_inv @ innov)
        test_ratio = nis / self._gate if self._gate is not None else 0.0
        if self._gate is not None and test_ratio > 1.0:
            return FusionResult(accepted=False, innovation=innov, nis=nis, test_ratio=test_ratio)
        K = self._P @ H.T @ S_inv
        self._x = self._x + K @ innov
        I_KH = np.eye(5) - K @ H
        P = I_KH @ self._P @ I_KH.T + K @ R @ K.T
        self._P = 0.5 * (P + P.T)
        return FusionResult(accepted=True, innovation=innov, nis=nis, test_ratio=test_ratio)
