"""The SLAM's loop closing (ORB-SLAM2's ``LoopClosing``, stereo: scale is known, so SE(3)), run
after each keyframe in the tracker's thread.

1. **Detection.** The keyframe's bag of words is looked up in the keyframe database
   (:class:`~quadnav.slam.relocalization.KeyframeDatabase`). Candidates are keyframes at least
   ``min_gap_keyframes`` older, not among its covisible ones, scoring at least what its least
   similar covisible keyframe scores (ORB-SLAM2's ``minScore``). A candidate must be found again
   by ``consistency`` keyframes in a row (it, or a keyframe covisible with it).
2. **Geometry.** The candidate's map points and those of its covisible keyframes are matched
   to the keyframe's keypoints by descriptor; PnP in RANSAC gives the keyframe's pose in the
   old map; a projection search of those points and the pose optimisation
   (:func:`~quadnav.slam.optimizer.optimize_pose`) must keep ``min_inliers``.
3. **Correction.** An SE(3) pose graph over every keyframe (:mod:`quadnav.posegraph`): the
   keyframes' relative poses before the loop (the sequential edges, and an edge between each
   pair sharing ``covisibility_edge`` points or more: ORB-SLAM2's essential graph) and the
   loop's edge, the first keyframe held. Each keyframe takes its corrected pose, each map point
   moves with the keyframe that made it.
   Before it, the loop must ask for no more than the drift can be: a correction over
   ``max_drift_m`` plus ``max_drift_fraction`` of the shortest way from the old keyframe to the
   new one through the map (keyframe to keyframe, the essential graph, the loops closed), or
   over ``max_drift_deg``, is a place that repeats and is refused (``rejected``).
4. **Fusion.** The old points found in the keyframe replace the duplicates it had made of them,
   in every keyframe that observes a duplicate.

ORB-SLAM2 follows with a global bundle adjustment in a thread of its own; not here yet."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.rotations import Pose
from quadnav.slam.config import LoopClosingConfig
from quadnav.slam.frame import Frame
from quadnav.slam.map import SlamKeyframe, SlamMap, pose_now
from quadnav.slam.relocalization import KeyframeDatabase

if TYPE_CHECKING:
    from quadnav.posegraph import LoopEdge

__all__ = ["LoopCloser", "LoopClosingReport", "PoseFitter"]

IntArray = NDArray[np.int64]


class PoseFitter(Protocol):
    """The tracker's projection search and pose optimisation of ``frame`` on map points
    ``ids`` from ``guess``: ``(T_C_W, keypoints, points)`` kept, or None."""

    def __call__(
        self, frame: Frame, guess: Pose, ids: IntArray
    ) -> tuple[Pose, IntArray, IntArray] | None: ...


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopClosingReport:
    """A loop closed: the keyframes (``old``, ``new``), the inliers that confirmed it, how far
    the new keyframe moved (m, rad), the points fused, the essential graph's edges."""

    old: int
    new: int
    inliers: int
    moved_m: float
    turned_rad: float
    fused: int
    edges: int


