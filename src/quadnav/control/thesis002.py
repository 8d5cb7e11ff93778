"""Thesis 002's controllers for the Euler-Lagrange model (chapter 5).

* :class:`PdController` (sections 5.1-5.2): altitude PD, x/y through virtual pitch/roll
  references, attitude PD. Gains are checked with Routh-Hurwitz on the closed loops of the
  linearised model (the altitude loop and the full 4th-order x-pitch and y-roll chains); an
  unstable set is a :class:`~quadnav.errors.ControlError`.
* :class:`NestedSaturationController` (sections 5.3-5.4, after Teel): the same altitude and
  yaw laws, and for x-pitch and y-roll a chain of four nested saturations whose levels are
  parameters. For tracking, the position, velocity, angle and rate in the law are replaced by
  their errors from the reference (the angle reference being the acceleration the trajectory
  needs, ``theta_d = x''_d / g``), which is what the thesis's tracking law intends.

Both are a :class:`~quadnav.control.base.Controller`: they read the estimate's position,
velocity, attitude (as ZYX Euler angles) and body rate (turned into Euler angle rates, the
model's ``phi', theta', psi'``), and the setpoint's position, velocity and yaw (the nested
saturations also its acceleration, jerk and snap; a field left None is zero). They return a
``thrust_tau`` :class:`~quadnav.control.base.Command`: the thrust ``u`` and ``tau~`` of eq. A.8.

:data:`PD_GAIN_SETS` names gain sets of the PD controller: ``table_5_1`` is the attitude gains
thesis 002 tuned on its vehicle (Table 5.1: Kp 120 and Kd 40 for roll and pitch, Kp 90 and
Kd 70 for yaw), the other gains staying at their defaults.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.control.base import (
    Command,
    Setpoint,
    euler_rates_from_body_rates,
    euler_rpy_from_quat_xyzw,
    require_rate,
)
from quadnav.control.stability import routh_hurwitz_stable
from quadnav.errors import ControlError
from quadnav.messages import StateEstimate
from quadnav.units import GRAVITY_M_S2

__all__ = ["PD_GAIN_SETS", "NestedSaturationController", "PdController"]

FloatArray = NDArray[np.float64]

#: Named gain sets of :class:`PdController` (keyword overrides of its defaults).
PD_GAIN_SETS: dict[str, dict[str, float]] = {
    "default": {},
    "table_5_1": {"kp_att": 120.0, "kd_att": 40.0, "kp_yaw": 90.0, "kd_yaw": 70.0},
}

_ZERO3 = np.zeros(3)


def _or_zero(x: FloatArray | None) -> FloatArray:
    return _ZERO3 if x is None else x


def _model_state(est: StateEstimate, who: str) -> list[float]:
    """The model's ``(x, y, z, phi, theta, psi, x', y', z', phi', theta', psi')``."""
    roll, pitch, yaw = euler_rpy_from_quat_xyzw(est.q_W_B_xyzw)
    rates = euler_rates_from_body_rates(roll, pitch, require_rate(est, who))
    return [*est.p_W_B.tolist(), roll, pitch, yaw, *est.v_W_B.tolist(), *rates]


def _position(ref: Setpoint, who: str) -> FloatArray:
    if ref.p is None:
        raise ControlError(f"{who} flies to a position: the setpoint has none")
    return ref.p


def _sat(x: float, level: float) -> float:
    return level if x > level else (-level if x < -level else x)


@dataclass(frozen=True, slots=True, kw_only=True)
class PdController:
    """Thesis 002 section 5.1 PD laws (gains in SI: N/m, N s/m, rad/m, rad s/m, 1/s^2, 1/s)."""

    mass_kg: float = 1.5
    gravity_m_s2: float = GRAVITY_M_S2
    kp_z: float = 12.0
    kd_z: float = 8.0
    kp_xy: float = 0.1
    kd_xy: float = 0.25
    kp_att: float = 16.0
    kd_att: float = 8.0
    kp_yaw: float = 4.0
    kd_yaw: float = 4.0
    max_tilt_rad: float | None = None

    def __post_init__(self) -> None:
        m, g = self.mass_kg, self.gravity_m_s2
        loops = {
            "altitude (kp_z, kd_z)": [1.0, self.kd_z / m, self.kp_z / m],
            "x-pitch and y-roll (kp_xy, kd_xy, kp_att, kd_att)": [
                1.0, self.kd_att, self.kp_att, g * self.kp_att * self.kd_xy, g * self.kp_att * self.kp_xy,
            ],
            "yaw (kp_yaw, kd_yaw)": [1.0, self.kd_yaw, self.kp_yaw],
        }  # fmt: skip
        for name, poly in loops.items():
            if not routh_hurwitz_stable(poly):
                raise ControlError(f"PD gains make the {name} loop unstable (Routh-Hurwitz)")
        if self.max_tilt_rad is not None and not 0 < self.max_tilt_rad < math.pi / 2:
            raise ControlError("max_tilt_rad must lie in (0, pi/2)")

    @classmethod
    def from_gain_set(cls, name: str, **overrides: float) -> PdController:
        """The controller with the gain set ``name`` of :data:`PD_GAIN_SETS`, then ``overrides``."""
        if name not in PD_GAIN_SETS:
            raise ControlError(f"no PD gain set {name!r}; choose from {', '.join(PD_GAIN_SETS)}")
        return cls(**{**PD_GAIN_SETS[name], **overrides})

    def __call__(self, t_ns: int, est: StateEstimate, ref: Setpoint) -> Command:
        x, y, z, phi, theta, psi, vx, vy, vz, dphi, dtheta, dpsi = _model_state(est, "the PD laws")
        p_ref, v_ref = _position(ref, "the PD laws"), _or_zero(ref.v)
        u = (
            self.mass_kg * self.gravity_m_s2
            + self.kp_z * (p_ref[2] - z)
            + self.kd_z * (v_ref[2] - vz)
        )
        theta_d = self.kp_xy * (p_ref[0] - x) + self.kd_xy * (v_ref[0] - vx)
        phi_d = self.kp_xy * (y - p_ref[1]) + self.kd_xy * (vy - v_ref[1])  # y'' = -g phi
        if self.max_tilt_rad is not None:
            theta_d = _sat(theta_d, self.max_tilt_rad)
            phi_d = _sat(phi_d, self.max_tilt_rad)
        tau = np.array(
            [
                -self.kp_att * (phi - phi_d) - self.kd_att * dphi,
                -self.kp_att * (theta - theta_d) - self.kd_att * dtheta,
                -self.kp_yaw * (psi - ref.yaw_rad) - self.kd_yaw * dpsi,
            ]
        )
        return Command(thrust_n=float(u), tau_B_rad_s2=tau)


