from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import SimError
from quadnav.geometry import cross3, rotation_matrix_xyzw
from quadnav.sim.rigid_body import RigidBodyQuadrotor, Wind
from quadnav.vehicle import Mixer, RigidBodyParams

P = RigidBodyParams()


def test_rotation_helpers_match_scipy() -> None:
    rng = np.random.default_rng(0)
    for q in Rotation.random(20, random_state=1).as_quat():
        np.testing.assert_allclose(
            rotation_matrix_xyzw(q), Rotation.from_quat(q).as_matrix(), atol=1e-14
        )
    a, b = rng.normal(size=3), rng.normal(size=3)
    np.testing.assert_allclose(cross3(a, b), np.cross(a, b), atol=1e-15)


def test_free_rotation_conserves_energy_and_angular_momentum() -> None:
    """No rotors, no drag torque: Euler's equations conserve 1/2 w.I.w and |I w|."""
    params = RigidBodyParams(inertia_kg_m2=(0.02, 0.03, 0.05))
    sim = RigidBodyQuadrotor(params, p0=(0.0, 0.0, 1000.0))
    sim.s[10:13] = [3.0, 0.1, 1.0]  # near the unstable middle axis: a demanding motion
    inertia = np.array(params.inertia_kg_m2)
    e0 = sim.energy_rot_j()
    L0 = np.linalg.norm(Rotation.from_quat(sim.s[6:10]).apply(inertia * sim.s[10:13]))
    for _ in range(5000):
        sim.step(np.zeros(4))
    L1 = np.linalg.norm(Rotation.from_quat(sim.s[6:10]).apply(inertia * sim.s[10:13]))
    # RK4 at 1 kHz: the drift after 5 s is at the level of the integrator's truncation error.
    assert sim.energy_rot_j() == pytest.approx(e0, rel=1e-8)
    assert pytest.approx(L0, rel=1e-6) == L1


def test_hover_thrust_equals_weight() -> None:
    assert 4 * P.k_thrust_n_s2 * P.hover_omega_rad_s**2 == pytest.approx(P.mass_kg * P.gravity_m_s2)
    sim = RigidBodyQuadrotor(P, p0=(0.0, 0.0, 2.0), hovering=True)
    cmd = np.full(4, P.hover_omega_rad_s)
    for _ in range(2000):
        s = sim.step(cmd)
    np.testing.assert_allclose(s[0:3], [0.0, 0.0, 2.0], atol=1e-9)
    np.testing.assert_allclose(s[3:6], 0.0, atol=1e-9)
    # The mixer asks for the same rotor speeds for a hover thrust and no torque.
    np.testing.assert_allclose(Mixer(P)(P.mass_kg * P.gravity_m_s2, np.zeros(3)), cmd, rtol=1e-12)


def test_a_step_in_one_rotor_turns_the_body_the_expected_way() -> None:
    """Rotor 1 is front-left (x > 0, y > 0) and turns counter-clockwise. More thrust on it lifts
    the left side (roll rate +) and the nose (pitch rate -, FLU), and its larger drag torque
    yaws the body clockwise (yaw rate -)."""
    sim = RigidBodyQuadrotor(P, p0=(0.0, 0.0, 5.0), hovering=True)
    cmd = np.full(4, P.hover_omega_rad_s)
    cmd[0] *= 1.05
    for _ in range(100):
        s = sim.step(cmd)
    wx, wy, wz = s[10:13]
    assert wx > 0 and wy < 0 and wz < 0


def test_rotor_limits_and_no_negative_thrust() -> None:
    mix = Mixer(P)
    omega = mix(0.5, np.array([5.0, -5.0, 1.0]))  # torques far beyond what 0.5 N allows
    assert np.all(omega >= P.omega_min_rad_s) and np.all(omega <= P.omega_max_rad_s)
    sim = RigidBodyQuadrotor(P, p0=(0.0, 0.0, 5.0))
    for _ in range(500):
        s = sim.step(np.array([5000.0, -10.0, 5000.0, 5000.0]))
    assert np.all(s[13:17] <= P.omega_max_rad_s) and np.all(s[13:17] >= P.omega_min_rad_s)


def test_ground_plane_take_off_and_landing() -> None:
    sim = RigidBodyQuadrotor(P)
    for _ in range(1000):
        s = sim.step(np.zeros(4))
    assert s[2] == 0.0 and np.all(s[3:6] == 0.0)
    for _ in range(1000):
        s = sim.step(np.full(4, 1.15 * P.hover_omega_rad_s))
    assert s[2] > 0.3  # took off
    heights = []
    for _ in range(20_000):
        s = sim.step(np.full(4, 0.9 * P.hover_omega_rad_s))
        heights.append(s[2])
    assert min(heights) == 0.0 and s[2] == 0.0 and s[5] == 0.0  # landed and stays, never below


def test_on_the_ground_nothing_turns_that_the_gyro_does_not_see() -> None:
    """Rotors spinning down unevenly on the ground (a torque, no lift): the body stands still,
    its attitude kept while its rates read zero. Each step zeroed the rates but kept the turn
    the step had integrated: after a touchdown the vehicle tilted 4 degrees in 1.5 s that no
    gyro saw, and the landed estimate ran off (``outdoor_vio_gps_realistic``, 2026-12-05)."""
    sim = RigidBodyQuadrotor(P)
    cmd = np.full(4, 0.5 * P.hover_omega_rad_s)
    cmd[0] *= 1.6  # one rotor faster: a torque about a horizontal axis and about z
    q0 = sim.step(cmd)[6:10].copy()
    for _ in range(2000):
        s = sim.step(cmd)
        assert s[2] == 0.0 and np.all(s[10:13] == 0.0)
    assert np.allclose(s[6:10], q0, atol=1e-12)


def test_gusts_have_the_configured_spread() -> None:
    wind = Wind(
        mean_m_s=(1.0, 0.0, 0.0), gust_sigma_m_s=2.0, gust_tau_s=0.5, rng=np.random.default_rng(3)
    )
    samples = np.array([wind.step(0.01) for _ in range(100_000)])
    np.testing.assert_allclose(samples.mean(axis=0), [1.0, 0.0, 0.0], atol=0.15)
    np.testing.assert_allclose(samples.std(axis=0), 2.0, rtol=0.1)


def test_bad_parameters() -> None:
    with pytest.raises(SimError, match="cannot lift"):
        RigidBodyParams(omega_max_rad_s=300.0)
    with pytest.raises(SimError):
        RigidBodyParams(mass_kg=-1.0)
    with pytest.raises(SimError, match="4 finite"):
        RigidBodyQuadrotor(P).step(np.array([1.0, np.nan, 0.0, 0.0]))


def test_plus_frame_front_rotor_pitches_without_rolling() -> None:
    plus = RigidBodyParams(config="+")
    sim = RigidBodyQuadrotor(plus, p0=(0.0, 0.0, 5.0), hovering=True)
    cmd = np.full(4, plus.hover_omega_rad_s)
    cmd[0] *= 1.05  # the front rotor
    for _ in range(100):
        s = sim.step(cmd)
    # Only the gyroscopic coupling of the pitch and yaw rates leaks into roll.
    assert s[11] < 0.0 and abs(s[10]) < 0.01 * abs(s[11])
