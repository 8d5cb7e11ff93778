"""Closed-loop acceptance of the controllers (thesis 002's four simulations, the circle with
and without gusts, thesis 003's experiments)."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.control.cascaded_pid import CascadedPidGains
from quadnav.control.thesis002 import NestedSaturationController, PdController
from quadnav.errors import ControlError
from quadnav.experiments.flight import FlightConfig, builtin_config, run_flight
from quadnav.experiments.flight_study import flight_metrics


def fly(name: str, **overrides: object) -> dict[str, object]:
    data = builtin_config(name)
    data.update(overrides)
    run = run_flight(FlightConfig.model_validate(data))
    m = flight_metrics(run)
    m["_run"] = run
    return m


@pytest.mark.parametrize("name", ["thesis002_pd_stabilization", "thesis002_nested_stabilization"])
def test_thesis002_controllers_stabilise_from_the_thesis_initial_state(name: str) -> None:
    m = fly(name)
    run = m["_run"]
    np.testing.assert_allclose(run.p[-1], [0.0, 0.0, 5.0], atol=0.01)  # type: ignore[attr-defined]
    np.testing.assert_allclose(run.euler_rpy[-1], 0.0, atol=1e-3)  # type: ignore[attr-defined]
    assert m["settling_time_s"] < 15.0


def test_nested_saturations_track_the_sigmoid_better_than_pd() -> None:
    pd = fly("thesis002_pd_tracking")
    nested = fly("thesis002_nested_tracking")
    assert nested["tracking_rmse_m"] < pd["tracking_rmse_m"]  # type: ignore[operator]
    assert nested["tracking_rmse_m"] < 0.1  # type: ignore[operator]


@pytest.mark.parametrize(
    ("gusts", "frame", "limit_m"),
    [(0.0, "x", 0.05), (2.0, "x", 0.05), (0.0, "+", 0.05)],
)
def test_cascaded_pid_tracks_the_circle(gusts: float, frame: str, limit_m: float) -> None:
    m = fly(
        "circle", duration_s=20.0, frame=frame, wind={"gust_sigma_m_s": gusts, "gust_tau_s": 2.0}
    )
    assert m["tracking_rmse_m"] <= limit_m  # type: ignore[operator]
    # Motor limits respected: the rotors stay inside their range, and once the start-up
    # transient is over (the vehicle starts at rest on a moving reference) nothing saturates.
    lo, hi = m["rotor_speed_range_rad_s"]  # type: ignore[misc]
    assert lo >= 0.0 and hi <= 1100.0
    run = m["_run"]
    assert not run.saturated[run.t_s >= 2.0].any()  # type: ignore[attr-defined]


def test_obstacle_is_detected_and_the_vehicle_retreats_to_waypoint_2() -> None:
    m = fly("thesis003_obstacle")
    ev = m["events"]
    assert ev["route_unsafe"] is True  # type: ignore[index]
    assert ev["retreated_to_waypoint"] == 2  # type: ignore[index]
    assert ev["finished"] is True  # type: ignore[index]
    assert m["min_obstacle_distance_m"] >= 0.5  # type: ignore[operator]
    run = m["_run"]
    np.testing.assert_allclose(run.p[-1], [2.0, 0.0, 2.0], atol=0.2)  # type: ignore[attr-defined]


def test_takeoff_then_forward() -> None:
    m = fly("thesis003_takeoff")
    run = m["_run"]
    assert m["events"] == {"phase": "done"}
    np.testing.assert_allclose(run.p[-1], [5.0, 0.0, 5.0], atol=0.1)  # type: ignore[attr-defined]


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
