"""A cascaded position - velocity - attitude - rate controller for the rigid-body model.

The structure PX4's multicopter controllers use: a P position loop gives a velocity
setpoint (plus the trajectory's velocity), a PID velocity loop an acceleration (plus the
trajectory's acceleration), which becomes a thrust vector limited in tilt and magnitude; a
P attitude loop on the rotation error gives body-rate setpoints and a PID rate loop the body
torques. Integrators are clamped (anti-windup) and frozen while the output saturates.
The mixer turns thrust and torques into rotor speed commands.

A setpoint may give a position, or only a velocity (the ``/cmd_vel`` interface of thesis 003's
controllers), and a yaw; its acceleration is fed forward. It is a
:class:`~quadnav.control.base.Controller`: it reads the estimate's position, velocity, attitude
and body rate, and returns a ``rotor_speeds`` :class:`~quadnav.control.base.Command` (with the
thrust and torque it mixed). It runs every loop at every call, with the fixed ``dt_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.control.base import Command, Setpoint, require_rate
from quadnav.control.stability import routh_hurwitz_stable
from quadnav.errors import ControlError
from quadnav.jit import njit
from quadnav.messages import StateEstimate
from quadnav.vehicle import Mixer, RigidBodyParams

__all__ = ["CascadedPid", "CascadedPidGains", "Setpoint"]  # Setpoint: from control.base

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class CascadedPidGains:
    kp_pos: tuple[float, float, float] = (2.0, 2.0, 2.0)
    kp_vel: tuple[float, float, float] = (6.0, 6.0, 8.0)
    ki_vel: tuple[float, float, float] = (4.0, 4.0, 4.0)
    kd_vel: tuple[float, float, float] = (0.05, 0.05, 0.0)
    kp_att: tuple[float, float, float] = (8.0, 8.0, 3.0)
    kp_rate: tuple[float, float, float] = (25.0, 25.0, 10.0)
    ki_rate: tuple[float, float, float] = (5.0, 5.0, 2.0)
    kd_rate: tuple[float, float, float] = (0.3, 0.3, 0.0)
    max_vel_m_s: float = 3.0
    max_tilt_rad: float = math.radians(35)
    max_rate_rad_s: float = 4.0
    vel_integral_limit_m_s2: float = 3.0
    rate_integral_limit: float = 2.0
    min_thrust_fraction: float = 0.08
    max_thrust_fraction: float = 0.9

    def __post_init__(self) -> None:
        for name in ("kp_pos", "kp_vel", "kp_att", "kp_rate"):
            if any(not g > 0 for g in getattr(self, name)):
                raise ControlError(f"{name} must be positive on every axis")
        for name in ("ki_vel", "kd_vel", "ki_rate", "kd_rate"):
            if any(g < 0 for g in getattr(self, name)):
                raise ControlError(f"{name} must be >= 0")
        # The velocity loop on a double integrator with the rate-limited attitude assumed fast:
        # s^3 + kp s^2 + ki s with a PI (the position P closes s^2 + ... ) must be Hurwitz.
        for k in range(3):
            poly = [
                1.0,
                self.kp_vel[k] + self.kd_vel[k],
                self.ki_vel[k] + self.kp_vel[k] * self.kp_pos[k],
                self.ki_vel[k] * self.kp_pos[k],
            ]
            if not routh_hurwitz_stable(poly):
                raise ControlError(
                    f"position/velocity gains on axis {'xyz'[k]} are unstable (Routh-Hurwitz)"
                )
        if not 0 < self.max_tilt_rad < math.pi / 2:
            raise ControlError("max_tilt_rad must lie in (0, pi/2)")
        if not 0 <= self.min_thrust_fraction < self.max_thrust_fraction <= 1:
            raise ControlError("need 0 <= min_thrust_fraction < max_thrust_fraction <= 1")


class CascadedPid:
    """Runs every loop at the call rate (1 kHz in the simulator); stateful (integrators).

    The loops run in one compiled kernel (:func:`_pid_step`; ``QUADNAV_JIT=0`` runs it as
    Python), a few microseconds a call where the numpy form took about a hundred."""

    def __init__(
        self, params: RigidBodyParams, gains: CascadedPidGains | None = None, *, dt_s: float = 0.001
    ) -> None:
        self.params = params
        self.g = gains or CascadedPidGains()
        self.dt = float(dt_s)
        self.mixer = Mixer(params)
        self._gains = _gain_vector(self.g, params, self.dt)
        self._consts = np.array(
            [params.mass_kg, params.gravity_m_s2, *params.inertia_kg_m2,
             params.k_thrust_n_s2 * params.omega_min_rad_s**2,
             params.k_thrust_n_s2 * params.omega_max_rad_s**2, params.k_thrust_n_s2,
             *self.mixer.A_inv.ravel()],
            dtype=np.float64,
        )  # fmt: skip
        # The loops' memory: the two integrators, the previous errors (no derivative kick on
        # the first call: a flag each says whether there is one).
        self._st = np.zeros(_N_STATE)
        self._none3 = np.zeros(3)
        self._ref: Setpoint | None = None  # the last setpoint, and its kernel arguments
        self._ref_args = self._setpoint_args(Setpoint())

    @property
    def vel_integral(self) -> FloatArray:
        """The velocity loop's integrator (m/s^2)."""
        return self._st[0:3].copy()

    @property
    def rate_integral(self) -> FloatArray:
        """The rate loop's integrator (rad/s^2)."""
        return self._st[3:6].copy()

    def __call__(self, t_ns: int, est: StateEstimate, ref: Setpoint) -> Command:
        """Rotor speed commands (rad/s) for the setpoint (``t_ns`` unused: fixed ``dt_s``)."""
        w = require_rate(est, "the cascaded PID")
        if ref is not self._ref:  # (an outer loop holds one setpoint for many calls)
            self._ref, self._ref_args = ref, self._setpoint_args(ref)
        p, has_p, v, a, yaw = self._ref_args
        out = np.empty(9)
        _pid_step(est.p_W_B, est.v_W_B, est.q_W_B_xyzw, w, p, has_p, v, a, yaw, self._gains,
                  self._consts, self._st, out)  # fmt: skip
        # (the command's arrays are views of this call's own output)
        return Command.of_rotors(float(out[7]), out[4:7], out[0:4], bool(out[8] > 0.0))

    def _setpoint_args(
        self, ref: Setpoint
    ) -> tuple[FloatArray, bool, FloatArray, FloatArray, float]:
        """The kernel's setpoint arguments: position (zeros when none, and whether there is
        one), velocity, acceleration (zeros when none), yaw."""
        z = self._none3
        return (
            z if ref.p is None else np.asarray(ref.p, dtype=np.float64), ref.p is not None,
            z if ref.v is None else np.asarray(ref.v, dtype=np.float64),
            z if ref.a is None else np.asarray(ref.a, dtype=np.float64),
            float(ref.yaw_rad),
        )  # fmt: skip


