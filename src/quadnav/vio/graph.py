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

Either factorises the linearised window with Cholesky (iSAM2's default, the faster). Since
GTSAM 4.3 a frontal block whose reciprocal condition number, its diagonal equilibrated, is under
sqrt(eps) (1.5e-8) is "Indeterminate linear system": on a long run the window gets there (the
gyro bias's random walk between keyframes 0.1 s apart weighs up to 1e11, the weakest direction
1e-2). The solve is then redone with QR on a smoother rebuilt from the last good solve's factors
and linearisation point with what was pending; the next ``qr_fallback_solves`` solves stay on
QR, then a rebuild tries Cholesky again; refused again, QR holds twice as long (up to 64 times).
:attr:`WindowGraph.fallbacks` counts them. A solve that fails with QR too passes GTSAM's error
on.

Other parts of the system add factors through :meth:`WindowGraph.add` (one-off) or through a
hook the window calls for each new keyframe (GPS, loop-closure priors: see
:class:`~quadnav.vio.window.SlidingWindow`).

With ``history`` the graph also keeps every factor it was given (less those removed) and each
variable's last accepted estimate (:meth:`WindowGraph.commit`; :meth:`WindowGraph.rollback`
drops what came since), marginalised or not: :meth:`WindowGraph.history` is the whole run's
graph again, for a smoothing over all of it at the end (``VioConfig.final_smoothing``). It
grows with the run (about 1 kB per observation).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Collection, Iterable, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from quadnav.vio.config import VioConfig

__all__ = ["GTSAM_ERRORS", "GraphHistory", "GraphSolution", "WindowGraph"]

FloatArray = NDArray[np.float64]

#: What GTSAM raises on a singular system or a failed solve.
GTSAM_ERRORS = (RuntimeError, IndexError, ValueError)


@dataclass(frozen=True, slots=True)
class GraphSolution:
    """A solve's estimate, the graph's total error there, the marginal covariances asked
    for (by key), the cross-covariances asked for (by pair of keys: ``cov(a, b)``, rows
    ``a``'s tangent, columns ``b``'s; a pair GTSAM could not give is absent), and whether
    Cholesky failed and QR redid it."""

    estimate: gtsam.Values
    error: float
    covariances: dict[int, FloatArray]
    qr_fallback: bool = False
    cross: dict[tuple[int, int], FloatArray] = dataclasses.field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class GraphHistory:
    """Every factor a window was given and not removed, and each variable's last estimate
    (its starting value if no solve has seen it): the whole segment's graph again."""

    factors: gtsam.NonlinearFactorGraph
    values: gtsam.Values


