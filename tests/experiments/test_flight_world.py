"""The world a rendered flight flies in is built around the route its plan flies: no obstacle
stands within the world's clearance of it, whatever the plan."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.experiments.scenarios import nav_builtin
from quadnav.experiments.vio_flight import flight_world, planned_path

CLEARANCE_M = 1.0  # world_around's


def _closest_obstacle_m(path: np.ndarray, scene_polys: tuple) -> tuple[float, str]:
    """The least distance from the route (sampled every 5 cm) to an obstacle's face."""
    a, b = path[:-1], path[1:]
    s = np.linspace(0.0, 1.0, 401)[:, None, None]
    pts = (a + s * (b - a)).reshape(-1, 3)
    best, name = np.inf, ""
    for poly in scene_polys:
        if not poly.name.startswith("obstacle:"):
            continue
        lo, hi = poly.points_W.min(axis=0), poly.points_W.max(axis=0)
        d = np.maximum(np.maximum(lo - pts, pts - hi), 0.0)
        dist = float(np.sqrt((d**2).sum(axis=1)).min())
        if dist < best:
            best, name = dist, poly.name
    return best, name


@pytest.mark.parametrize(
    ("scenario", "overrides"),
    [
        ("outdoor_vio_gps", []),  # the yard, a 20 m square at 5 m, 3 m/s
        ("indoor_vio", []),  # the hall, take off to 5 m and 5 m ahead
        ("indoor_vio", ["plan.kind=square", "plan.square_m=6", "plan.height_m=2"]),
    ],
)
def test_no_obstacle_stands_on_the_planned_route(scenario: str, overrides: list[str]) -> None:
    sc = nav_builtin(scenario, overrides)
    path = planned_path(sc)
    # the route is the plan's: a square reaches its far corner
    if sc.plan.kind == "square":
        assert np.allclose(path.max(axis=0)[:2], sc.plan.square_m)
    scene = flight_world(sc)
    assert any(p.name.startswith("obstacle:") for p in scene.polygons)  # there are some
    dist, name = _closest_obstacle_m(path, scene.polygons)
    assert dist >= CLEARANCE_M - 1e-6, f"{name} is {dist:.2f} m from the route"
