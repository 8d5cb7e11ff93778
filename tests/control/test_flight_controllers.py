"""Closed-loop acceptance of the controllers (thesis 002's four simulations, the circle with
and without gusts, thesis 003's experiments)."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.control.cascaded_pid import CascadedPidGains
from quadnav.control.thesis002 import NestedSaturationController, PdController
from quadnav.errors import ControlError
from quadnav.experiments.flight import FlightConfig, FlightRun, builtin_config, run_flight
from quadnav.experiments.flight_study import FlightMetrics, TrackingMetrics, flight_metrics


def fly(name: str, **overrides: object) -> tuple[FlightRun, FlightMetrics]:
    data = builtin_config(name)
    data.update(overrides)
    run = run_flight(FlightConfig.model_validate(data))
    return run, flight_metrics(run)


def tracking(m: FlightMetrics) -> TrackingMetrics:
    assert m.tracking is not None
    return m.tracking


@pytest.mark.parametrize("name", ["thesis002_pd_stabilization", "thesis002_nested_stabilization"])
def test_thesis002_controllers_stabilise_from_the_thesis_initial_state(name: str) -> None:
    run, m = fly(name)
    np.testing.assert_allclose(run.p[-1], [0.0, 0.0, 5.0], atol=0.01)
    np.testing.assert_allclose(run.euler_rpy[-1], 0.0, atol=1e-3)
    settle = tracking(m).settling_time_s
    assert isinstance(settle, float) and settle < 15.0


def test_nested_saturations_track_the_sigmoid_better_than_pd() -> None:
    pd = tracking(fly("thesis002_pd_tracking")[1]).tracking_rmse_m
    nested = tracking(fly("thesis002_nested_tracking")[1]).tracking_rmse_m
    assert isinstance(pd, float) and isinstance(nested, float)
    assert nested < pd
    assert nested < 0.1


@pytest.mark.parametrize(
    ("gusts", "frame", "limit_m"),
    [  # (the calm ones run with the long tests; the gusts' in CI)
        pytest.param(0.0, "x", 0.05, marks=pytest.mark.slow),
        (2.0, "x", 0.05),
        pytest.param(0.0, "+", 0.05, marks=pytest.mark.slow),
    ],
)
def test_cascaded_pid_tracks_the_circle(gusts: float, frame: str, limit_m: float) -> None:
    run, m = fly(
        "circle", duration_s=20.0, frame=frame, wind={"gust_sigma_m_s": gusts, "gust_tau_s": 2.0}
    )
    rmse = tracking(m).tracking_rmse_m
    assert isinstance(rmse, float) and rmse <= limit_m
    # Motor limits respected: the rotors stay inside their range, and once the start-up
    # transient is over (the vehicle starts at rest on a moving reference) nothing saturates.
    assert m.rotor_speed_range_rad_s is not None
    lo, hi = m.rotor_speed_range_rad_s
    assert lo >= 0.0 and hi <= 1100.0
    assert not run.saturated[run.t_s >= 2.0].any()


def test_obstacle_is_detected_and_the_vehicle_retreats_to_waypoint_2() -> None:
    """Thesis 003 figures 6.23-6.24: the house in the way of (0,0,2), (2,0,2), (6,0,2) is seen
    and the vehicle goes back to waypoint 2 (the thesis: "vuelve al waypoint número dos")."""
    run, m = fly("thesis003_obstacle")
    ev = run.events
    assert ev.route_unsafe is True
    assert ev.retreated_to_waypoint == 2
    assert ev.last_waypoint_reached == 2
    assert ev.finished is True
    # Seen on the third leg, before the vehicle gets within 1 m of the house's face (x 3.5).
    t_seen = ev.obstacle_detected_at_s
    assert t_seen is not None and ev.waypoints_reached_at_s[1] < t_seen
    x_seen = run.p[np.searchsorted(run.t_s, t_seen), 0]
    assert 2.4 < x_seen < 2.6
    assert m.min_obstacle_distance_m is not None and m.min_obstacle_distance_m >= 0.5
    np.testing.assert_allclose(run.p[-1], [2.0, 0.0, 2.0], atol=0.05)


def test_takeoff_then_forward_stops_within_the_thesis_tolerance() -> None:
    """Thesis 003 section 6.3: climb with vz = 0.2 (z_ref - z) until within 0.8 m, then x the
    same way; the node then ends and the vehicle hovers where it is."""
    run, _ = fly("thesis003_takeoff")
    assert run.events.takeoff_phase == "done"
    x, y, z = run.p[-1]
    assert 5.0 - 0.8 - 0.05 < x < 5.0 - 0.75  # stopped at the 0.8 m tolerance, not at the target
    assert abs(y) < 0.01 and 4.2 < z < 5.0
    # The P law: at 0.2 1/s the climb from 0 to 4.2 m takes about 5 ln(5 / 0.8) = 9.2 s.
    t_climb = run.t_s[np.argmax(run.p[:, 2] > 4.2)]
    assert 8.5 < t_climb < 11.0
    # Hovering at the end: the last two seconds move less than 2 cm.
    tail = run.p[run.t_s > run.t_s[-1] - 2.0]
    assert np.ptp(tail, axis=0).max() < 0.02


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: PdController(kd_xy=2.0), "x-pitch"),  # too much derivative in the outer loop
        (lambda: PdController(kp_z=-1.0), "altitude"),
        (lambda: NestedSaturationController(levels_rad_s2=(1.0, 0.6, 0.2, 0.05)), "Teel"),
        (lambda: CascadedPidGains(kp_vel=(0.0, 1.0, 1.0)), "kp_vel"),
    ],
)
def test_unstable_or_invalid_gains_are_refused(make, message: str) -> None:
    with pytest.raises(ControlError, match=message):
        make()


def test_scenario_validation() -> None:
    with pytest.raises(ValueError, match="euler_lagrange"):
        FlightConfig.model_validate({"vehicle": "rigid_body", "controller": "pd"})
