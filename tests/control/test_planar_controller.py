from __future__ import annotations

import math

import numpy as np
import pytest

from quadnav.control import PlanarSetpointProfile, ThesisPlanarController, truth_estimate
from quadnav.errors import ControlError
from quadnav.sim import PlanarParams, PlanarQuadrotor


def test_profile_is_the_thesis_profile_in_our_sign() -> None:
    prof = PlanarSetpointProfile()
    assert prof.reference(0.0) == (2.0, 0.0)
    assert prof.reference(2.6) == (0.0, 0.0)
    assert prof.reference(7.5) == (0.0, -math.pi / 6)
    assert prof.reference(9.0) == (0.0, math.pi / 6)


def test_closed_loop_climbs_then_heads_to_minus_x() -> None:
    """The thesis's vehicle climbs ~5 m (2 m/s for 2.5 s) and then moves towards -x."""
    P = PlanarParams()
    sim = PlanarQuadrotor(P, dt_ns=10_000_000)
    ctrl = ThesisPlanarController()
    truth = sim.state.to_vehicle_state()
    heights, xs = [], []
    for i in range(1, 1001):
        cmd = ctrl(i * 10_000_000, truth_estimate(truth), ctrl.setpoint(i * 10_000_000))
        s = sim.step(cmd.thrust_n, float(cmd.torque()[1]))
        truth = s.to_vehicle_state()
        heights.append(s.p_xz[1])
        xs.append(s.p_xz[0])
    assert 4.5 < heights[699] < 5.5  # before the tilt
    assert abs(xs[690]) < 1e-12  # no horizontal motion before the tilt starts at 7 s
    assert xs[-1] < -5.0
    # The climb-rate loop holds height within a few cm while tilted (thrust / cos(theta)).
    assert np.ptp(heights[700:]) < 0.3


@pytest.mark.parametrize("gains", [{"k_tilt": 0.0}, {"kd_tilt": -0.1}, {"k_climb": 0.0}])
def test_unstable_gains_are_refused(gains: dict[str, float]) -> None:
    with pytest.raises(ControlError):
        ThesisPlanarController(**gains)


def test_bad_profile_is_refused() -> None:
    with pytest.raises(ControlError):
        PlanarSetpointProfile(tilt_start_s=5.0, tilt_switch_s=4.0)
    with pytest.raises(ControlError):
        PlanarSetpointProfile(tilt_rad=math.pi / 2)
