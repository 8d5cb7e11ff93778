from __future__ import annotations

import numpy as np
import pytest

from quadnav.errors import SimError
from quadnav.sim.euler_lagrange import EulerLagrangeParams, EulerLagrangeQuadrotor

P = EulerLagrangeParams()


def test_hover_is_an_equilibrium() -> None:
    s0 = np.zeros(12)
    s0[2] = 3.0
    sim = EulerLagrangeQuadrotor(P, s0=s0)
    for _ in range(2000):
        s = sim.step(P.mass_kg * P.gravity_m_s2, np.zeros(3))
    np.testing.assert_allclose(s, s0, atol=1e-12)


def test_rk4_is_exact_on_a_constant_angular_acceleration() -> None:
    """psi'' = const is a polynomial of degree 2: RK4 integrates it exactly."""
    sim = EulerLagrangeQuadrotor(P, s0=np.zeros(12), dt_s=0.01)
    for _ in range(100):
        s = sim.step(P.mass_kg * P.gravity_m_s2, np.array([0.0, 0.0, 0.3]))
    assert s[5] == pytest.approx(0.5 * 0.3 * 1.0**2, rel=1e-12)
    assert s[11] == pytest.approx(0.3, rel=1e-12)


@pytest.mark.parametrize(("angle_index", "axis", "sign"), [(4, 0, 1.0), (3, 1, -1.0)])
def test_tilt_accelerates_as_eq_a8_says(angle_index: int, axis: int, sign: float) -> None:
    """x'' = g theta and y'' = -g phi for small angles, with thrust compensating the tilt."""
    s0 = np.zeros(12)
    s0[angle_index] = 0.05
    sim = EulerLagrangeQuadrotor(P, s0=s0, dt_s=0.001)
    u = P.mass_kg * P.gravity_m_s2 / np.cos(0.05)
    s = sim.step(u, np.zeros(3))
    accel = s[6 + axis] / 0.001
    assert accel == pytest.approx(sign * P.gravity_m_s2 * np.tan(0.05), rel=1e-6)


def test_bad_input() -> None:
    with pytest.raises(SimError):
        EulerLagrangeQuadrotor(P, s0=np.zeros(11))
    sim = EulerLagrangeQuadrotor(P, s0=np.zeros(12))
    with pytest.raises(SimError, match="non-finite"):
        sim.step(float("nan"), np.zeros(3))
