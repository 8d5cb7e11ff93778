"""The controller of thesis 000's planar simulation (section 2.3, appendix A).

It acts on the true state (the thesis does this to isolate the estimator): a vertical
velocity loop and a PD attitude loop, with the thesis's setpoint profile: climb at 2 m/s
for the first quarter of the run, then tilt to one side and to the other.

    thrust = m g / cos(theta) + k_climb (vz_ref - vz)
    torque = k_tilt (theta_ref - theta) - kd_tilt theta_rate

It is a :class:`~quadnav.control.base.Controller` on the planar vehicle in its 3-D form (the
x-z plane, pitch about +y, as ``PlanarState.to_vehicle_state`` gives it): it reads the
estimate's vertical velocity, its pitch (from ``q_W_B_xyzw``) and pitch rate (``w_B[1]``),
and the setpoint's vertical velocity ``v[2]`` and tilt (the pitch of ``q_W_B_xyzw``; None is
level). :meth:`PlanarSetpointProfile.setpoint` gives the thesis's profile as setpoints. The
command is ``thrust_torque`` with the torque about +y in ``torque_B_nm[1]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from quadnav.control.base import Command, Setpoint, require_rate
from quadnav.errors import ControlError
from quadnav.messages import StateEstimate
from quadnav.units import GRAVITY_M_S2

__all__ = ["PlanarSetpointProfile", "ThesisPlanarController"]


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanarSetpointProfile:
    """Climb for ``climb_end_s``, then ``theta_ref = -tilt`` from ``tilt_start_s`` and
    ``+tilt`` from ``tilt_switch_s`` (our sign: the vehicle heads to -x first, as in the thesis).
    """

    climb_rate_m_s: float = 2.0
    climb_end_s: float = 2.5
    tilt_rad: float = math.pi / 6
    tilt_start_s: float = 7.0
    tilt_switch_s: float = 8.5

    def __post_init__(self) -> None:
        if not self.tilt_start_s <= self.tilt_switch_s:
            raise ControlError("tilt_start_s must not come after tilt_switch_s")
        if not abs(self.tilt_rad) < math.pi / 2:
            raise ControlError(f"tilt must be below 90 degrees, got {math.degrees(self.tilt_rad)}")

    def reference(self, t_s: float) -> tuple[float, float]:
        """(vertical velocity reference in m/s, tilt reference in rad) at ``t_s``."""
        vz_ref = self.climb_rate_m_s if t_s < self.climb_end_s else 0.0
        if t_s < self.tilt_start_s:
            theta_ref = 0.0
        elif t_s < self.tilt_switch_s:
            theta_ref = -self.tilt_rad
        else:
            theta_ref = self.tilt_rad
        return vz_ref, theta_ref

    def setpoint(self, t_s: float) -> Setpoint:
        """The reference at ``t_s`` as a setpoint: ``v = (0, 0, vz_ref)``, tilt about +y."""
        vz_ref, theta_ref = self.reference(t_s)
        half = 0.5 * theta_ref
        return Setpoint(
            v=np.array([0.0, 0.0, vz_ref]),
            q_W_B_xyzw=np.array([0.0, math.sin(half), 0.0, math.cos(half)]),
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class ThesisPlanarController:
    """Thrust and torque from the true state; gains are the thesis's."""

    mass_kg: float = 1.0
    gravity_m_s2: float = GRAVITY_M_S2
    k_climb: float = 2.0
    k_tilt: float = 0.2
    kd_tilt: float = 0.1
    profile: PlanarSetpointProfile = PlanarSetpointProfile()
    t0_ns: int = 0

    def __post_init__(self) -> None:
        # The attitude loop I th'' = -kd th' - k th is stable for k > 0 and kd > 0 (Routh-Hurwitz).
        if self.k_tilt <= 0.0 or self.kd_tilt <= 0.0:
            raise ControlError("k_tilt and kd_tilt must be > 0 for a stable attitude loop")
        if self.k_climb <= 0.0:
            raise ControlError("k_climb must be > 0 for a stable climb-rate loop")

    def setpoint(self, t_ns: int) -> Setpoint:
        """The profile's setpoint at ``t_ns`` (its clock starts at ``t0_ns``)."""
        return self.profile.setpoint((t_ns - self.t0_ns) * 1e-9)

    def __call__(self, t_ns: int, est: StateEstimate, ref: Setpoint) -> Command:
        """Thrust (N) and the torque about +y (N m) for the planar vehicle."""
        vz_ref = 0.0 if ref.v is None else float(ref.v[2])
        theta_ref = 0.0 if ref.q_W_B_xyzw is None else _pitch(ref.q_W_B_xyzw)
        theta = _pitch(est.q_W_B_xyzw)
        theta_rate = float(require_rate(est, "the planar controller")[1])
        thrust = self.mass_kg * self.gravity_m_s2 / math.cos(theta)
        thrust += self.k_climb * (vz_ref - float(est.v_W_B[2]))
        torque = self.k_tilt * (theta_ref - theta) - self.kd_tilt * theta_rate
        return Command(thrust_n=thrust, torque_B_nm=np.array([0.0, torque, 0.0]))


def _pitch(q_xyzw: np.ndarray) -> float:
    """The rotation about +y of a planar attitude (a quaternion about y only)."""
    return 2.0 * math.atan2(float(q_xyzw[1]), float(q_xyzw[3]))