# -- the compiled kernel (quadnav.jit) ---------------------------------------------------------
_N_STATE = 14  # velocity integrator, rate integrator, previous errors (3 each), two flags


def _gain_vector(g: CascadedPidGains, p: RigidBodyParams, dt: float) -> FloatArray:
    """The gains as the kernel reads them: the eight per-axis gains (3 each, in the order of
    :class:`CascadedPidGains`), then the limits, the thrust bounds (N) and the step."""
    return np.array(
        [*g.kp_pos, *g.kp_vel, *g.ki_vel, *g.kd_vel, *g.kp_att, *g.kp_rate, *g.ki_rate,
         *g.kd_rate, g.max_vel_m_s, math.tan(g.max_tilt_rad), g.max_rate_rad_s,
         g.vel_integral_limit_m_s2, g.rate_integral_limit, g.min_thrust_fraction * p.max_thrust_n,
         g.max_thrust_fraction * p.max_thrust_n, dt],
        dtype=np.float64,
    )  # fmt: skip


@njit
def _clip(x: float, lim: float) -> float:
    return min(max(x, -lim), lim)


@njit
def _thrust_vector(
    p: FloatArray, v: FloatArray, ref_p: FloatArray, has_p: bool, ref_v: FloatArray,
    ref_a: FloatArray, g: FloatArray, c: FloatArray, st: FloatArray, F: FloatArray,
) -> bool:  # fmt: skip
    """The position loop (P, limited in speed) and the velocity loop (PID, anti-windup) into
    the thrust vector ``F``, limited in tilt and magnitude; whether a limit cut it."""
    max_vel, tan_tilt, vel_lim, F_min, F_max, dt = g[24], g[25], g[27], g[29], g[30], g[31]
    v_sp = np.empty(3)
    for k in range(3):
        v_sp[k] = ref_v[k] + (g[k] * (ref_p[k] - p[k]) if has_p else 0.0)
    speed = math.sqrt(v_sp[0] * v_sp[0] + v_sp[1] * v_sp[1] + v_sp[2] * v_sp[2])
    if speed > max_vel:
        for k in range(3):
            v_sp[k] *= max_vel / speed
    err = np.empty(3)
    for k in range(3):
        err[k] = v_sp[k] - v[k]
        d_err = (err[k] - st[6 + k]) / dt if st[12] > 0.0 else 0.0
        st[6 + k] = err[k]
        a_sp = g[3 + k] * err[k] + st[k] + g[9 + k] * d_err + ref_a[k]
        F[k] = c[0] * (a_sp + (c[1] if k == 2 else 0.0))
    st[12] = 1.0
    F[2] = max(F[2], F_min)
    horiz = math.hypot(F[0], F[1])
    max_h = F[2] * tan_tilt
    tilt_limited = horiz > max_h
    if tilt_limited:
        F[0] *= max_h / horiz
        F[1] *= max_h / horiz
    norm = math.sqrt(F[0] * F[0] + F[1] * F[1] + F[2] * F[2])
    thrust_limited = norm > F_max
    if thrust_limited:
        for k in range(3):
            F[k] *= F_max / norm
    saturated: bool = tilt_limited or thrust_limited
    if not saturated:  # integrate only while the output is achievable
        for k in range(3):
            st[k] = _clip(st[k] + g[6 + k] * err[k] * dt, vel_lim)
    return saturated


