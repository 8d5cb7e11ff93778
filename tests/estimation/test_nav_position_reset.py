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
