"""Thesis 003's free flight of figure 6.22 through (0,0,3), (2,2,3), (4,5,3) with its PID
waypoint follower (section 6.5: kp_lin 0.2, kd_lin 0.01, ki_lin 0.004, kp_ang 3.4, kd_ang 0.2,
ki_ang 0.02 at 10 Hz, a waypoint reached within 0.5 m), and thesis 002's Table 5.1 gains."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadnav.control.thesis002 import PdController
from quadnav.errors import ConfigError, ControlError
from quadnav.experiments.flight import FlightConfig, FlightRun, builtin_config, run_flight
from quadnav.io.config import load_config

WAYPOINTS = np.array([(0.0, 0.0, 3.0), (2.0, 2.0, 3.0), (4.0, 5.0, 3.0)])


@pytest.fixture(scope="module")
def free_flight() -> FlightRun:
    return run_flight(FlightConfig.model_validate(builtin_config("thesis003_waypoints")))


@pytest.mark.slow  # the waypoint flight; thesis 003's obstacle retreat flies in CI
def test_every_waypoint_is_reached_within_half_a_metre_in_order(free_flight: FlightRun) -> None:
    run, ev = free_flight, free_flight.events
    assert ev.finished is True and ev.route_unsafe is False and ev.last_waypoint_reached == 3
    times = np.array(ev.waypoints_reached_at_s)
    assert len(times) == 3 and np.all(np.diff(times) > 2.0)  # one leg after the other
    for k, (wp, t_k) in enumerate(zip(WAYPOINTS, times, strict=True)):
        i = np.searchsorted(run.t_s, t_k)
        assert np.linalg.norm(run.p[i] - wp) < 0.5, k
        before = run.t_s < (times[k - 1] if k else 0.0)
        if before.any():  # not there before its turn
            assert np.linalg.norm(run.p[before] - wp, axis=1).min() > 0.5, k


@pytest.mark.slow  # the waypoint flight; thesis 003's obstacle retreat flies in CI
def test_the_legs_are_flown_as_the_thesis_flies_them(free_flight: FlightRun) -> None:
    run = free_flight
    t1, t2, t3 = run.events.waypoints_reached_at_s
    # Reached 0.5 m below the first, the height closes on 3 m during the second leg and stays.
    assert abs(run.p[np.searchsorted(run.t_s, t1), 2] - 2.5) < 0.05
    assert np.abs(run.p[run.t_s >= t2, 2] - 3.0).max() < 0.2
    # Each horizontal leg runs straight from where the last waypoint was reached to the next.
    for (t_a, t_b), wp in zip([(t1, t2), (t2, t3)], WAYPOINTS[1:], strict=True):
        leg = (run.t_s >= t_a) & (run.t_s <= t_b)
        a = run.p[np.searchsorted(run.t_s, t_a), 0:2]
        d = (wp[0:2] - a) / np.linalg.norm(wp[0:2] - a)
        rel = run.p[leg, 0:2] - a
        cross = np.abs(rel[:, 0] * d[1] - rel[:, 1] * d[0])
        assert cross.max() < 0.15
    # It faces the waypoint it flies to (the laser looks ahead): heading on the last leg.
    mid = np.searchsorted(run.t_s, 0.5 * (t2 + t3))
    bearing = math.atan2(5.0 - 2.0, 4.0 - 2.0)
    assert abs(math.remainder(run.euler_rpy[mid, 2] - bearing, math.tau)) < math.radians(10)
    # Slow, as the thesis's gains make it: velocity commands of kp 0.2 per metre.
    speed = np.linalg.norm(run.v, axis=1)
    assert 0.4 < speed.max() < 1.5
    # After the last waypoint it hovers where it is, inside the 0.5 m.
    tail = run.t_s > run.t_s[-1] - 2.0
    assert np.linalg.norm(run.p[tail] - WAYPOINTS[2], axis=1).max() < 0.5
    assert speed[tail].max() < 0.05


def fly_pd(**overrides: object) -> FlightRun:
    data = builtin_config("thesis002_pd_stabilization")
    data.update(overrides)
    return run_flight(FlightConfig.model_validate(data))


def test_table_5_1_gains_fly_the_pd_stabilisation() -> None:
    """From psi 0.5 at rest the first yaw torque is -Kp_psi psi = -90 * 0.5 (default: -4 * 0.5);
    with Kd_psi 70 the yaw rate is damped hard: psi stays monotone, no overshoot."""
    run = fly_pd(el_pd_gains="table_5_1")
    assert run.torque[0, 2] == pytest.approx(-45.0)
    np.testing.assert_allclose(run.p[-1], [0.0, 0.0, 5.0], atol=0.01)
    np.testing.assert_allclose(run.euler_rpy[-1], 0.0, atol=1e-3)
    psi = run.euler_rpy[:, 2]
    assert np.all(np.diff(psi) <= 1e-12) and psi.min() > -1e-6
    assert fly_pd(duration_s=0.1).torque[0, 2] == pytest.approx(-2.0)
    # A gain given on top of the set wins.
    over = fly_pd(el_pd_gains="table_5_1", el_pd={"kp_yaw": 50.0}, duration_s=0.1)
    assert over.torque[0, 2] == pytest.approx(-25.0)


def test_table_5_1_is_a_named_gain_set_and_others_are_refused() -> None:
    pd = PdController.from_gain_set("table_5_1")
    assert (pd.kp_att, pd.kd_att, pd.kp_yaw, pd.kd_yaw) == (120.0, 40.0, 90.0, 70.0)
    with pytest.raises(ControlError, match="table_5_1"):
        PdController.from_gain_set("table_9")
    with pytest.raises(ConfigError, match="el_pd_gains"):
        load_config(
            FlightConfig,
            None,
            ["el_pd_gains=table_9"],
            base=builtin_config("thesis002_pd_stabilization"),
        )