@dataclass
class LoopCloser:
    """Loop closing over the tracker's map and keyframe database (see the module)."""

    config: LoopClosingConfig = field(default_factory=LoopClosingConfig)
    closed: list[LoopClosingReport] = field(default_factory=list)
    _streak: list[tuple[int, set[int]]] = field(default_factory=list)  # (keyframe, group)
    _last_loop: int = -(10**9)
    #: loops found but refused as implausible (a correction larger than the drift can be), and
    #: what each asked for (``keyframe N to M: moves 1.512 m and 2.1 deg; the drift can be...``)
    rejected: int = 0
    refusals: list[str] = field(default_factory=list)

    def after_keyframe(
        self, kf: SlamKeyframe, m: SlamMap, db: KeyframeDatabase, fit: PoseFitter
    ) -> LoopClosingReport | None:
        """Look for a loop at the newest keyframe ``kf`` and close it (see the module);
        ``fit(frame, guess, ids)``: the tracker's projection search and pose optimisation on
        points ``ids`` from ``guess``, giving ``(T_C_W, keypoints, points)`` or None."""
        cfg = self.config
        if not cfg.enabled or kf.index - self._last_loop < cfg.min_gap_keyframes:
            return None
        cand = self._consistent(kf, m, db)
        if cand is None:
            return None
        found = self._geometry(kf, m, cand, fit)
        if found is None:
            return None
        T_C_W, kps, ids = found
        edges = self._essential_edges(m)
        refusal = self._implausible(kf, m, m.keyframes[cand], T_C_W, edges)
        if refusal is not None:
            self.rejected += 1
            self.refusals.append(refusal)
            self._streak.clear()
            return None
        report = self._correct(kf, m, m.keyframes[cand], T_C_W, kps, ids, edges)
        self._last_loop = kf.index
        self._streak.clear()
        self.closed.append(report)
        return report

    # -- detection ------------------------------------------------------------------------------
    def _consistent(self, kf: SlamKeyframe, m: SlamMap, db: KeyframeDatabase) -> int | None:
        cfg = self.config
        near = m.covisible(kf, cfg.covisible)
        near_ids = {k.index for k in near}
        bow, _ = db.db.transform(kf.frame.features.descriptors)
        scores = db.db.scores(bow)
        others = [k.index for k in near[1:]]
        floor = float(scores[others].min()) if others else 0.0
        ok = [
            int(i) for i in np.argsort(-scores[: len(m.keyframes)], kind="stable")
            if i <= kf.index - cfg.min_gap_keyframes and int(i) not in near_ids
            and scores[i] >= floor and scores[i] > 0 and not m.keyframes[int(i)].bad
        ][:3]  # fmt: skip
        groups = [(c, {k.index for k in m.covisible(m.keyframes[c], cfg.covisible)}) for c in ok]
        prev = self._streak[-1][1] if self._streak else set()
        hit = next(((c, g) for c, g in groups if g & prev), None)
        if hit is None:
            self._streak = [groups[0]] if groups else []
            return None
        self._streak.append(hit)
        return hit[0] if len(self._streak) >= cfg.consistency else None

    def _geometry(
        self, kf: SlamKeyframe, m: SlamMap, cand: int, fit: PoseFitter
    ) -> tuple[Pose, IntArray, IntArray] | None:
        from quadnav.geometry.multiview import pnp
        from quadnav.place.verification import match_descriptors

        cfg = self.config
        ids = m.local_points(m.covisible(m.keyframes[cand], cfg.covisible))
        f, c = kf.frame.features, kf.frame.camera
        ia, ib = match_descriptors(m.descriptors[ids], f.descriptors, max_hamming=cfg.max_hamming,
                                   ratio=cfg.ratio)  # fmt: skip
        if len(ia) < cfg.min_matches:
            return None
        xy = np.column_stack([(f.uv_px[ib, 0] - c.cx) / c.fx, (f.uv_px[ib, 1] - c.cy) / c.fy])
        res = pnp(m.X_W[ids[ia]], xy, ransac_threshold=cfg.ransac_px / c.fx,
                  min_points=cfg.min_matches // 2, iterations=300, seed=kf.index)  # fmt: skip
        if res is None:
            return None
        out = fit(kf.frame, res.T_W_C.inverse(), ids)
        if out is None or len(out[1]) < cfg.min_inliers:
            return None
        return out

    def _implausible(
        self, kf: SlamKeyframe, m: SlamMap, old: SlamKeyframe, T_C_W: Pose,
        edges: list[LoopEdge],
    ) -> str | None:  # fmt: skip
        """Why the loop is refused, or None when it moves ``kf`` by no more than the drift can
        have grown between it and ``old``: ``max_drift_m`` plus ``max_drift_fraction`` of the
        shortest way between them through the map (:meth:`_way_m`), and ``max_drift_deg``. A
        place that repeats (a wallpaper's period, a second identical shelf) passes every
        geometric check and asks for a jump of that period."""
        cfg = self.config
        length = self._way_m(m, old.index, kf.index, edges)
        moved = float(np.linalg.norm(kf.T_C_W.inverse().p_A_B - T_C_W.inverse().p_A_B))
        turned = float(np.degrees((kf.T_C_W.R_A_B * T_C_W.R_A_B.inv()).magnitude()))
        bound = cfg.max_drift_m + cfg.max_drift_fraction * length  # (no way: max_drift_m)
        bound = bound if np.isfinite(bound) else cfg.max_drift_m
        if moved <= bound and turned <= cfg.max_drift_deg:
            return None
        return (
            f"keyframe {kf.index} to {old.index} refused: it moves {moved:.3f} m and "
            f"{turned:.2f} deg; the drift can be {bound:.3f} m and {cfg.max_drift_deg:g} deg"
        )

    def _way_m(self, m: SlamMap, a: int, b: int, edges: list[LoopEdge]) -> float:
        """The shortest way (m) from keyframe ``a`` to ``b`` over the map's graph: from each
        keyframe to the next, along the essential graph's ``edges`` and the loops closed
        before, each as long as the keyframes are apart now. The drift between two keyframes
        grows along the way the map joins them: after a lap that closed a loop it is the way
        back through that loop, not every lap since (in a room flown around for minutes, 3 %
        of the whole path would let any jump through)."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import dijkstra

        n = len(m.keyframes)
        # (a culled keyframe where its parent has it now: its own pose no longer moves)
        pos = np.array([pose_now(k, m.keyframes).inverse().p_A_B for k in m.keyframes])
        pairs = [(i, i + 1) for i in range(n - 1)]
        pairs += [(e.old, e.new) for e in edges] + [(r.old, r.new) for r in self.closed]
        # (each pair once: a sparse matrix adds up the duplicates of an entry)
        i, j = np.unique(np.sort(np.array(pairs, np.int64).reshape(-1, 2), axis=1), axis=0).T
        w = np.linalg.norm(pos[i] - pos[j], axis=1) + 1e-9  # (zero would be no edge)
        graph = coo_matrix((w, (i, j)), shape=(n, n)).tocsr()
        return float(dijkstra(graph, directed=False, indices=a)[b])

    # -- correction ------------------------------------------------------------------------------
    def _correct(
        self, kf: SlamKeyframe, m: SlamMap, old: SlamKeyframe, T_C_W: Pose, kps: IntArray,
        ids: IntArray, edges: list[LoopEdge],
    ) -> LoopClosingReport:  # fmt: skip
        from quadnav.posegraph import PoseGraphConfig, PoseGraphProblem, solve

        cfg = self.config
        before = [k.T_C_W for k in m.keyframes]
        T_old_new = old.T_C_W @ T_C_W.inverse()  # (the new camera in the old one's frame)
        loop = _edge(old.index, kf.index, T_old_new, cfg.loop_sigma_m, cfg.loop_sigma_rad)
        graph = PoseGraphConfig(kind="se3", sequential_sigma_m=cfg.edge_sigma_m,
                                sequential_sigma_rot_rad=cfg.edge_sigma_rad, robust="none")  # fmt: skip
        problem = PoseGraphProblem.from_poses(
            [k.index for k in m.keyframes], [T.inverse() for T in before], [*edges, loop],
            config=graph,
        )  # fmt: skip
        result = solve(problem)
        for k, T_W_C in zip(m.keyframes, result.poses, strict=True):
            k.T_C_W = T_W_C.inverse()
        _move_points(m, before)
        moved = before[kf.index].inverse().p_A_B - kf.T_C_W.inverse().p_A_B
        dR = (before[kf.index].R_A_B * kf.T_C_W.R_A_B.inv()).magnitude()
        fused = _fuse(m, kf, kps, ids)
        return LoopClosingReport(old=old.index, new=kf.index, inliers=len(kps),
                                 moved_m=float(np.linalg.norm(moved)), turned_rad=float(dR),
                                 fused=fused, edges=len(edges) + 1)  # fmt: skip

    def _essential_edges(self, m: SlamMap) -> list[LoopEdge]:
        """An edge between each pair of keyframes sharing ``covisibility_edge`` points or more
        (beyond the sequential ones the graph makes), at their relative pose now."""
        cfg = self.config
        out: list[LoopEdge] = []
        for kf in m.keyframes:
            _, ids = kf.observed
            counts = m.sharing(ids[~m.bad[ids]], among=m.keyframes[: kf.index])
            for j in np.flatnonzero(counts >= cfg.covisibility_edge):
                if kf.index - int(j) <= 4:  # (a sequential edge joins them already)
                    continue
                a = m.keyframes[int(j)]
                T = a.T_C_W @ kf.T_C_W.inverse()
                out.append(_edge(a.index, kf.index, T, cfg.edge_sigma_m, cfg.edge_sigma_rad))
        return out


def _edge(old: int, new: int, T_old_new: Pose, sigma_m: float, sigma_rad: float) -> LoopEdge:
    from quadnav.posegraph import LoopEdge

    cov = np.diag([sigma_rad**2] * 3 + [sigma_m**2] * 3)
    return LoopEdge(old=old, new=new, T_old_new=T_old_new, cov=cov)


def _move_points(m: SlamMap, before: list[Pose]) -> None:
    """Each map point moved with the keyframe that made it (its pose ``before`` to now)."""
    order = np.argsort(m.first_keyframe, kind="stable")
    ends = np.searchsorted(m.first_keyframe[order], np.arange(len(m.keyframes) + 1))
    for k, kf in enumerate(m.keyframes):
        sel = order[ends[k] : ends[k + 1]]
        if len(sel):
            m.X_W[sel] = kf.T_C_W.inverse() @ (before[k] @ m.X_W[sel])


def _fuse(m: SlamMap, kf: SlamKeyframe, kps: IntArray, ids: IntArray) -> int:
    """The old points ``ids`` found at ``kf``'s keypoints ``kps`` replace the points ``kf`` had
    there (in every keyframe); those it had none at observe them now. How many were replaced."""
    fused = 0
    for kp, old in zip(kps.tolist(), ids.tolist(), strict=True):
        dup = int(kf.points[kp])
        if dup == old or m.bad[old]:  # (an old point this fusion has just replaced)
            continue
        if dup >= 0:
            m.replace(dup, old)
            fused += 1
        elif not (kf.points == old).any():
            m.observe(kf, np.array([kp]), np.array([old]))
    return fused