@dataclass(frozen=True, slots=True, kw_only=True)
class NestedSaturationController:
    """Thesis 002 sections 5.3-5.4. ``levels_rad_s2`` are the saturation levels M1..M4 of
    the x-pitch and y-roll chains, outermost first; Teel's condition M(i+1) < M(i) / 2 is
    checked."""

    mass_kg: float = 1.5
    gravity_m_s2: float = GRAVITY_M_S2
    kp_z: float = 12.0
    kd_z: float = 8.0
    kp_yaw: float = 4.0
    kd_yaw: float = 4.0
    levels_rad_s2: tuple[float, float, float, float] = (4.0, 1.9, 0.9, 0.4)

    def __post_init__(self) -> None:
        m = self.mass_kg
        if not routh_hurwitz_stable([1.0, self.kd_z / m, self.kp_z / m]):
            raise ControlError("altitude gains (kp_z, kd_z) are unstable (Routh-Hurwitz)")
        if not routh_hurwitz_stable([1.0, self.kd_yaw, self.kp_yaw]):
            raise ControlError("yaw gains (kp_yaw, kd_yaw) are unstable (Routh-Hurwitz)")
        M = self.levels_rad_s2
        if len(M) != 4 or any(not v > 0 for v in M):
            raise ControlError("levels_rad_s2 needs four positive saturation levels")
        for i in range(3):
            if not M[i + 1] < M[i] / 2:
                raise ControlError(
                    f"saturation levels must satisfy M{i + 2} < M{i + 1} / 2 (Teel), got {M}"
                )

    def _chain(self, ang: float, rate: float, pos: float, vel: float) -> float:
        """The nested law ``a'' = chain`` for one axis of ``p'' = -g a``, in normalised
        variables (pos and vel already divided by g), as printed in thesis 002 eq. for tau~_theta."""
        M1, M2, M3, M4 = self.levels_rad_s2
        inner = _sat(rate + 3.0 * ang - 3.0 * vel - pos, M4)
        inner = _sat(2.0 * ang + rate - vel + inner, M3)
        inner = _sat(ang + rate + inner, M2)
        return -_sat(rate + inner, M1)

    def __call__(self, t_ns: int, est: StateEstimate, ref: Setpoint) -> Command:
        who = "the nested saturations"
        x, y, z, phi, theta, psi, vx, vy, vz, dphi, dtheta, dpsi = _model_state(est, who)
        g = self.gravity_m_s2
        p_ref, v_ref, a_ref, j_ref = (
            _position(ref, who),
            _or_zero(ref.v),
            _or_zero(ref.a),
            _or_zero(ref.j),
        )
        r1 = -self.kd_z * (vz - v_ref[2]) - self.kp_z * (z - p_ref[2])
        u = (r1 + self.mass_kg * g) / (math.cos(phi) * math.cos(theta))
        # The printed laws are for p'' = -g a (x'' = -g theta, y'' = +g phi); model A.8 has
        # x'' = +g theta and y'' = -g phi, so the chain acts on a = -theta for x and a = phi for y.
        # Tracking: errors from the reference; the angle from the acceleration the reference needs.
        snap = _or_zero(ref.snap)
        tau_theta = snap[0] / g - self._chain(
            -(theta - a_ref[0] / g),
            -(dtheta - j_ref[0] / g),
            (x - p_ref[0]) / g,
            (vx - v_ref[0]) / g,
        )
        tau_phi = -snap[1] / g + self._chain(
            phi + a_ref[1] / g, dphi + j_ref[1] / g, (y - p_ref[1]) / g, (vy - v_ref[1]) / g
        )
        tau_psi = -self.kd_yaw * dpsi - self.kp_yaw * (psi - ref.yaw_rad)
        return Command(thrust_n=float(u), tau_B_rad_s2=np.array([tau_phi, tau_theta, tau_psi]))
