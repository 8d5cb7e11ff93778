"""Clipped IMU samples and accelerometer-bias learning, as PX4's EKF2 handles them.

* :class:`ClippedImuSample` is an IMU sample whose accelerometer saturated on some body axes
  (``sensor_combined.accelerometer_clipping``, bit k for axis k; PX4's IMU down-sampler ORs
  the flags of the samples it averages).
* On a clipped axis the accelerometer's process noise is PX4's ``BADACC_BIAS_PNOISE`` (4.9
  m/s^2) instead of ``EKF2_ACC_NOISE``: what the saturated reading lost is then carried as
  velocity uncertainty, and the next velocity observation corrects the velocity instead of
  turning the attitude and the biases to explain it (``covariance.cpp``).
* :class:`BiasLearningGate` is ``updateIMUBiasInhibit`` (``ekf_helper.cpp``): the
  accelerometer bias is not learnt on a clipped axis, nor on any axis while the vehicle
  manoeuvres hard (peak-held body rate above ``EKF2_ABL_GYRLIM`` or specific force above
  ``EKF2_ABL_ACCLIM``, decaying with ``EKF2_ABL_TAU``). An inhibited bias keeps its value; its
  variance is set aside and given back when learning resumes.
* :class:`Releveller` (our addition; PX4 relies on its velocity aiding): after clipping, once
  the vehicle is at rest (0.2 s), the tilt is set from the accelerometer, the velocity to
  zero, the position back to where the rest began and the accelerometer bias back to what it
  was before the clipping.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from quadnav.estimation.horizon import require_positive
from quadnav.messages import ImuSample

__all__ = ["BADACC_NOISE_M_S2", "BiasLearningGate", "ClippedImuSample", "Releveller", "clip_axes"]

BADACC_NOISE_M_S2 = 4.9  # PX4's BADACC_BIAS_PNOISE
_NONE = np.zeros(3, bool)
_ALL = np.ones(3, bool)


@dataclass(frozen=True, slots=True, kw_only=True)
class ClippedImuSample(ImuSample):
    """An IMU sample flagged as clipped: ``accel_clip_axes`` bit k for body (FLU) axis k."""

    accel_clip_axes: int = 0


def clip_axes(imu: ImuSample) -> int:
    """The clipped-axis bits of any IMU sample (0 for a plain one)."""
    return int(getattr(imu, "accel_clip_axes", 0))


@dataclass(slots=True)
class BiasLearningGate:
    """Which accelerometer-bias axes may be learnt now, and their set-aside variances."""

    gyro_limit_rad_s: float = 3.0
    accel_limit_m_s2: float = 25.0
    tau_s: float = 0.5
    rate_filt: float = 0.0
    accel_filt: float = 0.0
    inhibited: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(3, bool))
    saved_var: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    n_inhibited_steps: int = 0

    def __post_init__(self) -> None:
        require_positive(self, ("gyro_limit_rad_s", "accel_limit_m_s2", "tau_s"))

    def update(
        self, gyro: NDArray[np.float64], accel: NDArray[np.float64], clipped: int, dt_s: float
    ) -> NDArray[np.bool_]:
        """The axes to inhibit after this IMU sample."""
        beta = 1.0 - min(max(dt_s / self.tau_s, 0.0), 1.0)
        self.rate_filt = max(math.sqrt(float(gyro @ gyro)), beta * self.rate_filt)
        self.accel_filt = max(math.sqrt(float(accel @ accel)), beta * self.accel_filt)
        hard = self.rate_filt > self.gyro_limit_rad_s or self.accel_filt > self.accel_limit_m_s2
        if not hard and not clipped:
            return _NONE
        self.n_inhibited_steps += 1
        return _ALL if hard else np.array([bool(clipped >> k & 1) for k in range(3)])

    def apply(self, P: NDArray[np.float64], first: int, axes: NDArray[np.bool_]) -> None:
        """Zero the covariance of newly inhibited bias states (``first`` + axis), keeping
        their variances; give them back to axes learning again. In place."""
        if not axes.any() and not self.inhibited.any():
            return
        for k in range(3):
            i = first + k
            if axes[k]:
                if not self.inhibited[k]:
                    self.saved_var[k] = P[i, i]
                P[i, :] = 0.0
                P[:, i] = 0.0
            elif self.inhibited[k]:
                P[i, i] = self.saved_var[k] if math.isfinite(self.saved_var[k]) else 0.0
        self.inhibited = axes


@dataclass(slots=True)
class Releveller:
    """After accelerometer clipping the inertial solution's tilt and velocity are not to be
    trusted, nor what the accelerometer bias learnt from them. Once the IMU shows the vehicle
    at rest for ``window_s`` (body rate under ``gyro_max_rad_s``, specific force within
    ``accel_tol_m_s2`` of gravity), :meth:`update` returns the mean specific force to
    re-level on, as the ground alignment does, with the bias from before the clipping, and
    ``p_rest``, the position when the rest began: the vehicle has not moved since, so what the
    position moved meanwhile is the velocity error the clipping left, to be undone. The window
    is short (0.2 s, 20 filter steps at 100 Hz): until the re-levelling the tilt and that
    velocity error stay (issue 21: a second at more than 1 degree with 1 s)."""

    window_s: float = 0.2
    gyro_max_rad_s: float = 0.1
    accel_tol_m_s2: float = 0.5
    pending: bool = False
    bias_before: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    bias_var_before: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    p_rest: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    _still_s: float = 0.0
    _sum: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    _n: int = 0

    def __post_init__(self) -> None:
        require_positive(self, ("window_s", "gyro_max_rad_s", "accel_tol_m_s2"))

    def on_clip(self, bias: NDArray[np.float64], bias_var: NDArray[np.float64]) -> None:
        if not self.pending:  # the bias as it was before this crash
            self.bias_before, self.bias_var_before = bias.copy(), bias_var.copy()
            self.pending = True
        self._still_s, self._sum, self._n = 0.0, np.zeros(3), 0

    def update(
        self,
        gyro: NDArray[np.float64],
        accel: NDArray[np.float64],
        dt_s: float,
        g: float,
        p: NDArray[np.float64],
    ) -> NDArray[np.float64] | None:
        """One IMU sample (bias-free rate, raw specific force) and the position after it."""
        if not self.pending:
            return None
        still = (
            np.linalg.norm(gyro) < self.gyro_max_rad_s
            and abs(np.linalg.norm(accel) - g) < self.accel_tol_m_s2
        )
        if not still:
            self._still_s, self._sum, self._n = 0.0, np.zeros(3), 0
            return None
        if self._n == 0:
            self.p_rest = p.copy()
        self._still_s += dt_s
        self._sum += accel
        self._n += 1
        if self._still_s < self.window_s:
            return None
        self.pending = False
        return self._sum / self._n
