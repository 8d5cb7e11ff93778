"""The window's smoother on a badly conditioned chain: GTSAM's Cholesky refuses it (since 4.3 a
frontal block whose equilibrated reciprocal condition number is under sqrt(eps) is
"indeterminate"), the solve is redone with QR from the last good solve, and Cholesky is tried
again after ``qr_fallback_solves`` solves."""

from __future__ import annotations

from collections.abc import Callable

import gtsam
import numpy as np
import pytest

from quadnav.vio.config import VioConfig
from quadnav.vio.graph import GTSAM_ERRORS, WindowGraph

STEP = np.array([0.1, -0.05, 0.02])
START = np.array([1.0, 2.0, 3.0])


def _chain(graph: WindowGraph, first: int, last: int, sigma: float) -> None:
    """Variables ``first..last`` (3-vectors, stamped with their number) joined by exact steps
    of ``STEP`` with ``sigma``; the first of all also gets a weak prior (sigma 100) at
    ``START``. Starting values off by 0.3 so the solve has work to do."""
    for k in range(first, last + 1):
        graph.insert(k, START + k * STEP + 0.3, float(k))
        if k == 0:
            graph.add(gtsam.PriorFactorVector(0, START, gtsam.noiseModel.Isotropic.Sigma(3, 100)))
        else:
            noise = gtsam.noiseModel.Isotropic.Sigma(3, sigma)
            graph.add(gtsam.BetweenFactorVector(k - 1, k, STEP, noise))


def _check(graph: WindowGraph, last: int) -> None:
    sol = graph.solve(covariance_of=(last,))
    x = {k: sol.estimate.atVector(k) for k in range(max(0, last - 3), last + 1)}
    for k in list(x)[1:]:  # the stiff steps are exact
        np.testing.assert_allclose(x[k] - x[k - 1], STEP, atol=1e-6)
    for k in x:  # the chain is START + k STEP (the weak prior: LM may stop a little short)
        np.testing.assert_allclose(x[k], START + k * STEP, atol=0.01)
    # the weak prior's 100 carries to the newest (the stiff steps add next to nothing)
    assert 99.0 < float(np.sqrt(sol.covariances[last][0, 0])) < 101.0


@pytest.mark.parametrize("smoother", ["isam2", "batch"])
def test_cholesky_refuses_a_stiff_chain_and_qr_solves_it(smoother: str) -> None:
    """Steps 1e8 times stiffer (in information) than the prior: Cholesky throws, the fallback
    solves it; then each solve adds a variable, stays on QR for 3 solves, goes back to
    Cholesky (which throws again on this chain) and falls back again, for 6 solves."""
    cfg = VioConfig(smoother=smoother, qr_fallback_solves=3)
    graph = WindowGraph(cfg, lag=6.0)
    _chain(graph, 0, 5, sigma=0.01)
    _check(graph, 5)
    assert graph.fallbacks == 1 and graph.on_qr
    for k in range(6, 9):  # three solves on QR
        _chain(graph, k, k, sigma=0.01)
        _check(graph, k)
        assert graph.fallbacks == 1
    assert graph.on_qr
    _chain(graph, 9, 9, sigma=0.01)  # Cholesky again: refused, QR again, twice as long
    _check(graph, 9)
    assert graph.fallbacks == 2 and graph.on_qr
    for k in range(10, 16):  # six solves on QR
        _chain(graph, k, k, sigma=0.01)
        _check(graph, k)
    assert graph.fallbacks == 2
    _chain(graph, 16, 16, sigma=0.01)
    _check(graph, 16)
    assert graph.fallbacks == 3


def test_without_the_fallback_the_stiff_chain_fails() -> None:
    graph = WindowGraph(VioConfig(qr_fallback_solves=0), lag=6.0)
    _chain(graph, 0, 5, sigma=0.01)
    with pytest.raises(GTSAM_ERRORS, match="Indeterminate"):
        graph.solve()


def test_a_well_conditioned_chain_stays_on_cholesky() -> None:
    """Steps of sigma 1 (1e4 times the prior's information): no fallback, back on Cholesky
    after a fallback's solves."""
    graph = WindowGraph(VioConfig(qr_fallback_solves=2), lag=6.0)
    _chain(graph, 0, 5, sigma=1.0)
    for k in range(6, 12):
        _chain(graph, k, k, sigma=1.0)
        graph.solve()
    assert graph.fallbacks == 0 and not graph.on_qr
    # a stiff step now: QR for two solves, then Cholesky takes the mild chain again
    _chain(graph, 12, 12, sigma=1e-4)
    graph.solve()
    assert graph.fallbacks == 1 and graph.on_qr
    for k in range(13, 16):
        _chain(graph, k, k, sigma=1.0)
        graph.solve()
    assert graph.fallbacks == 1 and not graph.on_qr


