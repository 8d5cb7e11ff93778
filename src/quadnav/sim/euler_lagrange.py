"""The Euler-Lagrange quadrotor model of thesis 002 (appendix A, eq. A.8), as written.

Generalised coordinates ``q = (x, y, z, phi, theta, psi)`` (z up, ZYX Euler angles: roll
about x, pitch about y, yaw about z), inputs the total thrust ``u`` and the torques after
the change of variables A.7, ``tau~ = J^-1 (tau - C eta')``, which makes each angle a double
integrator::

    m x'' = u (sin phi sin psi + cos phi cos psi sin theta)
    m y'' = u (cos phi sin theta sin psi - cos psi sin phi)
    m z'' = u cos theta cos phi - m g
    phi'' = tau~_phi,  theta'' = tau~_theta,  psi'' = tau~_psi

State ``s = (x, y, z, phi, theta, psi, x', y', z', phi', theta', psi')``, integrated with RK4.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import SimError
from quadnav.messages import VehicleState
from quadnav.sim.integrate import rk4_step
from quadnav.units import GRAVITY_M_S2

__all__ = ["EulerLagrangeParams", "EulerLagrangeQuadrotor", "el_derivative"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class EulerLagrangeParams:
    """Mass and gravity (the thesis gives g = 9.8 m/s^2 and no mass; 1.5 kg is its class of frame)."""

    mass_kg: float = 1.5
    gravity_m_s2: float = GRAVITY_M_S2

    def __post_init__(self) -> None:
        if not (self.mass_kg > 0 and self.gravity_m_s2 > 0):
            raise SimError("EulerLagrangeParams: mass and gravity must be > 0")


def el_derivative(s: FloatArray, u: float, tau: FloatArray, p: EulerLagrangeParams) -> FloatArray:
    """``s'`` of eq. A.8 for thrust ``u`` (N) and ``tau = (tau~_phi, tau~_theta, tau~_psi)`` (rad/s^2)."""
    phi, theta, psi = s[3], s[4], s[5]
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)
    a = u / p.mass_kg
    out = np.empty(12)
    out[0:6] = s[6:12]
    out[6] = a * (sf * sp + cf * cp * st)
    out[7] = a * (cf * st * sp - cp * sf)
    out[8] = a * ct * cf - p.gravity_m_s2
    out[9:12] = tau
    return out


class EulerLagrangeQuadrotor:
    """Steps eq. A.8 with RK4; the state is validated (finite) after every step."""

    def __init__(self, params: EulerLagrangeParams, *, s0: FloatArray, dt_s: float = 0.001) -> None:
        s0 = np.asarray(s0, dtype=np.float64)
        if s0.shape != (12,) or not np.isfinite(s0).all():
            raise SimError(f"the Euler-Lagrange state must be 12 finite numbers, got {s0.shape}")
        if not dt_s > 0:
            raise SimError(f"the step must be > 0 s, got {dt_s}")
        self.params = params
        self.dt_s = float(dt_s)
        self.s = s0.copy()

    def vehicle_state(self, t_ns: int, q_W_B_xyzw: FloatArray, w_B: FloatArray) -> VehicleState:
        """The true state at ``t_ns`` for a sensor (a camera rendered along the flight): position
        and velocity its own, the attitude and body rate its Euler angles and their rates give
        (converted by the caller, ``control.base``'s conventions), no acceleration sampled."""
        s = self.s
        return VehicleState(t_ns=int(t_ns), p_W_B=s[0:3].copy(), v_W_B=s[6:9].copy(),
                            a_W_B=np.zeros(3), q_W_B_xyzw=np.asarray(q_W_B_xyzw, np.float64),
                            w_B=np.asarray(w_B, np.float64))  # fmt: skip

    def step(self, u: float, tau: FloatArray) -> FloatArray:
        tau = np.asarray(tau, dtype=np.float64)
        if not (math.isfinite(u) and np.isfinite(tau).all()):
            raise SimError(f"non-finite input: u {u}, tau {tau.tolist()}")
        p = self.params
        with np.errstate(all="ignore"):  # a diverging state is caught below, in one line
            self.s = rk4_step(lambda s: el_derivative(s, u, tau, p), self.s, self.dt_s)
        if not np.isfinite(self.s).all():
            raise SimError("the Euler-Lagrange simulation diverged")
        return self.s
