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
from quadnav.geometry.rotations import cross3, rotation_matrix_xyzw
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
    """Runs every loop at the call rate (1 kHz in the simulator); stateful (integrators)."""

    def __init__(
        self, params: RigidBodyParams, gains: CascadedPidGains | None = None, *, dt_s: float = 0.001
    ) -> None:
        self.params = params
        self.g = gains or CascadedPidGains()
        self.dt = float(dt_s)
        self.mixer = Mixer(params)
        self._I = np.asarray(params.inertia_kg_m2)
        self._vel_int = np.zeros(3)
        self._rate_int = np.zeros(3)
        self._prev_vel_err: FloatArray | None = None  # no derivative kick on the first call
        self._prev_rate_err: FloatArray | None = None

    def __call__(self, t_ns: int, est: StateEstimate, ref: Setpoint) -> Command:
        """Rotor speed commands (rad/s) for the setpoint (``t_ns`` unused: fixed ``dt_s``)."""
        g, p, dt = self.g, self.params, self.dt
        kp_pos, kp_vel, ki_vel, kd_vel = (
            np.asarray(x) for x in (g.kp_pos, g.kp_vel, g.ki_vel, g.kd_vel)
        )
        # Position -> velocity
        v_sp = np.zeros(3) if ref.v is None else np.asarray(ref.v, dtype=np.float64).copy()
        if ref.p is not None:
            v_sp = v_sp + kp_pos * (ref.p - est.p_W_B)
        speed = float(np.linalg.norm(v_sp))
        if speed > g.max_vel_m_s:
            v_sp *= g.max_vel_m_s / speed
        # Velocity -> acceleration (PID, anti-windup)
        err = v_sp - est.v_W_B
        d_err = np.zeros(3) if self._prev_vel_err is None else (err - self._prev_vel_err) / dt
        self._prev_vel_err = err
        a_sp = kp_vel * err + self._vel_int + kd_vel * d_err
        if ref.a is not None:
            a_sp = a_sp + ref.a
        # Thrust vector, limited in tilt and magnitude
        F = p.mass_kg * (a_sp + np.array([0.0, 0.0, p.gravity_m_s2]))
        F_min = g.min_thrust_fraction * p.max_thrust_n
        F_max = g.max_thrust_fraction * p.max_thrust_n
        F[2] = max(F[2], F_min)
        horiz = math.hypot(F[0], F[1])
        max_h = F[2] * math.tan(g.max_tilt_rad)
        tilt_limited = horiz > max_h
        if tilt_limited:
            F[0:2] *= max_h / horiz
        norm = float(np.linalg.norm(F))
        thrust_limited = norm > F_max
        if thrust_limited:
            F *= F_max / norm
        saturated = bool(tilt_limited or thrust_limited)
        if not saturated:  # integrate only while the output is achievable
            self._vel_int = np.clip(
                self._vel_int + ki_vel * err * dt,
                -g.vel_integral_limit_m_s2,
                g.vel_integral_limit_m_s2,
            )
        # Desired attitude: body z along F, heading from the yaw setpoint
        z_d = F / np.linalg.norm(F)
        x_c = np.array([math.cos(ref.yaw_rad), math.sin(ref.yaw_rad), 0.0])
        y_d = cross3(z_d, x_c)
        y_d /= np.linalg.norm(y_d)
        x_d = cross3(y_d, z_d)
        R_d = np.column_stack([x_d, y_d, z_d])
        R = rotation_matrix_xyzw(est.q_W_B_xyzw)
        # Attitude -> rates: P on the geometric attitude error e_R = vee(R^T R_d - R_d^T R) / 2
        # (Lee, Leok and McClamroch), the rotation towards the desired attitude in the body frame.
        E = R.T @ R_d
        att_err = 0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
        w_sp = np.clip(np.asarray(g.kp_att) * att_err, -g.max_rate_rad_s, g.max_rate_rad_s)
        # Rates -> torques (PID plus the gyroscopic term)
        w = require_rate(est, "the cascaded PID")
        rerr = w_sp - w
        d_rerr = np.zeros(3) if self._prev_rate_err is None else (rerr - self._prev_rate_err) / dt
        self._prev_rate_err = rerr
        self._rate_int = np.clip(
            self._rate_int + np.asarray(g.ki_rate) * rerr * dt,
            -g.rate_integral_limit,
            g.rate_integral_limit,
        )
        alpha = np.asarray(g.kp_rate) * rerr + self._rate_int + np.asarray(g.kd_rate) * d_rerr
        torque = self._I * alpha + cross3(w, self._I * w)
        # Collective thrust along the current body z
        thrust = float(F @ R[:, 2])
        thrust = min(max(thrust, F_min), F_max)
        return Command(
            thrust_n=thrust,
            torque_B_nm=torque,
            rotor_rad_s=self.mixer(thrust, torque),
            saturated=saturated,
        )
