from __future__ import annotations

import math

import numpy as np
import pytest

from quadnav.errors import SimError
from quadnav.sim.world import Box, LaserScanner, World

HOUSE = World(boxes=(Box(min_m=(3.5, -2.0, 0.0), max_m=(5.5, 2.0, 3.0), name="house"),))


def test_ranges_to_a_wall_follow_the_geometry() -> None:
    scan = LaserScanner(noise_sigma_m=0.0).scan(
        HOUSE, np.array([2.0, 0.0, 2.0]), 0.0, 0, np.random.default_rng(0)
    )
    a = scan.angles_rad
    hit = np.isfinite(scan.ranges_m)
    # Rays that reach the wall x = 3.5 through its face travel 1.5 / cos(angle).
    face = hit & (np.abs(a) < math.atan2(2.0, 1.5))
    np.testing.assert_allclose(scan.ranges_m[face], 1.5 / np.cos(a[face]), atol=1e-9)
    assert not hit[np.abs(a) > math.pi / 2].any()  # nothing behind


def test_yaw_turns_the_scan_and_height_matters() -> None:
    rng = np.random.default_rng(0)
    s = LaserScanner(noise_sigma_m=0.0)
    facing_away = s.scan(HOUSE, np.array([2.0, 0.0, 2.0]), math.pi, 0, rng)
    i = int(np.argmin(np.abs(np.angle(np.exp(1j * (facing_away.angles_rad - math.pi))))))
    assert facing_away.ranges_m[i] == pytest.approx(1.5)  # the house is now behind the body
    above = s.scan(HOUSE, np.array([2.0, 0.0, 3.5]), 0.0, 0, rng)
    assert np.all(np.isinf(above.ranges_m))


def test_distance_to_obstacles() -> None:
    d = HOUSE.min_distance_m(np.array([[2.0, 0.0, 2.0], [4.0, 0.0, 1.0], [5.5, 3.0, 3.0]]))
    np.testing.assert_allclose(d, [1.5, 0.0, 1.0])
    with pytest.raises(SimError):
        Box(min_m=(1, 0, 0), max_m=(0, 1, 1))
