"""The SLAM's tracking (ORB-SLAM2's ``Tracking``, stereo and RGB-D): the first frame with
enough stereo points starts the map at the identity; each next frame is predicted by a
constant-velocity model (or, when too few points match, where the last frame was, or else where
PnP on the reference keyframe's points matched by descriptor puts it), the map
points of the last keyframes are matched to it by projection (a window of ``search_radius_px``
times the point's scale around where it projects, the right coordinate too for stereo
keypoints, the nearest descriptor within ``max_hamming``, one map point per keypoint), its pose
is optimised on them (:mod:`quadnav.slam.optimizer`), matched again with the optimised pose
(the local map) and optimised again. The local map is the points of the keyframes that see the
most of the last frame's points, and of the newest keyframe (ORB-SLAM2's local keyframes, by
covisibility: a place seen again is tracked on the points first made there). Under
``min_inliers`` it is lost, and each next frame tries to relocalize on the map
(:mod:`quadnav.slam.relocalization`); the map is kept. A keyframe is taken on the thesis's
rules (:class:`~quadnav.slam.config.SlamConfig`; not in the frames just after a
relocalization), adds map points from its close stereo points that matched none, and local
mapping runs on it (:mod:`quadnav.slam.local_mapping`). On a map saved before, the tracker
starts lost and relocalizes; in localization-only mode (``mapping=False``) it never adds a
keyframe or a point.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.rotations import Pose
from quadnav.slam.config import RelocalizationConfig, SlamConfig
from quadnav.slam.frame import Frame
from quadnav.slam.local_mapping import LocalMappingReport, global_bundle_adjustment, local_mapping
from quadnav.slam.loop_closing import LoopCloser, LoopClosingReport
from quadnav.slam.map import SlamKeyframe, SlamMap, pose_now
from quadnav.slam.optimizer import optimize_pose
from quadnav.slam.relocalization import KeyframeDatabase, pnp_candidates

__all__ = ["StereoTracker", "TrackResult", "search_by_projection"]

FloatArray = NDArray[np.float64]
TrackState = Literal["waiting", "tracking", "lost"]


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackResult:
    """What tracking made of a frame: its ``state``, the camera's pose ``T_W_C`` (None unless
    tracking), the matches kept after the optimisation, whether it became a keyframe, and the
    keyframe it was relocalized on (None: tracked as usual) and the loop its keyframe closed;
    ``cov_C``: the pose's covariance in the camera frame from the pose-only optimisation
    (:class:`~quadnav.slam.optimizer.PoseFit`; None where none was made, as at the first frame);
    the keypoints tracked (rows of the frame's features) and the map points they observe."""

    t_ns: int
    state: TrackState
    T_W_C: Pose | None
    cov_C: FloatArray | None = None
    inliers: int = 0
    keyframe: bool = False
    relocalized_on: int | None = None
    loop: LoopClosingReport | None = None
    keypoints: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    points: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))


