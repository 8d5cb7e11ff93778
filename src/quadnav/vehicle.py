"""The description of a multirotor shared by the simulator and the controllers: mass,
inertia, rotor geometry and limits, and the mixer that maps thrust and torques to rotors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import SimError
from quadnav.units import GRAVITY_M_S2

__all__ = ["Mixer", "RigidBodyParams"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class RigidBodyParams:
    """A 1.5 kg, 450 mm quadrotor by default (close to the F450-class frames of the theses)."""

    mass_kg: float = 1.5
    inertia_kg_m2: tuple[float, float, float] = (0.029, 0.029, 0.055)
    arm_length_m: float = 0.225
    config: Literal["x", "+"] = "x"
    k_thrust_n_s2: float = 1.5e-5  # N per (rad/s)^2
    k_torque_nm_s2: float = 2.4e-7  # N m per (rad/s)^2
    omega_min_rad_s: float = 0.0
    omega_max_rad_s: float = 1100.0
    motor_tau_s: float = 0.02
    drag_n_s_m: tuple[float, float, float] = (0.25, 0.25, 0.35)  # linear drag per body axis
    gravity_m_s2: float = GRAVITY_M_S2

    def __post_init__(self) -> None:
        positive = {
            "mass_kg": self.mass_kg,
            "arm_length_m": self.arm_length_m,
            "k_thrust_n_s2": self.k_thrust_n_s2,
            "k_torque_nm_s2": self.k_torque_nm_s2,
            "omega_max_rad_s": self.omega_max_rad_s,
            "motor_tau_s": self.motor_tau_s,
            "gravity_m_s2": self.gravity_m_s2,
        }
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0):
                raise SimError(f"RigidBodyParams.{name} must be finite and > 0, got {value}")
        if any(not v > 0 for v in self.inertia_kg_m2):
            raise SimError("RigidBodyParams.inertia_kg_m2 must be positive")
        if not 0 <= self.omega_min_rad_s < self.omega_max_rad_s:
            raise SimError("RigidBodyParams needs 0 <= omega_min_rad_s < omega_max_rad_s")
        if self.max_thrust_n < self.mass_kg * self.gravity_m_s2 * 1.2:
            raise SimError(
                "the rotors cannot lift 1.2x the vehicle's weight: raise omega_max or k_thrust"
            )

    @property
    def max_thrust_n(self) -> float:
        return 4 * self.k_thrust_n_s2 * self.omega_max_rad_s**2

    @property
    def hover_omega_rad_s(self) -> float:
        return math.sqrt(self.mass_kg * self.gravity_m_s2 / (4 * self.k_thrust_n_s2))

    def rotor_geometry(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Rotor x, y (m, FLU) and spin directions, front-left first, counter-clockwise."""
        start = math.pi / 4 if self.config == "x" else 0.0
        ang = start + np.arange(4) * math.pi / 2
        spin = np.array([1.0, -1.0, 1.0, -1.0])
        return self.arm_length_m * np.cos(ang), self.arm_length_m * np.sin(ang), spin


@dataclass(frozen=True, slots=True)
class Mixer:
    """Collective thrust and body torques to rotor speed commands, with limits.

    Rotor thrusts solve ``[T, tau_x, tau_y, tau_z] = A f``; each is clipped to what a rotor
    can give (never negative) before becoming a speed command.
    """

    params: RigidBodyParams
    A: FloatArray = field(init=False)
    A_inv: FloatArray = field(init=False)

    def __post_init__(self) -> None:
        x, y, spin = self.params.rotor_geometry()
        km = self.params.k_torque_nm_s2 / self.params.k_thrust_n_s2
        A = np.vstack([np.ones(4), y, -x, -spin * km])
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "A_inv", np.linalg.inv(A))

    def __call__(self, thrust_n: float, torque_nm: FloatArray) -> FloatArray:
        p = self.params
        f = self.A_inv @ np.array([thrust_n, *torque_nm])
        f_max = p.k_thrust_n_s2 * p.omega_max_rad_s**2
        f_min = p.k_thrust_n_s2 * p.omega_min_rad_s**2
        return np.asarray(np.sqrt(np.clip(f, f_min, f_max) / p.k_thrust_n_s2), dtype=np.float64)