class WindowGraph:
    """A fixed-lag smoother over keys stamped with a time (the keyframe number); see the
    module. ``history``: keep the whole graph too (:meth:`history`)."""

    def __init__(self, config: VioConfig, lag: float, *, history: bool = False) -> None:
        self.config = config
        self.lag = float(lag)
        self._smoother: gtsam.BatchFixedLagSmoother | gtsam.IncrementalFixedLagSmoother
        self._smoother = self._new_smoother()
        self._graph = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()
        self._stamps: dict[int, float] = {}
        self._remove: list[int] = []
        #: the last good solve's factors (their slots as the smoother numbers them),
        #: linearisation point and stamps: what a rebuilt smoother starts from
        self._kept = _Kept(gtsam.NonlinearFactorGraph(), gtsam.Values(), {})
        self._qr_left = 0  # solves left on QR after a fallback (0: on Cholesky)
        self._qr_hold = config.qr_fallback_solves  # QR solves after the next fallback
        #: solves that Cholesky failed and QR redid
        self.fallbacks = 0
        self._history = history
        self._hist: list[gtsam.NonlinearFactor | None] = []
        self._hist_of: dict[int, list[int]] = {}  # key -> its factors' places in _hist
        self._hist_values = gtsam.Values()
        self._hist_mark = 0  # the history's factors from here on are not committed yet
        self._hist_new: list[int] = []  # keys first inserted since the last commit
        self._solved: gtsam.Values | None = None  # the last solve's estimate, not committed

    def _new_smoother(
        self, *, qr: bool = False
    ) -> gtsam.BatchFixedLagSmoother | gtsam.IncrementalFixedLagSmoother:
        cfg = self.config
        if cfg.smoother == "isam2":
            p = gtsam.ISAM2Params()
            p.setRelinearizeThreshold(cfg.isam2_relinearize_threshold)
            p.relinearizeSkip = 1
            p.findUnusedFactorSlots = True  # removed factors' slots are reused: bounded
            if qr:
                p.setFactorization("QR")
            return gtsam.IncrementalFixedLagSmoother(self.lag, p)
        lm = gtsam.LevenbergMarquardtParams()
        lm.setMaxIterations(cfg.optimizer_iterations)
        lm.setRelativeErrorTol(1e-3)
        lm.setlambdaUpperBound(1e6)
        if qr:
            lm.setLinearSolverType("MULTIFRONTAL_QR")
        return gtsam.BatchFixedLagSmoother(self.lag, lm)

    @property
    def on_qr(self) -> bool:
        """The smoother factorises with QR (after a Cholesky failure, for a while)."""
        return self._qr_left > 0

    # -- building ---------------------------------------------------------------------------
    def insert(
        self,
        key: int,
        value: gtsam.Pose3
        | gtsam.imuBias.ConstantBias
        | gtsam.Cal3_S2
        | gtsam.Cal3DS2
        | gtsam.Cal3Fisheye
        | FloatArray,
        stamp: float,
    ) -> None:
        """A new variable with its starting value, stamped (it leaves the lag with it)."""
        self._values.insert(key, value)
        self._stamps[key] = float(stamp)
        if self._history and not self._hist_values.exists(key):
            one = gtsam.Values()
            one.insert(key, value)
            self._hist_values.insert(one)
            self._hist_new.append(key)

    def restamp(self, key: int, stamp: float) -> None:
        """A variable already in the graph made as new as ``stamp`` (one that must never leave
        the lag, such as a calibration, is restamped with each new keyframe)."""
        self._stamps[key] = float(stamp)

    def add(self, factor: gtsam.NonlinearFactor) -> None:
        """A factor for the next solve; its keys must be in the graph by then."""
        self._graph.add(factor)
        if self._history:
            at = len(self._hist)
            self._hist.append(factor)
            for key in factor.keys():  # noqa: SIM118 (a GTSAM factor)
                self._hist_of.setdefault(int(key), []).append(at)

    def add_all(self, factors: Sequence[gtsam.NonlinearFactor]) -> None:
        for f in factors:
            self.add(f)

    def commit(self) -> None:
        """The caller accepted the last solve: its estimate becomes the history's values, and
        the factors and variables given so far stay in it (see :meth:`rollback`)."""
        if self._solved is not None:
            self._hist_values.insert_or_assign(self._solved)
        self._solved = None
        self._hist_mark = len(self._hist)
        self._hist_new = []

    def rollback(self) -> None:
        """The caller refused what came since the last commit (a solve that diverged or gave
        an implausible state): its factors and new variables leave the history, and the
        history keeps the last committed estimates."""
        for i in range(self._hist_mark, len(self._hist)):
            self._hist[i] = None
        for key in self._hist_new:
            if self._hist_values.exists(key):
                self._hist_values.erase(key)
        self._hist_new = []
        self._solved = None

    def history(self) -> GraphHistory:
        """The whole graph so far (see the module; empty without ``history``)."""
        graph = gtsam.NonlinearFactorGraph()
        for f in self._hist:
            if f is not None:
                graph.add(f)
        return GraphHistory(graph, gtsam.Values(self._hist_values))

    def remove_where(
        self,
        keep: Callable[[gtsam.NonlinearFactor], bool],
        touching: Collection[int] | None = None,
        *,
        forget: bool = True,
    ) -> int:
        """Drop, at the next solve, the smoother's factors for which ``keep`` is False; how
        many. ``touching``: only factors on one of these keys are looked at (``keep`` must keep
        every other): GTSAM's variable index finds them, instead of a look at every factor
        (0.1 ms for a window's 1,500 slots, against 2 ms). ``forget`` False: the history keeps
        them (dropped from the window for its cost, not because they are wrong)."""
        fs = self._smoother.getFactors()
        if touching is None:
            candidates: Iterable[int] = range(fs.size())
        else:
            index, found = gtsam.VariableIndex(fs), set[int]()
            for key in touching:
                with contextlib.suppress(ValueError):  # a key the smoother no longer holds
                    found.update(int(i) for i in index.at(key))
            candidates = sorted(found)
        slots = []
        for i in candidates:
            f = fs.at(i)
            if f is not None and not keep(f):
                slots.append(i)
        self._remove.extend(slots)
        if self._history and forget:
            self._forget(keep, touching)
        return len(slots)

    def _forget(
        self, keep: Callable[[gtsam.NonlinearFactor], bool], touching: Collection[int] | None
    ) -> None:
        """The history's factors ``keep`` refuses dropped too (those marginalised already
        included: a landmark found bad leaves the whole run's graph)."""
        places = (
            range(len(self._hist))
            if touching is None
            else sorted({i for key in touching for i in self._hist_of.get(int(key), ())})
        )
        for i in places:
            f = self._hist[i]
            if f is not None and not keep(f):
                self._hist[i] = None

    @property
    def factor_slots(self) -> int:
        """The smoother's factor slots (a removed factor's slot counts until it is reused):
        what its factor graph holds in memory."""
        return int(self._smoother.getFactors().size())

    # -- solving ----------------------------------------------------------------------------
    def marginal(self, key: int) -> FloatArray | None:
        """The marginal covariance of ``key`` at the last solve (None: not in the window, or
        GTSAM could not give it)."""
        try:
            covs = self._solution(self._smoother, [key], qr=self.on_qr).covariances
        except GTSAM_ERRORS:
            return None
        return covs.get(key)

    def solve(
        self, covariance_of: Sequence[int] = (), cross_of: Sequence[tuple[int, int]] = ()
    ) -> GraphSolution:
        """Add what is pending, optimise, marginalise what left the lag; the marginal
        covariances of ``covariance_of`` (keys still in the window) and the cross-covariances
        of the pairs ``cross_of`` (iSAM2 on Cholesky only: from the same joint marginal, at
        little cost; a key the solve marginalised is skipped). A Cholesky failure is
        redone with QR (see the module); GTSAM's errors otherwise pass through
        (:data:`GTSAM_ERRORS`): the caller says why a solve failed."""
        pending = _Pending(self._graph, self._values, dict(self._stamps.items()), self._remove)
        self._graph, self._values, self._stamps, self._remove = (
            gtsam.NonlinearFactorGraph(), gtsam.Values(), {}, []
        )  # fmt: skip
        back_to_cholesky = self._qr_left == 1
        try:
            if back_to_cholesky:
                sm = self._rebuilt(pending, qr=False)
            else:
                sm = self._smoother
                sm.update(
                    pending.graph, pending.values, dict(pending.stamps.items()), pending.remove
                )
            sol = self._solution(sm, covariance_of, qr=self._qr_left > 1, cross_of=cross_of)
            self._qr_left = max(self._qr_left - 1, 0)
        except GTSAM_ERRORS:
            if self._qr_left > 1 or self.config.qr_fallback_solves == 0:
                raise  # QR failed too, or no fallback
            sm = self._rebuilt(pending, qr=True)
            sol = dataclasses.replace(self._solution(sm, covariance_of, qr=True), qr_fallback=True)
            self.fallbacks += 1
            # a window Cholesky refuses again when retried stays on QR twice as long (up to
            # 64 times): each retry costs two full factorisations
            base = self.config.qr_fallback_solves
            self._qr_hold = min(2 * self._qr_hold, 64 * base) if back_to_cholesky else base
            self._qr_left = self._qr_hold + 1
        self._smoother = sm
        if self._history:  # the history takes it once the caller accepts it (commit)
            self._solved = sol.estimate
        # copies (the smoother returns its own graph and values, which change in place); the
        # linearisation point, not the estimate: the marginal factors iSAM2 keeps are linear
        # in the step from it (rebuilt at the estimate, a window's error triples)
        kept = gtsam.NonlinearFactorGraph()
        kept.push_back(sm.getFactors())
        stamps = dict(sm.timestamps())  # (a copy: keys and stamps as Python numbers)
        self._kept = _Kept(kept, gtsam.Values(sm.getLinearizationPoint()), stamps)
        return sol

    def _rebuilt(
        self, pending: _Pending, *, qr: bool
    ) -> gtsam.BatchFixedLagSmoother | gtsam.IncrementalFixedLagSmoother:
        """A new smoother (QR or Cholesky) from the last good solve and what is pending, updated
        once (it marginalises what is older than the lag at that update)."""
        kept, gone = self._kept, set(pending.remove)
        graph = gtsam.NonlinearFactorGraph()
        for i in range(kept.factors.size()):
            f = kept.factors.at(i)
            if f is not None and i not in gone:
                graph.add(f)
        graph.push_back(pending.graph)
        values = gtsam.Values(kept.theta)
        values.insert(pending.values)
        sm = self._new_smoother(qr=qr)
        sm.update(graph, values, dict({**kept.stamps, **pending.stamps}.items()))
        return sm

    @staticmethod
    def _solution(
        sm: gtsam.BatchFixedLagSmoother | gtsam.IncrementalFixedLagSmoother,
        covariance_of: Sequence[int],
        *,
        qr: bool,
        cross_of: Sequence[tuple[int, int]] = (),
    ) -> GraphSolution:
        """The smoother's estimate, error and marginal covariances (iSAM2's from its Bayes
        tree, factorised as the smoother is: on Cholesky, the keys' joint marginal at once,
        which costs a third less than one key at a time (the same blocks to 1e-8), one key at a
        time if that fails or on QR; the batch smoother's from the whole window, with QR when
        ``qr``: ``Marginals`` would use Cholesky)."""
        est = sm.calculateEstimate()
        error = float(sm.getFactors().error(est))
        covs: dict[int, FloatArray] = {}
        cross: dict[tuple[int, int], FloatArray] = {}
        if covariance_of and np.isfinite(error):
            pairs = [(a, b) for a, b in cross_of if est.exists(a) and est.exists(b)]
            if isinstance(sm, gtsam.IncrementalFixedLagSmoother):
                if not qr:
                    covs, cross = _joint_marginals(sm, covariance_of, pairs)
                covs = covs or {k: np.asarray(sm.marginalCovariance(k)) for k in covariance_of}
            elif qr:
                lin = sm.getFactors().linearize(est)
                covs = {
                    k: np.asarray(
                        np.linalg.inv(lin.marginal([k], gtsam.EliminateQR).hessian()[0]), np.float64
                    )
                    for k in covariance_of
                }
            else:
                marg = gtsam.Marginals(sm.getFactors(), est)
                covs = {k: np.asarray(marg.marginalCovariance(k)) for k in covariance_of}
                for a, b in pairs:
                    joint = marg.jointMarginalCovariance([a, b])
                    covs.setdefault(a, np.asarray(joint.at(a, a), np.float64))
                    cross[(a, b)] = np.asarray(joint.at(a, b), np.float64)
        return GraphSolution(estimate=est, error=error, covariances=covs, cross=cross)