@pytest.mark.parametrize("stiff", [False, True])
def test_the_marginal_covariances_of_several_keys_are_each_keys_own(stiff: bool) -> None:
    """Several keys' covariances at once (iSAM2's joint marginal on Cholesky, one key at a time
    on QR) are each key's own marginal: as the whole graph's QR elimination gives them, and each
    under its own key (the chain's newest is the least certain, its oldest the most)."""
    graph = WindowGraph(VioConfig(qr_fallback_solves=3), lag=20.0)
    _chain(graph, 0, 5, sigma=0.01 if stiff else 1.0)
    graph.solve()
    for k in range(6, 9):
        _chain(graph, k, k, sigma=1.0)
        keys = (k, k - 2, 1)
        sol = graph.solve(covariance_of=keys)
        assert graph.on_qr == stiff
        # the whole window (nothing left the lag yet), linearised and eliminated by QR
        lin = graph._smoother.getFactors().linearize(sol.estimate)
        for key in keys:
            want = np.linalg.inv(lin.marginal([key], gtsam.EliminateQR).hessian()[0])
            np.testing.assert_allclose(sol.covariances[key], want, rtol=1e-6, atol=1e-9)
        variances = [float(sol.covariances[key][0, 0]) for key in keys]
        assert variances == sorted(variances, reverse=True)


def test_removing_the_factors_on_some_keys_finds_those_a_full_look_finds() -> None:
    """remove_where(touching=...) looks only at the factors on the given keys (by GTSAM's
    variable index) and drops the same ones as a look at every factor; a key the smoother does
    not hold is no error."""

    def chain() -> WindowGraph:  # each variable with a prior too: it stays determinate
        g = WindowGraph(VioConfig(), lag=20.0)
        _chain(g, 0, 7, sigma=1.0)
        for k in range(8):
            prior = gtsam.noiseModel.Isotropic.Sigma(3, 10.0)
            g.add(gtsam.PriorFactorVector(k, START + k * STEP, prior))
        g.solve()
        return g

    def steps_on(keys: set[int]) -> Callable[[gtsam.NonlinearFactor], bool]:
        return lambda f: (
            not (isinstance(f, gtsam.BetweenFactorVector) and bool(keys & set(f.keys())))
        )

    graph, full = chain(), chain()
    assert full.remove_where(steps_on({3, 6})) == 4  # 2-3, 3-4, 5-6, 6-7
    assert graph.remove_where(steps_on({3, 6}), touching=(3, 6, 99)) == 4
    assert graph._remove == full._remove
    graph.solve()
    left = graph._smoother.getFactors()
    kept = [left.at(i) for i in range(left.size()) if left.at(i) is not None]
    assert not any(isinstance(f, gtsam.BetweenFactorVector) and 3 in list(f.keys()) for f in kept)


@pytest.mark.parametrize("smoother", ["isam2", "batch"])
def test_the_step_between_two_keys_is_what_the_whole_window_says(smoother: str) -> None:
    """The cross-covariance of two keys gives their difference's covariance as QR on the whole
    window does. Two keys that each close a loop to the start share the start's error (its
    prior's sigma of 100): their marginals are both about 100 squared, and the growth from one
    to the next says nothing of the step between them, which the cross-covariance gets."""
    graph = WindowGraph(VioConfig(smoother=smoother), lag=20.0)
    _chain(graph, 0, 6, sigma=1.0)
    loop = gtsam.noiseModel.Isotropic.Sigma(3, 0.2)
    graph.add(gtsam.BetweenFactorVector(0, 6, 6 * STEP, loop))
    graph.solve()
    _chain(graph, 7, 7, sigma=1.0)
    graph.add(gtsam.BetweenFactorVector(0, 7, 7 * STEP, gtsam.noiseModel.Isotropic.Sigma(3, 0.05)))
    sol = graph.solve(covariance_of=(7,), cross_of=[(6, 7), (99, 7)])
    assert set(sol.cross) == {(6, 7)}  # a key the window does not hold is skipped
    lin = graph._smoother.getFactors().linearize(sol.estimate)
    ordering = gtsam.Ordering()
    for k in range(8):
        ordering.push_back(k)
    info, _ = lin.hessian(ordering)
    d = np.zeros((3, 24))
    d[:, 21:24], d[:, 18:21] = np.eye(3), -np.eye(3)
    want = d @ np.linalg.inv(info) @ d.T
    got = sol.covariances[7] + sol.covariances[6] - sol.cross[(6, 7)] - sol.cross[(6, 7)].T
    # the marginals are 1e4 and the step 0.04: agreement to about 1e-9 of the marginals
    np.testing.assert_allclose(got, want, atol=1e-4)
    # the step: the 0.2 and 0.05 loops with the unit step between them, about 0.2 squared
    assert 0.03 < float(want[0, 0]) < 0.05
    assert sol.covariances[7][0, 0] > 9_000.0
    # the newest key's marginal shrinks (its loop is the tighter) while the step is 0.04
    assert float(sol.covariances[7][0, 0] - sol.covariances[6][0, 0]) < -0.03