def search_by_projection(
    frame: Frame, X_W: FloatArray, descriptors: NDArray[np.uint8], octave: NDArray[np.int64],
    T_C_W: Pose, radius_px: float, max_hamming: int, taken: NDArray[np.bool_] | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:  # fmt: skip
    """Matches of map points (``X_W``, their ``descriptors`` and the ``octave`` they were seen
    at) to the frame's keypoints (those not ``taken``): (keypoint, point index, Hamming distance), each
    keypoint to at most one point (the nearest descriptor)."""
    from scipy.spatial import cKDTree

    from quadnav.place.vocabulary import hamming

    c, f = frame.camera, frame.features
    taken = np.zeros(len(f), bool) if taken is None else taken
    X = T_C_W @ X_W if len(X_W) else np.zeros((0, 3))
    z = X[:, 2]
    front = z > 0.1
    u = np.where(front, c.fx * X[:, 0] / np.where(front, z, 1) + c.cx, -1e9)
    v = np.where(front, c.fy * X[:, 1] / np.where(front, z, 1) + c.cy, -1e9)
    ur = u - c.bf / np.where(front, z, 1)
    scale = f.scales[np.minimum(octave, len(f.scales) - 1)]
    none = np.zeros(0, np.int64)
    P = np.flatnonzero(front)
    if len(P) == 0 or len(f) == 0:
        return none, none, none
    # every point's keypoints within its window at once: those in its column band, then in its
    # circle; a tie goes to the keypoint a KD-tree over them lists first (its leaves' order)
    tree_order = cKDTree(f.uv_px).indices.astype(np.int64)
    leaf = np.empty(len(f), np.int64)
    leaf[tree_order] = np.arange(len(f))
    by_u = np.argsort(f.uv_px[:, 0], kind="stable")
    r = radius_px * scale[P]
    a = np.searchsorted(f.uv_px[by_u, 0], u[P] - r, side="left")
    counts = np.searchsorted(f.uv_px[by_u, 0], u[P] + r, side="right") - a
    p = np.repeat(P, counts)
    cand = by_u[np.arange(int(counts.sum())) + np.repeat(a - (np.cumsum(counts) - counts), counts)]
    du, dv = f.uv_px[cand, 0] - u[p], f.uv_px[cand, 1] - v[p]
    inside = du * du + dv * dv <= np.repeat(r * r, counts)
    cand, p = cand[inside], p[inside]
    rank = leaf[cand]
    ok = ~taken[cand] & (np.abs(f.octave[cand] - octave[p]) <= 1)
    u_r = frame.stereo.u_right[cand]
    ok &= (u_r < 0) | (np.abs(u_r - ur[p]) <= radius_px * scale[p])
    cand, p, rank = cand[ok], p[ok], rank[ok]
    if len(cand) == 0:
        return none, none, none
    d = hamming(f.descriptors[cand], descriptors[p]).astype(np.int64)
    # each point's nearest keypoint (the first in the tree's order on a tie) within max_hamming:
    # the least of distance * n + leaf over each point's run (p is in runs, ascending)
    n = len(f)
    starts = np.flatnonzero(np.r_[True, p[1:] != p[:-1]])
    best = np.minimum.reduceat(d * n + rank, starts)
    pt, dist, kp = p[starts], best // n, tree_order[best % n]
    keep = dist <= max_hamming
    pt, dist, kp = pt[keep], dist[keep], kp[keep]
    # ... and each keypoint's nearest point (the lower index on a tie)
    o = np.lexsort((pt, dist, kp))
    o = o[np.r_[True, kp[o][1:] != kp[o][:-1]]] if len(o) else o
    return kp[o], pt[o], dist[o]


@dataclass
class _Matches:
    keypoints: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    points: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    cov: FloatArray | None = None  # (the pose fitted on them: its covariance, PoseFit's)


class StereoTracker:
    """Tracking (see the module): :meth:`track` each frame in time order. ``slam_map``: a map
    saved before, tracked on once relocalized in it; ``mapping``: False for localization only
    (no keyframe, no map point is added: ORB-SLAM2's localization mode)."""

    def __init__(
        self, config: SlamConfig | None = None, *, slam_map: SlamMap | None = None,
        mapping: bool = True,
    ) -> None:  # fmt: skip
        self.config = config or SlamConfig()
        self.mapping = mapping
        self.map = slam_map or SlamMap()
        self.state: TrackState = "lost" if self.map.keyframes else "waiting"
        self.database = KeyframeDatabase()
        for kf in self.map.keyframes:
            self.database.add(kf)
        self.last_mapping: LocalMappingReport | None = None
        self.loop_closer = LoopCloser(self.config.loop_closing)
        self.relocalizations = 0
        self.ambiguous = 0  # (relocalizations refused: two places fit)
        self._loop: LoopClosingReport | None = None
        self._T_C_W_last: Pose | None = None
        self._velocity: Pose | None = None  # T_C_W(k) T_W_C(k-1)
        self._since_reloc = 10**9
        self._since_keyframe = 0
        self._reference: SlamKeyframe | None = (
            self.map.keyframes[-1] if self.map.keyframes else None
        )
        self._last_points = np.zeros(0, np.int64)  # the map points the last frame tracked
        # each tracked frame: its time, reference keyframe and pose in it (final_poses)
        self._relative: list[tuple[int, int, NDArray[np.float64]]] = []

    def final_poses(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Every tracked frame's time and camera pose ``T_W_C`` (N, 4, 4) through its reference
        keyframe's pose now: what local mapping and loop closing did since is in it (ORB-SLAM2's
        saved trajectory; not causal)."""
        n = len(self._relative)
        t = np.array([r[0] for r in self._relative], np.int64)
        T = np.empty((n, 4, 4))
        kfs = self.map.keyframes
        T_W_R = {
            k: pose_now(kfs[k], kfs).inverse().matrix() for k in {r[1] for r in self._relative}
        }
        for i, (_, k, T_R_C) in enumerate(self._relative):
            T[i] = T_W_R[k] @ T_R_C
        return t, T

    def track(self, frame: Frame) -> TrackResult:
        if self.state == "waiting":
            if not self.mapping:
                return TrackResult(t_ns=frame.t_ns, state="waiting", T_W_C=None)
            return self._initialize(frame)
        if self.state == "lost" or self._T_C_W_last is None:
            return self._relocalize(frame)
        last = self._T_C_W_last
        guess = last if self._velocity is None else self._velocity @ last
        fit = self._fit(frame, guess)
        if fit is None and self._velocity is not None:
            fit = self._fit(frame, last)  # (the motion changed: from where the last frame was)
        if fit is None:
            fit = self._fit_reference(frame)
        if fit is None:
            self.state = "lost"
            return TrackResult(t_ns=frame.t_ns, state="lost", T_W_C=None)
        T_C_W, matches = fit
        self._velocity = T_C_W @ last.inverse()
        return self._tracked(frame, T_C_W, matches)

    # -- steps --------------------------------------------------------------------------------
    def _initialize(self, frame: Frame) -> TrackResult:
        if int(frame.stereo.matched.sum()) < self.config.init_min_points:
            return TrackResult(t_ns=frame.t_ns, state="waiting", T_W_C=None)
        self.state = "tracking"
        self._T_C_W_last = Pose.identity()
        idx = np.flatnonzero(frame.stereo.matched)
        kf = self.map.add_keyframe(Pose.identity(), frame)
        self._last_points = self.map.add_points(kf, idx)
        self.database.add(kf)
        self._reference = kf
        self._relative.append((frame.t_ns, kf.index, np.eye(4)))
        return TrackResult(t_ns=frame.t_ns, state="tracking", T_W_C=Pose.identity(),
                           inliers=len(idx), keyframe=True)  # fmt: skip

    def _tracked(self, frame: Frame, T_C_W: Pose, matches: _Matches) -> TrackResult:
        """The frame tracked at ``T_C_W`` on ``matches``: the reference keyframe updated (the
        one seeing most of its points) and a keyframe taken if the rules want one."""
        self._T_C_W_last = T_C_W
        self._last_points = matches.points
        self._since_keyframe += 1
        self._since_reloc += 1
        counts = self.map.sharing(matches.points)
        if len(counts) and counts.max() > 0:
            self._reference = self.map.keyframes[int(np.argmax(counts))]
        n = len(matches.keypoints)
        keyframe = self._wants_keyframe(frame, matches)
        self._loop = None
        if keyframe:
            T_C_W = self._add_keyframe(frame, T_C_W, matches)
        if self._reference is not None:
            T_R_C = self._reference.T_C_W @ T_C_W.inverse()
            self._relative.append((frame.t_ns, self._reference.index, T_R_C.matrix()))
        return TrackResult(t_ns=frame.t_ns, state="tracking", T_W_C=T_C_W.inverse(),
                           cov_C=matches.cov, inliers=n, keyframe=keyframe,
                           loop=self._loop, keypoints=matches.keypoints,
                           points=matches.points)  # fmt: skip

    def _relocalize(self, frame: Frame) -> TrackResult:
        """After a loss (or on a loaded map): the keyframes that look like the frame, PnP on
        their points, then the pose confirmed on each one's local map (see
        :mod:`quadnav.slam.relocalization`); the best taken unless another, nearly as good,
        puts the camera elsewhere (a place that repeats: it stays lost, ``ambiguous``)."""
        cfg = self.config.relocalization
        fits: list[tuple[int, tuple[Pose, _Matches]]] = []
        for k, T in pnp_candidates(frame, self.map, self.database.candidates(frame, cfg), cfg):
            self._reference = self.map.keyframes[k]
            self._last_points = np.zeros(0, np.int64)
            fit = self._fit(frame, T)
            if fit is not None and len(fit[1].keypoints) >= cfg.min_inliers:
                fits.append((k, fit))
        if not fits:
            return TrackResult(t_ns=frame.t_ns, state="lost", T_W_C=None)
        k, best = max(fits, key=lambda f: len(f[1][1].keypoints))
        if _ambiguous(best, [f for _, f in fits], cfg):
            self.ambiguous += 1
            return TrackResult(t_ns=frame.t_ns, state="lost", T_W_C=None)
        self._reference = self.map.keyframes[k]
        self.state = "tracking"
        self.relocalizations += 1
        self._velocity = None
        self._since_reloc = 0
        result = self._tracked(frame, *best)
        return dataclasses.replace(result, relocalized_on=k)

    def _fit_reference(self, frame: Frame) -> tuple[Pose, _Matches] | None:
        """ORB-SLAM2's ``TrackReferenceKeyFrame``, for a motion no prediction follows: the
        reference keyframe's points matched to the frame by descriptor, a pose by PnP on them,
        then the local map from it."""
        ref = self._reference
        if ref is None or ref.bad:
            return None
        for _, T in pnp_candidates(frame, self.map, [ref.index], self.config.relocalization):
            return self._fit(frame, T)
        return None

    def _fit(
        self, frame: Frame, guess: Pose, ids: NDArray[np.int64] | None = None
    ) -> tuple[Pose, _Matches] | None:
        """Match and optimise twice (the guess, then the local map from the first fit), on the
        points ``ids`` (default: the local map's)."""
        cfg = self.config
        T = guess
        ids = self._local_points() if ids is None else ids
        for radius in (cfg.search_radius_px, cfg.search_radius_px / 3):
            m = self._match(frame, T, radius, ids)
            if len(m.keypoints) < cfg.min_inliers:
                m = self._match(frame, T, 2 * radius, ids)
            if len(m.keypoints) < cfg.min_inliers:
                return None
            f = frame.features
            fit = optimize_pose(
                T, self.map.X_W[m.points], f.uv_px[m.keypoints], frame.stereo.u_right[m.keypoints],
                f.scales[f.octave[m.keypoints]] ** 2,
                frame.camera.intrinsics,
            )  # fmt: skip
            T = fit.T_C_W
            keep = fit.inliers
            m = _Matches(keypoints=m.keypoints[keep], points=m.points[keep], cov=fit.cov)
            if len(m.keypoints) < cfg.min_inliers:
                return None
        return T, m

    def _fit_on(
        self, frame: Frame, guess: Pose, ids: NDArray[np.int64]
    ) -> tuple[Pose, NDArray[np.int64], NDArray[np.int64]] | None:
        """:meth:`_fit` on points ``ids``, for loop closing."""
        fit = self._fit(frame, guess, ids)
        return None if fit is None else (fit[0], fit[1].keypoints, fit[1].points)

    def local_keyframes(self) -> list[SlamKeyframe]:
        """The keyframes whose points are searched for in the next frame: the newest, and those
        that see the most of the last frame's points (or, without any, the reference keyframe's
        covisible ones), ``local_keyframes`` in all."""
        m, n = self.map, self.config.local_keyframes
        if not m.keyframes:
            return []
        newest = m.keyframes[-1]
        counts = m.sharing(self._last_points) if len(self._last_points) else None
        if counts is None or counts.max() <= 0:
            ref = self._reference or newest
            out = m.covisible(ref, n)
        else:
            order = [int(i) for i in np.argsort(-counts, kind="stable")[:n] if counts[i] > 0]
            out = [m.keyframes[i] for i in order]
        if self.mapping and newest not in out:
            out = [newest, *out[: n - 1]]
        return out

    def _local_points(self) -> NDArray[np.int64]:
        return self.map.local_points(self.local_keyframes())

    def _match(self, frame: Frame, T_C_W: Pose, radius: float, ids: NDArray[np.int64]) -> _Matches:
        m = self.map
        kp, j, _ = search_by_projection(
            frame, m.X_W[ids], m.descriptors[ids], m.octave[ids], T_C_W, radius,
            self.config.max_hamming,
        )  # fmt: skip
        return _Matches(keypoints=kp, points=ids[j])

    def _wants_keyframe(self, frame: Frame, matches: _Matches) -> bool:
        """ORB-SLAM2's ``NeedNewKeyFrame`` for a stereo camera, local mapping being idle (it
        runs inline): when the frame tracks under ``keyframe_ratio`` of the
        points its reference keyframe has that ``keyframe_min_observers`` keyframes see, or
        fewer than ``close_tracked`` close points while ``close_untracked`` more could be made;
        it must track ``keyframe_min_tracked``. Not within ``keyframe_max_frames`` of a
        relocalization (once the map has as many keyframes). ``keyframe_every`` frames: one
        anyway (0: never by count)."""
        c = self.config
        if not self.mapping:
            return False
        if (
            self._since_reloc < c.keyframe_max_frames
            and len(self.map.keyframes) > c.keyframe_max_frames
        ):
            return False  # (ORB-SLAM2: not just after a relocalization)
        tracked = len(matches.keypoints)
        due = c.keyframe_every > 0 and self._since_keyframe >= c.keyframe_every
        thin = tracked < c.keyframe_ratio * self._reference_points()
        close_in = int(frame.close[matches.keypoints].sum())
        close_out = int(frame.close.sum()) - close_in
        need_close = close_in < c.close_tracked and close_out > c.close_untracked
        return (due or thin or need_close) and tracked >= c.keyframe_min_tracked

    def _reference_points(self) -> int:
        """The reference keyframe's good points seen by ``keyframe_min_observers`` keyframes
        or more (one while the map has two keyframes or fewer): ORB-SLAM2's ``nRefMatches``
        (its 3 and 2 observations, a stereo one counting twice)."""
        ref = self._reference
        if ref is None:
            return 0
        ids = ref.points[ref.points >= 0]
        ids = ids[~self.map.bad[ids]]
        least = self.config.keyframe_min_observers if len(self.map.keyframes) > 2 else 1
        return int((self.map.n_obs[ids] >= least).sum())

    def _add_keyframe(self, frame: Frame, T_C_W: Pose, matches: _Matches) -> Pose:
        """The frame as a keyframe: it observes the points it tracked, makes points of its close
        stereo keypoints that matched none, and local mapping runs; its (adjusted) pose."""
        kf = self.map.add_keyframe(T_C_W, frame)
        self.map.observe(kf, matches.keypoints, matches.points)
        fresh = frame.close.copy()
        fresh[matches.keypoints] = False
        self.map.add_points(kf, np.flatnonzero(fresh))
        self.database.add(kf)
        self._reference = kf
        self._since_keyframe = 0
        if self.config.local_mapping:
            self.last_mapping = local_mapping(
                self.map, local_keyframes=self.config.local_ba_keyframes,
                fuse=self.config.fuse_neighbours,
            )  # fmt: skip
        self._loop = self.loop_closer.after_keyframe(kf, self.map, self.database, self._fit_on)
        if self._loop is not None and self.config.global_ba:
            cfg = self.config
            global_bundle_adjustment(
                self.map, newest=cfg.global_ba_keyframes, max_held=cfg.global_ba_held
            )
        self._T_C_W_last = kf.T_C_W
        return kf.T_C_W


def _ambiguous(
    best: tuple[Pose, _Matches], fits: list[tuple[Pose, _Matches]], cfg: RelocalizationConfig
) -> bool:
    """Whether another fit keeps ``ambiguous_ratio`` of the best one's inliers with the camera
    ``ambiguous_m`` or ``ambiguous_deg`` away from it."""
    T, n = best[0].inverse(), len(best[1].keypoints)
    for other, m in fits:
        if len(m.keypoints) < cfg.ambiguous_ratio * n:
            continue
        T_o = other.inverse()
        far = np.linalg.norm(T_o.p_A_B - T.p_A_B) > cfg.ambiguous_m
        turned = np.degrees((T_o.R_A_B * T.R_A_B.inv()).magnitude()) > cfg.ambiguous_deg
        if far or turned:
            return True
    return False
