"""The random-walk fusion reference: on an odometry whose error is a random walk, the best rate is
the walk's, and the fused error is the steady-state Kalman filter's of the closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadnav.errors import EvalError
from quadnav.eval.fusion_reference import random_walk_fusion_reference

ODO_HZ, FIX_HZ, SIGMA = 20.0, 2.0, (1.5, 1.5, 2.5)


def _walk(q: float, seconds: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    t_ns = np.arange(0, round(seconds * 1e9), round(1e9 / ODO_HZ), dtype=np.int64)
    steps = np.random.default_rng(seed).normal(0.0, math.sqrt(q / ODO_HZ), (len(t_ns), 3))
    steps[0] = 0.0
    return t_ns, np.cumsum(steps, axis=0)


def _steady_rmse(q: float) -> float:
    """A random walk of rate q seen every T with noise R: the filter's variance after a fix
    solves P^2 + a P - a R = 0 (a = q T); between fixes it grows by q a step, so the states'
    mean is P + q (T - dt) / 2. Summed over the three axes."""
    T, dt = 1.0 / FIX_HZ, 1.0 / ODO_HZ
    a = q * T
    total = 0.0
    for s in SIGMA:
        R = s * s
        total += (-a + math.sqrt(a * a + 4 * a * R)) / 2 + q * (T - dt) / 2
    return math.sqrt(total)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_on_a_random_walk_the_reference_is_the_kalman_filters_at_the_walks_rate(seed: int) -> None:
    q = 0.01  # m^2/s a axis: a VIO that drifts about 0.8 m a minute
    t, err = _walk(q, 900.0, seed)
    b = random_walk_fusion_reference(t, err, SIGMA, FIX_HZ, seed=seed)
    assert b.rate_m2_s == pytest.approx(q, rel=1.0)  # (the grid's half-decades: 0.01 itself)
    assert b.rmse_m == pytest.approx(_steady_rmse(q), rel=0.1)
    assert b.rmse_m < 0.5 * b.alone_m  # (over 15 minutes the walk wanders metres)


def test_the_reference_is_never_worse_than_the_odometry_alone() -> None:
    """An odometry that hardly drifts (1 cm in a minute): the fixes (1.5 m) can only add their
    noise, and the best rate is the one that takes nearly nothing from them."""
    t, err = _walk(1e-6, 60.0, 3)
    b = random_walk_fusion_reference(t, err, SIGMA, FIX_HZ)
    assert b.rmse_m <= b.alone_m
    assert b.rate_m2_s <= 1e-5


def test_an_outage_leaves_the_odometry_alone_and_the_reference_rises() -> None:
    t, err = _walk(0.01, 300.0, 4)
    full = random_walk_fusion_reference(t, err, SIGMA, FIX_HZ)
    cut = random_walk_fusion_reference(t, err, SIGMA, FIX_HZ, outages_s=[(60.0, 240.0)])
    assert cut.rmse_m > 1.2 * full.rmse_m
    assert cut.alone_m == full.alone_m


@pytest.mark.parametrize(
    ("times", "errors", "sigma", "rate", "match"),
    [
        (np.arange(3), np.zeros((3, 2)), SIGMA, 2.0, "must be \\(N, 3\\)"),
        (np.array([0, 2, 1]), np.zeros((3, 3)), SIGMA, 2.0, "must increase"),
        (np.arange(3.0), np.zeros((3, 3)), SIGMA, 2.0, "integer ns"),
        (np.arange(3), np.full((3, 3), np.nan), SIGMA, 2.0, "finite"),
        (np.arange(3), np.zeros((3, 3)), (1.0, 0.0, 1.0), 2.0, "3 positive numbers"),
        (np.arange(3), np.zeros((3, 3)), SIGMA, math.inf, "must be > 0 Hz"),
    ],
)
def test_bad_input_is_a_one_line_error(times, errors, sigma, rate, match) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(EvalError, match=match):
        random_walk_fusion_reference(times, errors, sigma, rate)
