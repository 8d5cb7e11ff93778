"""The planar quadrotor of thesis 000, section 2.3 (eqs 2.14-2.22).

The vehicle moves in the vertical x-z plane of the world (ENU: x east, z up). Its
attitude is one angle ``theta_rad``: the rotation of the FLU body about the world +y
axis, so a positive angle turns the thrust axis towards +x. (The thesis measures its
angle the other way round, about -y, so its +30 degrees is our -30 degrees; the
trajectory is the same.)

Dynamics, integrated with the thesis's semi-implicit Euler step of ``dt``::

    theta_dd = tau / I                          (2.14)
    theta_d += dt * theta_dd ; theta += dt * theta_d       (2.15, 2.16)
    a = (R(theta) [0, T] + [0, -m g]) / m       (2.17-2.20)
    v += dt * a ; p += dt * v                   (2.21, 2.22)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import SimError
from quadnav.messages import VehicleState
from quadnav.units import GRAVITY_M_S2

__all__ = ["PlanarParams", "PlanarQuadrotor", "PlanarState"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanarParams:
    """Physical parameters; the defaults are the thesis's (1 kg, a 0.45 m rod's inertia)."""

    mass_kg: float = 1.0
    gravity_m_s2: float = GRAVITY_M_S2
    inertia_kg_m2: float = 1.0 * 0.45**2 / 12.0

    def __post_init__(self) -> None:
        for name in ("mass_kg", "gravity_m_s2", "inertia_kg_m2"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0.0:
                raise SimError(f"PlanarParams.{name} must be finite and > 0, got {value}")


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanarState:
    """State of the planar vehicle at ``t_ns``; ``a_xz`` is the acceleration of the last step."""

    t_ns: int
    p_xz: FloatArray
    v_xz: FloatArray
    a_xz: FloatArray
    theta_rad: float
    theta_rate_rad_s: float

    def to_vehicle_state(self) -> VehicleState:
        """The same state in the common 3-D form (y = 0, rotation about +y)."""
        half = 0.5 * self.theta_rad
        return VehicleState(
            t_ns=self.t_ns,
            p_W_B=np.array([self.p_xz[0], 0.0, self.p_xz[1]]),
            v_W_B=np.array([self.v_xz[0], 0.0, self.v_xz[1]]),
            a_W_B=np.array([self.a_xz[0], 0.0, self.a_xz[1]]),
            q_W_B_xyzw=np.array([0.0, np.sin(half), 0.0, np.cos(half)]),
            w_B=np.array([0.0, self.theta_rate_rad_s, 0.0]),
        )


class PlanarQuadrotor:
    """Steps the planar dynamics with a fixed ``dt``; thrust and torque come from a callable."""

    def __init__(self, params: PlanarParams, *, dt_ns: int, t0_ns: int = 0) -> None:
        if dt_ns <= 0:
            raise SimError(f"the simulation step must be > 0 ns, got {dt_ns}")
        self.params = params
        self.dt_ns = int(dt_ns)
        self.state = PlanarState(
            t_ns=int(t0_ns),
            p_xz=np.zeros(2),
            v_xz=np.zeros(2),
            a_xz=np.zeros(2),
            theta_rad=0.0,
            theta_rate_rad_s=0.0,
        )

    def step(self, thrust_n: float, torque_nm: float) -> PlanarState:
        """Advance one step with the given actuation; returns the new state."""
        if not (np.isfinite(thrust_n) and np.isfinite(torque_nm)):
            raise SimError(f"non-finite actuation: thrust {thrust_n}, torque {torque_nm}")
        p = self.params
        s = self.state
        dt = self.dt_ns * 1e-9
        with np.errstate(all="ignore"):  # a diverging state is caught below, in one line
            theta_rate = s.theta_rate_rad_s + dt * torque_nm / p.inertia_kg_m2
            theta = s.theta_rad + dt * theta_rate
            # Thrust along body +z, rotated into the world x-z plane by theta about +y.
            a = np.array(
                [
                    thrust_n * np.sin(theta) / p.mass_kg,
                    thrust_n * np.cos(theta) / p.mass_kg - p.gravity_m_s2,
                ]
            )
            v = s.v_xz + dt * a
            pos = s.p_xz + dt * v
        self.state = PlanarState(
            t_ns=s.t_ns + self.dt_ns,
            p_xz=pos,
            v_xz=v,
            a_xz=a,
            theta_rad=float(theta),
            theta_rate_rad_s=float(theta_rate),
        )
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(v)) and np.isfinite(theta)):
            raise SimError(f"the planar simulation diverged at t = {self.state.t_ns * 1e-9:.4g} s")
        return self.state