def _joint_marginals(
    sm: gtsam.IncrementalFixedLagSmoother,
    keys: Sequence[int],
    pairs: Sequence[tuple[int, int]] = (),
) -> tuple[dict[int, FloatArray], dict[tuple[int, int], FloatArray]]:
    """The marginal covariances of ``keys`` and the pairs' keys, and the cross-covariances of
    ``pairs``, from one joint marginal in iSAM2's Bayes tree; empty for fewer than two keys or
    if GTSAM fails (the caller then asks one key at a time)."""
    every = list(dict.fromkeys([*keys, *(k for pair in pairs for k in pair)]))
    if len(every) < 2:
        return {}, {}
    try:
        joint = sm.getISAM2().jointMarginalCovariance(every)
        covs = {k: np.asarray(joint.at(k, k), np.float64) for k in every}
        cross = {(a, b): np.asarray(joint.at(a, b), np.float64) for a, b in pairs}
    except GTSAM_ERRORS:
        return {}, {}
    return covs, cross


@dataclass(frozen=True, slots=True)
class _Pending:
    """What a solve adds: factors, new values, stamps, the smoother's factor slots to drop."""

    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    stamps: dict[int, float]
    remove: list[int]


@dataclass(frozen=True, slots=True)
class _Kept:
    """A good solve's smoother factors (slots kept), linearisation point and stamps."""

    factors: gtsam.NonlinearFactorGraph
    theta: gtsam.Values
    stamps: dict[int, float]