@njit
def _pid_step(
    p: FloatArray, v: FloatArray, q: FloatArray, w: FloatArray, ref_p: FloatArray,
    has_p: bool, ref_v: FloatArray, ref_a: FloatArray, yaw: float, g: FloatArray,
    c: FloatArray, st: FloatArray, out: FloatArray,
) -> None:  # fmt: skip
    """The four loops and the mixer in scalars. ``out``: rotor speeds (4), torque (3), thrust,
    saturated (1 or 0); ``st`` (the integrators and previous errors) is updated in place."""
    max_rate, rate_lim, F_min, F_max, dt = g[26], g[28], g[29], g[30], g[31]
    F = np.empty(3)
    saturated = _thrust_vector(p, v, ref_p, has_p, ref_v, ref_a, g, c, st, F)
    # Desired attitude: body z along F, heading from the yaw setpoint
    nF = math.sqrt(F[0] * F[0] + F[1] * F[1] + F[2] * F[2])
    zx, zy, zz = F[0] / nF, F[1] / nF, F[2] / nF
    cx, cy = math.cos(yaw), math.sin(yaw)
    yx, yy, yz = -zz * cy, zz * cx, zx * cy - zy * cx  # z_d x (cos, sin, 0)
    ny = math.sqrt(yx * yx + yy * yy + yz * yz)
    yx, yy, yz = yx / ny, yy / ny, yz / ny
    xx, xy, xz = yy * zz - yz * zy, yz * zx - yx * zz, yx * zy - yy * zx  # y_d x z_d
    # R_W_B from the quaternion; E = R^T R_d; the geometric attitude error (Lee, Leok and
    # McClamroch) e_R = vee(E - E^T) / 2, the rotation towards the desired attitude (body).
    qx, qy, qz, qw = q[0], q[1], q[2], q[3]
    r00, r01, r02 = 1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)
    r10, r11, r12 = 2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)
    r20, r21, r22 = 2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)
    # E[i, j] = R[:, i] . R_d[:, j], R_d's columns x_d, y_d, z_d
    e21 = r02 * yx + r12 * yy + r22 * yz
    e12 = r01 * zx + r11 * zy + r21 * zz
    e02 = r00 * zx + r10 * zy + r20 * zz
    e20 = r02 * xx + r12 * xy + r22 * xz
    e10 = r01 * xx + r11 * xy + r21 * xz
    e01 = r00 * yx + r10 * yy + r20 * yz
    att = (0.5 * (e21 - e12), 0.5 * (e02 - e20), 0.5 * (e10 - e01))
    # Attitude -> rates (P, limited) -> torques (PID plus the gyroscopic term)
    alpha = np.empty(3)
    for k in range(3):
        w_sp = _clip(g[12 + k] * att[k], max_rate)
        rerr = w_sp - w[k]
        d_rerr = (rerr - st[9 + k]) / dt if st[13] > 0.0 else 0.0
        st[9 + k] = rerr
        st[3 + k] = _clip(st[3 + k] + g[18 + k] * rerr * dt, rate_lim)
        alpha[k] = g[15 + k] * rerr + st[3 + k] + g[21 + k] * d_rerr
    st[13] = 1.0
    Ix, Iy, Iz = c[2], c[3], c[4]
    out[4] = Ix * alpha[0] + (w[1] * Iz * w[2] - w[2] * Iy * w[1])
    out[5] = Iy * alpha[1] + (w[2] * Ix * w[0] - w[0] * Iz * w[2])
    out[6] = Iz * alpha[2] + (w[0] * Iy * w[1] - w[1] * Ix * w[0])
    # Collective thrust along the current body z, then the mixer: rotor thrusts solve
    # [T, tau] = A f, each clipped to what a rotor gives, as speeds.
    thrust = min(max(F[0] * r02 + F[1] * r12 + F[2] * r22, F_min), F_max)
    out[7] = thrust
    out[8] = 1.0 if saturated else 0.0
    f_min, f_max, k_thrust = c[5], c[6], c[7]
    for i in range(4):
        f = c[8 + 4 * i] * thrust
        for j in range(3):
            f += c[8 + 4 * i + 1 + j] * out[4 + j]
        out[i] = math.sqrt(min(max(f, f_min), f_max) / k_thrust)
