from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from quadnav.control.stability import routh_hurwitz_stable
from quadnav.control.trajectories import Circle, Sigmoid, Waypoints


@given(st.lists(st.floats(-10, 10), min_size=1, max_size=5))
@settings(max_examples=300)
def test_routh_hurwitz_agrees_with_the_roots(tail: list[float]) -> None:
    coeffs = [1.0, *tail]
    roots = np.roots(coeffs)
    margin = np.max(np.abs(roots.real)) if len(roots) else 1.0
    if len(roots) and np.min(np.abs(roots.real)) < 1e-6 * max(1.0, margin):
        return  # on the imaginary axis up to round-off: either answer is defensible
    assert routh_hurwitz_stable(coeffs) == bool(np.all(roots.real < 0))


@pytest.mark.parametrize(
    "traj", [Sigmoid(), Circle(), Waypoints(points_m=[(0, 0, 1), (2, 0, 1), (2, 3, 2)])]
)
def test_derivatives_are_consistent(traj) -> None:
    t = np.linspace(0.5, 18.0, 3501)
    h = t[1] - t[0]
    r = traj.reference(t)
    v_num = np.gradient(r.p, h, axis=0)
    inner = slice(3, -3)
    # central differences across an acceleration jump are off by a/2 * h: 2e-3 covers it
    np.testing.assert_allclose(v_num[inner], r.v[inner], atol=2e-3)
    a_num = np.gradient(r.v, h, axis=0)
    if isinstance(traj, Waypoints):  # piecewise-constant acceleration: compare away from its jumps
        ok = np.all(np.isclose(a_num, r.a, atol=1e-6), axis=1)
        assert ok.mean() > 0.99
    else:
        np.testing.assert_allclose(a_num[inner], r.a[inner], atol=1e-3)


def test_circle_speed_and_waypoints_visit_every_point() -> None:
    c = Circle(radius_m=2.0, speed_m_s=1.0).reference(np.linspace(0, 10, 101))
    np.testing.assert_allclose(np.linalg.norm(c.v, axis=1), 1.0)
    # 2 m at 0.5 m/s with 1 m/s^2: 0.5 s to speed up, 3.5 s cruising, 0.5 s to stop.
    w = Waypoints(points_m=[(0, 0, 1), (2, 0, 1)], speed_m_s=0.5, accel_m_s2=1.0, hold_s=1.0)
    r = w.reference(np.array([0.5, 1.25, 3.0, 5.5, 6.0, 100.0]))
    np.testing.assert_allclose(
        r.p[:, 0], [0.0, 0.03125, 0.875, 2.0, 2.0, 2.0]
    )  # 0.125 + 1.5 s x 0.5
    np.testing.assert_allclose(r.v[:, 0], [0.0, 0.25, 0.5, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(r.a[:, 0], [0.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    assert w.duration_s == pytest.approx(1.0 + 4.5 + 1.0)
