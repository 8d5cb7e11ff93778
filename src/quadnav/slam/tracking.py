"""The SLAM's tracking (ORB-SLAM2's ``Tracking``, stereo and RGB-D): the first frame with
enough stereo points starts the map at the identity; each next frame is predicted by a
constant-velocity model (or, when too few points match, where the last frame was), the map
points of the last keyframes are matched to it by projection (a window of ``search_radius_px``
times the point's scale around where it projects, the right coordinate too for stereo
keypoints, the nearest descriptor within ``max_hamming``, one map point per keypoint), its pose
is optimised on them (:mod:`quadnav.slam.optimizer`), matched again with the optimised pose
(the local map) and optimised again. Under ``min_inliers`` it is lost. A keyframe is taken on
the thesis's rules (:class:`~quadnav.slam.config.SlamConfig`) and adds map points from its close
stereo points that matched none, and local mapping runs on it
(:mod:`quadnav.slam.local_mapping`). Loop closing and relocalization after a loss are the next
parts of issue 24: until then a lost tracker stays lost.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.rotations import Pose
from quadnav.slam.config import SlamConfig
from quadnav.slam.frame import Frame
from quadnav.slam.local_mapping import LocalMappingReport, local_mapping
from quadnav.slam.map import SlamMap
from quadnav.slam.optimizer import optimize_pose

__all__ = ["StereoTracker", "TrackResult", "search_by_projection"]

FloatArray = NDArray[np.float64]
TrackState = Literal["waiting", "tracking", "lost"]


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackResult:
    """What tracking made of a frame: its ``state``, the camera's pose ``T_W_C`` (None unless
    tracking), the matches kept after the optimisation, and whether it became a keyframe."""

    t_ns: int
    state: TrackState
    T_W_C: Pose | None
    inliers: int = 0
    keyframe: bool = False


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


class StereoTracker:
    """Tracking (see the module): :meth:`track` each frame in time order."""

    def __init__(self, config: SlamConfig | None = None) -> None:
        self.config = config or SlamConfig()
        self.state: TrackState = "waiting"
        self.map = SlamMap()
        self.last_mapping: LocalMappingReport | None = None
        self._T_C_W_last: Pose | None = None
        self._velocity: Pose | None = None  # T_C_W(k) T_W_C(k-1)
        self._since_keyframe = 0
        self._ref_tracked = 0

    def track(self, frame: Frame) -> TrackResult:
        if self.state == "waiting":
            return self._initialize(frame)
        if self.state == "lost" or self._T_C_W_last is None:
            return TrackResult(t_ns=frame.t_ns, state="lost", T_W_C=None)
        last = self._T_C_W_last
        guess = last if self._velocity is None else self._velocity @ last
        fit = self._fit(frame, guess)
        if fit is None and self._velocity is not None:
            fit = self._fit(frame, last)  # (the motion changed: from where the last frame was)
        if fit is None:
            self.state = "lost"
            return TrackResult(t_ns=frame.t_ns, state="lost", T_W_C=None)
        T_C_W, matches = fit
        self._velocity = T_C_W @ last.inverse()
        self._T_C_W_last = T_C_W
        self._since_keyframe += 1
        n = len(matches.keypoints)
        keyframe = self._wants_keyframe(n)
        if keyframe:
            T_C_W = self._add_keyframe(frame, T_C_W, matches, n)
        return TrackResult(t_ns=frame.t_ns, state="tracking", T_W_C=T_C_W.inverse(), inliers=n,
                           keyframe=keyframe)  # fmt: skip

    # -- steps --------------------------------------------------------------------------------
    def _initialize(self, frame: Frame) -> TrackResult:
        if int(frame.stereo.matched.sum()) < self.config.init_min_points:
            return TrackResult(t_ns=frame.t_ns, state="waiting", T_W_C=None)
        self.state = "tracking"
        self._T_C_W_last = Pose.identity()
        idx = np.flatnonzero(frame.stereo.matched)
        self.map.add_points(self.map.add_keyframe(Pose.identity(), frame), idx)
        self._ref_tracked = len(idx)
        return TrackResult(t_ns=frame.t_ns, state="tracking", T_W_C=Pose.identity(),
                           inliers=len(idx), keyframe=True)  # fmt: skip

    def _fit(self, frame: Frame, guess: Pose) -> tuple[Pose, _Matches] | None:
        """Match and optimise twice (the guess, then the local map from the first fit)."""
        cfg = self.config
        T = guess
        for radius in (cfg.search_radius_px, cfg.search_radius_px / 3):
            m = self._match(frame, T, radius)
            if len(m.keypoints) < cfg.min_inliers:
                m = self._match(frame, T, 2 * radius)
            if len(m.keypoints) < cfg.min_inliers:
                return None
            f = frame.features
            fit = optimize_pose(
                T, self.map.X_W[m.points], f.uv_px[m.keypoints], frame.stereo.u_right[m.keypoints],
                f.scales[f.octave[m.keypoints]] ** 2,
                frame.camera.intrinsics,
            )  # fmt: skip
            T = fit.T_C_W
            m = _Matches(keypoints=m.keypoints[fit.inliers], points=m.points[fit.inliers])
            if len(m.keypoints) < cfg.min_inliers:
                return None
        return T, m

    def _match(self, frame: Frame, T_C_W: Pose, radius: float) -> _Matches:
        m = self.map
        ids = m.local_points(m.keyframes[-self.config.local_keyframes :])
        kp, j, _ = search_by_projection(
            frame, m.X_W[ids], m.descriptors[ids], m.octave[ids], T_C_W, radius,
            self.config.max_hamming,
        )  # fmt: skip
        return _Matches(keypoints=kp, points=ids[j])

    def _wants_keyframe(self, tracked: int) -> bool:
        c = self.config
        due = self._since_keyframe >= c.keyframe_max_frames
        thin = tracked < c.keyframe_ratio * self._ref_tracked
        return (due or thin) and tracked >= c.keyframe_min_tracked

    def _add_keyframe(self, frame: Frame, T_C_W: Pose, matches: _Matches, n: int) -> Pose:
        """The frame as a keyframe: it observes the points it tracked, makes points of its close
        stereo keypoints that matched none, and local mapping runs; its (adjusted) pose."""
        kf = self.map.add_keyframe(T_C_W, frame)
        self.map.observe(kf, matches.keypoints, matches.points)
        fresh = frame.close.copy()
        fresh[matches.keypoints] = False
        self.map.add_points(kf, np.flatnonzero(fresh))
        self._since_keyframe = 0
        self._ref_tracked = n  # (ORB-SLAM2: the points its reference keyframe tracks)
        if self.config.local_mapping:
            self.last_mapping = local_mapping(
                self.map, local_keyframes=self.config.local_ba_keyframes
            )
            self._T_C_W_last = kf.T_C_W
        return kf.T_C_W
