"""The optical-flow scenario: no position source, the horizontal position dead-reckoned from
flow over the range finder's height."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.errors import QuadnavError
from quadnav.experiments.nav import run_nav
from quadnav.experiments.nav_study import nav_metrics
from quadnav.experiments.scenarios import NAV_SCENARIOS, nav_builtin

SHORT = ("plan.square_m=1.5", "plan.hold_s=2")


@pytest.fixture(scope="module")
def flights() -> list:
    sc = nav_builtin("indoor_flow", SHORT)
    return [run_nav(sc, seed) for seed in (0, 1)]


def test_indoor_flow_dead_reckons_the_square_within_centimetres(flights: list) -> None:
    for r in flights:
        m = nav_metrics(r)
        err = np.linalg.norm(r.output_p - r.truth_p, axis=1)
        horiz_v = np.linalg.norm(r.output_v[:, :2] - r.truth_v[:, :2], axis=1)
        assert isinstance(m.output_rmse_m, float) and m.output_rmse_m < 0.10
        assert err[-1] < 0.25  # the drift over the whole flight, landed
        assert float(np.sqrt(np.mean(horiz_v**2))) < 0.10  # flow observes the velocity
        assert (
            isinstance(m.hold_max_horizontal_error_m, float) and m.hold_max_horizontal_error_m < 0.2
        )
        # the square's four 1.5 m sides (and the small corrections on the ground) were flown
        assert 6.0 <= m.distance_flown_m <= 6.6
        assert isinstance(m.drift_percent, float) and m.drift_percent < 4.0
        assert m.drift_percent == pytest.approx(100 * m.end_horizontal_error_m / m.distance_flown_m)
        flow = r.sources["flow"]
        assert flow.fused > 0.95 * flow.received > 400
        assert "vision" not in r.sources and "gps" not in r.sources


def test_without_flow_the_same_flight_is_refused() -> None:
    assert "indoor_flow" in NAV_SCENARIOS
    with pytest.raises(QuadnavError, match="flow"):
        nav_builtin("indoor_flow", ["flow.enabled=false"])
