"""The window's factor graph and its solver: factors and values wait in a pending batch, and a
solve hands them to a GTSAM fixed-lag smoother that optimises and marginalises what is older
than the lag (its information stays as a linear factor on what remains).

Two smoothers (``VioConfig.smoother``):

- ``isam2`` (the default): ``IncrementalFixedLagSmoother``, iSAM2 underneath (incremental:
  only the part of the Bayes tree the new factors touch is refactored, and variables are
  relinearised when they move more than ``isam2_relinearize_threshold``); the newest state's
  marginal covariance comes from the Bayes tree at little cost.
- ``batch``: ``BatchFixedLagSmoother``, Levenberg-Marquardt over the whole window each solve
  (``optimizer_iterations`` steps), marginal covariances from a full ``Marginals``. Slower;
  kept as the reference.

Other parts of the system add factors through :meth:`WindowGraph.add` (one-off) or through a
hook the window calls for each new keyframe (GPS, loop-closure priors: see
:class:`~quadnav.vio.window.SlidingWindow`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import SupportsFloat, SupportsInt

import gtsam
import numpy as np
from numpy.typing import NDArray

from quadnav.vio.config import VioConfig

__all__ = ["GTSAM_ERRORS", "GraphSolution", "WindowGraph"]

FloatArray = NDArray[np.float64]

#: What GTSAM raises on a singular system or a failed solve.
GTSAM_ERRORS = (RuntimeError, IndexError, ValueError)


@dataclass(frozen=True, slots=True)
class GraphSolution:
    """A solve's estimate, the graph's total error there, and the marginal covariances asked
    for (by key)."""

    estimate: gtsam.Values
    error: float
    covariances: dict[int, FloatArray]


class WindowGraph:
    """A fixed-lag smoother over keys stamped with a time (the keyframe number); see the
    module."""

    def __init__(self, config: VioConfig, lag: float) -> None:
        self.config = config
        self.lag = float(lag)
        self._smoother: gtsam.BatchFixedLagSmoother | gtsam.IncrementalFixedLagSmoother
        self._smoother = self._new_smoother()
        self._graph = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()
        self._stamps: dict[SupportsInt, SupportsFloat] = {}
        self._remove: list[int] = []

    def _new_smoother(self) -> gtsam.BatchFixedLagSmoother | gtsam.IncrementalFixedLagSmoother:
        cfg = self.config
        if cfg.smoother == "isam2":
            p = gtsam.ISAM2Params()
            p.setRelinearizeThreshold(cfg.isam2_relinearize_threshold)
            p.relinearizeSkip = 1
            p.findUnusedFactorSlots = True  # removed factors' slots are reused: bounded
            return gtsam.IncrementalFixedLagSmoother(self.lag, p)
        lm = gtsam.LevenbergMarquardtParams()
        lm.setMaxIterations(cfg.optimizer_iterations)
        lm.setRelativeErrorTol(1e-3)
        lm.setlambdaUpperBound(1e6)
        return gtsam.BatchFixedLagSmoother(self.lag, lm)

    # -- building ---------------------------------------------------------------------------
    def insert(
        self,
        key: int,
        value: gtsam.Pose3 | gtsam.imuBias.ConstantBias | gtsam.Cal3_S2 | FloatArray,
        stamp: float,
    ) -> None:
        """A new variable with its starting value, stamped (it leaves the lag with it)."""
        self._values.insert(key, value)
        self._stamps[key] = float(stamp)

    def restamp(self, key: int, stamp: float) -> None:
        """A variable already in the graph made as new as ``stamp`` (one that must never leave
        the lag, such as a calibration, is restamped with each new keyframe)."""
        self._stamps[key] = float(stamp)

    def add(self, factor: gtsam.NonlinearFactor) -> None:
        """A factor for the next solve; its keys must be in the graph by then."""
        self._graph.add(factor)

    def add_all(self, factors: Sequence[gtsam.NonlinearFactor]) -> None:
        for f in factors:
            self._graph.add(f)

    def remove_where(self, keep: Callable[[gtsam.NonlinearFactor], bool]) -> int:
        """Drop, at the next solve, the smoother's factors for which ``keep`` is False; how
        many."""
        fs = self._smoother.getFactors()
        slots = []
        for i in range(fs.size()):
            f = fs.at(i)
            if f is not None and not keep(f):
                slots.append(i)
        self._remove.extend(slots)
        return len(slots)

    @property
    def factor_slots(self) -> int:
        """The smoother's factor slots (a removed factor's slot counts until it is reused):
        what its factor graph holds in memory."""
        return int(self._smoother.getFactors().size())

    # -- solving ----------------------------------------------------------------------------
    def solve(self, covariance_of: Sequence[int] = ()) -> GraphSolution:
        """Add what is pending, optimise, marginalise what left the lag; the marginal
        covariances of ``covariance_of`` (keys still in the window). GTSAM's errors pass
        through (:data:`GTSAM_ERRORS`): the caller says why a solve failed."""
        graph, values, stamps, remove = self._graph, self._values, self._stamps, self._remove
        self._graph, self._values, self._stamps, self._remove = (
            gtsam.NonlinearFactorGraph(), gtsam.Values(), {}, []
        )  # fmt: skip
        sm = self._smoother
        sm.update(graph, values, dict(stamps.items()), remove)
        est = sm.calculateEstimate()
        error = float(sm.getFactors().error(est))
        covs: dict[int, FloatArray] = {}
        if covariance_of and np.isfinite(error):
            if isinstance(sm, gtsam.IncrementalFixedLagSmoother):
                covs = {k: np.asarray(sm.marginalCovariance(k)) for k in covariance_of}
            else:
                marg = gtsam.Marginals(sm.getFactors(), est)
                covs = {k: np.asarray(marg.marginalCovariance(k)) for k in covariance_of}
        return GraphSolution(estimate=est, error=error, covariances=covs)
