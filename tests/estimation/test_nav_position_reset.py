"""A position-only source refused for too long resets the position and widens the velocity's
uncertainty, so that the velocity error that made the position run away gets corrected."""

from __future__ import annotations

import numpy as np

from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.messages import ImuSample, PositionSample

DT_S = 0.01
V_TRUE = np.array([2.0, 0.0, 0.0])


def _run(seconds: float) -> tuple[NavEkf, list[bool]]:
    """The filter starts still and sure of it (velocity sigma 1 mm/s) while the body moves
    east at 2 m/s; fixes of the true position come once a second."""
    P0 = np.diag([1e-4] * 3 + [1e-6] * 3 + [1e-2] * 3 + [1e-8] * 3 + [1e-6] * 3)
    ekf = NavEkf(NavEkfConfig(), p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=[0, 0, 0, 1.0], P0=P0)
    g = ekf.config.gravity_m_s2
    accepted = []
    for k in range(1, round(seconds / DT_S) + 1):
        t_ns = round(k * DT_S * 1e9)
        ekf.predict(ImuSample(t_ns=t_ns, gyro_rad_s=np.zeros(3), accel_m_s2=[0, 0, g]), DT_S)
        if k % 100 == 0:
            fix = PositionSample(t_ns=t_ns, p_W_B=V_TRUE * k * DT_S, sigma_m=0.3)
            accepted.append(ekf.fuse(fix).accepted)
    return ekf, accepted


def test_the_velocity_is_corrected_after_a_position_reset() -> None:
    ekf, accepted = _run(20.0)
    resets = [msg for _, msg in ekf.events if "position reset to it" in msg]
    assert resets and "velocity sigma widened" in resets[0]
    # after the reset the fixes are taken again, and the velocity is found
    assert all(accepted[-10:])
    assert np.linalg.norm(ekf.v - V_TRUE) < 0.2
    assert len(resets) <= 2


def test_a_widened_velocity_is_as_uncertain_as_the_drift_implied() -> None:
    ekf, _ = _run(3.0)  # fixes refused at 1 and 2 s (the filter sure it is still), reset at 3 s
    assert any("velocity sigma widened" in msg for _, msg in ekf.events)
    sigma_vx = float(np.sqrt(ekf.P[3, 3]))
    # 6 m of innovation after 2 s refused: about 2 to 3 m/s per second of refusal
    assert 1.5 < sigma_vx < 4.0


def _landed_after(
    v0: np.ndarray, p_sigma_m: float = 0.3, force_g: float = 1.0
) -> tuple[NavEkf, list[bool]]:
    """A filter sure of its velocity ``v0`` (1 cm/s) with its position and velocity
    correlated as after a flight (2 s of prediction), then 1 s of zero-velocity updates
    ("landed", 25 Hz, 2 cm/s) while the IMU reads ``force_g`` (1: a body at rest; 0: falling)
    for the last second."""
    from quadnav.messages import VelocitySample

    P0 = np.diag([p_sigma_m**2] * 3 + [1e-4] * 3 + [1e-4] * 3 + [1e-8] * 3 + [1e-6] * 3)
    ekf = NavEkf(NavEkfConfig(), p0=np.zeros(3), v0=v0, q0_xyzw=[0, 0, 0, 1.0], P0=P0)
    g = ekf.config.gravity_m_s2
    accepted = []
    for k in range(1, 301):
        t_ns = round(k * DT_S * 1e9)
        f = g if k <= 200 else force_g * g
        ekf.predict(ImuSample(t_ns=t_ns, gyro_rad_s=np.zeros(3), accel_m_s2=[0, 0, f]), DT_S)
        if k > 200 and k % 4 == 0:
            zvu = VelocitySample(t_ns=t_ns, v_W_B=np.zeros(3), sigma_m_s=0.02)
            accepted.append(ekf.fuse(zvu).accepted)
    return ekf, accepted


def test_a_velocity_far_off_at_touchdown_is_reset_by_the_zero_velocity_update() -> None:
    """A hard touchdown leaves the velocity 2 m/s off while the filter is sure of it. Refused
    by the gate (as every update was until 2026-12-05), the velocity stayed off and the
    landed estimate ran away; fused past the gate, it dragged the position metres through
    their correlation. Reset: the velocity is zero, the position stays where the prediction
    had it, and the next updates are fused."""
    v0 = np.array([2.0, -1.0, 0.5])
    ekf, accepted = _landed_after(v0)
    resets = [msg for _, msg in ekf.events if msg.startswith("landed: velocity")]
    assert len(resets) == 1 and "2.29 m/s off" in resets[0]
    assert all(accepted)  # (the first taken as a reset)
    assert np.linalg.norm(ekf.v) < 0.02
    # where 2.04 s at v0 put it (the reset comes at the first update, at 2.04 s)
    assert np.allclose(ekf.p, v0 * 2.04, atol=0.02)
    # a velocity a little off is fused as any measurement: no reset
    ekf, accepted = _landed_after(np.array([0.01, 0.0, 0.0]))
    assert all(accepted) and not any("landed" in m for _, m in ekf.events)
    # a body the accelerometer says is falling (motors cut above the ground) is not reset
    ekf, accepted = _landed_after(v0, force_g=0.0)
    assert not all(accepted) and not any("landed" in m for _, m in ekf.events)
