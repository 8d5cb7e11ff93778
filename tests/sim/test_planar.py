from __future__ import annotations

import math

import numpy as np
import pytest

from quadnav.errors import SimError
from quadnav.sim import PlanarParams, PlanarQuadrotor

DT_NS = 10_000_000
P = PlanarParams()


def test_hover_thrust_holds_the_vehicle_still() -> None:
    sim = PlanarQuadrotor(P, dt_ns=DT_NS)
    for _ in range(500):
        s = sim.step(P.mass_kg * P.gravity_m_s2, 0.0)
    np.testing.assert_allclose(s.p_xz, 0.0, atol=1e-12)
    assert s.t_ns == 500 * DT_NS


def test_free_fall_matches_the_semi_implicit_euler_closed_form() -> None:
    """v_n = -g n dt and p_n = -g dt^2 n (n + 1) / 2 for the thesis's step (eqs 2.21, 2.22)."""
    sim = PlanarQuadrotor(P, dt_ns=DT_NS)
    n = 137
    for _ in range(n):
        s = sim.step(0.0, 0.0)
    dt = DT_NS * 1e-9
    assert s.v_xz[1] == pytest.approx(-P.gravity_m_s2 * n * dt, rel=1e-12)
    assert s.p_xz[1] == pytest.approx(-P.gravity_m_s2 * dt**2 * n * (n + 1) / 2, rel=1e-12)


def test_constant_torque_spins_up_as_newton_says() -> None:
    sim = PlanarQuadrotor(P, dt_ns=DT_NS)
    torque, n, dt = 0.01, 50, DT_NS * 1e-9
    for _ in range(n):
        s = sim.step(P.mass_kg * P.gravity_m_s2, torque)
    alpha = torque / P.inertia_kg_m2
    assert s.theta_rate_rad_s == pytest.approx(alpha * n * dt, rel=1e-12)
    assert s.theta_rad == pytest.approx(alpha * dt**2 * n * (n + 1) / 2, rel=1e-12)


def test_positive_pitch_accelerates_towards_plus_x() -> None:
    sim = PlanarQuadrotor(P, dt_ns=DT_NS)
    sim.state = type(sim.state)(
        t_ns=0,
        p_xz=np.zeros(2),
        v_xz=np.zeros(2),
        a_xz=np.zeros(2),
        theta_rad=0.3,
        theta_rate_rad_s=0.0,
    )
    thrust = P.mass_kg * P.gravity_m_s2 / math.cos(0.3)
    s = sim.step(thrust, 0.0)
    assert s.a_xz[0] == pytest.approx(P.gravity_m_s2 * math.tan(0.3), rel=1e-12)
    assert s.a_xz[1] == pytest.approx(0.0, abs=1e-12)


def test_vehicle_state_form_is_consistent() -> None:
    sim = PlanarQuadrotor(P, dt_ns=DT_NS)
    for _ in range(30):
        s = sim.step(12.0, 0.02)
    vs = s.to_vehicle_state()
    np.testing.assert_array_equal(vs.p_W_B[[0, 2]], s.p_xz)
    assert vs.p_W_B[1] == 0.0
    # The quaternion is a rotation about +y by theta.
    assert 2 * math.atan2(vs.q_W_B_xyzw[1], vs.q_W_B_xyzw[3]) == pytest.approx(s.theta_rad)
    assert vs.w_B[1] == s.theta_rate_rad_s


def test_bad_inputs_raise_sim_errors() -> None:
    with pytest.raises(SimError):
        PlanarParams(mass_kg=0.0)
    with pytest.raises(SimError):
        PlanarQuadrotor(P, dt_ns=0)
    sim = PlanarQuadrotor(P, dt_ns=DT_NS)
    with pytest.raises(SimError, match="non-finite"):
        sim.step(float("nan"), 0.0)
