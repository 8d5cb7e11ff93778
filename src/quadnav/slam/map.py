"""The SLAM's map: map points (position, descriptor, the level first seen at, the keyframe that
made them, how many keyframes observe them, whether culled) and keyframes (their pose, frame
and, per keypoint, the map point it observes or -1); which keyframes see the same points (the
covisibility of ORB-SLAM2, counted when asked from each point's observers); and the map as
arrays for a file (:mod:`quadnav.io.slam_map`), format ``quadnav-slam-map`` version 1:

- the head: ``format``, ``version``, the numbers of ``keyframes`` and ``points``, and the
  rectified ``camera`` (fx, fy, cx, cy in px, ``baseline_m``) every keyframe was measured in;
- the points: ``X_W`` (m, the map's frame: the first keyframe's rectified left camera),
  ``descriptors`` (32 bytes), ``octave``, ``first_keyframe``, ``n_obs``, ``bad``;
- the keyframes: ``kf_t_ns``, ``kf_T_C_W`` (4x4), ``kf_n`` (keypoints each), ``kf_bad``
  (culled), and their keypoints
  concatenated: ``kp_uv_px``, ``kp_octave``, ``kp_angle_deg``, ``kp_response``, ``kp_size_px``,
  ``kp_descriptors``, ``kp_u_right``, ``kp_depth_m``, ``kp_close``, ``kp_point`` (the map point
  or -1); ``scales`` (the pyramid's).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import SlamError
from quadnav.geometry.rotations import Pose
from quadnav.slam.frame import Frame, StereoCamera
from quadnav.vision.orb import OrbFeatures
from quadnav.vision.stereo_match import StereoKeypoints

__all__ = ["SLAM_MAP_FORMAT", "SLAM_MAP_VERSION", "SlamKeyframe", "SlamMap", "pose_now"]

SLAM_MAP_FORMAT = "quadnav-slam-map"
SLAM_MAP_VERSION = 1
_KP = ("uv_px", "octave", "angle_deg", "response", "size_px", "descriptors")

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(slots=True)
class SlamKeyframe:
    """A keyframe: its ``index``, the camera's pose ``T_C_W``, its ``frame`` and ``points``
    (per keypoint: the map point it observes, -1 for none); ``bad``: culled (it observes
    nothing; its index stays taken), then ``parent`` is the keyframe it follows and ``T_C_P``
    its pose in that one's camera (ORB-SLAM2's spanning tree, for :meth:`pose_now`)."""

    index: int
    T_C_W: Pose
    frame: Frame
    points: IntArray
    bad: bool = False
    parent: int = -1
    T_C_P: Pose | None = None

    @property
    def observed(self) -> tuple[IntArray, IntArray]:
        """(keypoints, map points) of its observations."""
        kp = np.flatnonzero(self.points >= 0)
        return kp, self.points[kp]


def pose_now(kf: SlamKeyframe, keyframes: list[SlamKeyframe]) -> Pose:
    """``kf``'s ``T_C_W`` as the map has it now: a culled keyframe's through its parents (their
    poses move on with the map, its own no longer does)."""
    T = Pose.identity()
    while kf.bad and kf.parent >= 0 and kf.T_C_P is not None:
        T = T @ kf.T_C_P
        kf = keyframes[kf.parent]
    return T @ kf.T_C_W


class _Observations:
    """Which keyframes observe each map point (ORB-SLAM2's ``MapPoint::mObservations``): an
    append-only log of (keyframe, keypoint) entries linked per point (``head``, ``nxt``). An
    entry stands while that keyframe's keypoint still observes that point, so forgetting,
    culling and fusing need not touch the log; it is read through :meth:`SlamMap.observers`."""

    def __init__(self) -> None:
        self.head = np.full(0, -1, np.int64)
        self.kf = np.zeros(0, np.int32)
        self.kp = np.zeros(0, np.int32)
        self.nxt = np.zeros(0, np.int64)
        self.n = 0

    def add(self, k: int, kps: IntArray, ids: IntArray, n_points: int) -> None:
        """Keyframe ``k`` observes points ``ids`` at keypoints ``kps``."""
        if len(self.head) < n_points:
            self.head = np.r_[self.head, np.full(n_points - len(self.head), -1, np.int64)]
        m = len(ids)
        if m == 0:
            return
        if self.n + m > len(self.kf):
            cap = max(2 * len(self.kf), self.n + m, 1024)
            self.kf, self.kp, self.nxt = (np.r_[a, np.zeros(cap - len(a), a.dtype)]
                                          for a in (self.kf, self.kp, self.nxt))  # fmt: skip
        e = np.arange(self.n, self.n + m, dtype=np.int64)
        self.kf[e], self.kp[e] = k, kps
        order = np.argsort(ids, kind="stable")  # (a point twice in one call: chained in order)
        sp, se = ids[order], e[order]
        first = np.r_[True, sp[1:] != sp[:-1]]
        self.nxt[se] = np.where(first, self.head[sp], np.r_[-1, se[:-1]])
        last = np.r_[sp[1:] != sp[:-1], True]
        self.head[sp[last]] = se[last]
        self.n += m

    def entries(self, ids: IntArray) -> tuple[IntArray, IntArray, IntArray]:
        """Every entry of points ``ids``, standing or not: (keyframe, keypoint, point)."""
        cur, ps = self.head[ids], ids
        es, pts = [], []
        while True:
            sel = cur >= 0
            cur, ps = cur[sel], ps[sel]
            if not len(cur):
                break
            es.append(cur)
            pts.append(ps)
            cur = self.nxt[cur]
        if not es:
            empty = np.zeros(0, np.int64)
            return empty, empty, empty
        e = np.concatenate(es)
        return self.kf[e].astype(np.int64), self.kp[e].astype(np.int64), np.concatenate(pts)


class SlamMap:
    """Map points in growing arrays (ids are indices, never reused) and the keyframes."""

    def __init__(self) -> None:
        self._obs = _Observations()
        self.X_W = np.zeros((0, 3))
        self.descriptors = np.zeros((0, 32), np.uint8)
        self.octave = np.zeros(0, np.int64)
        self.first_keyframe = np.zeros(0, np.int64)
        self.n_obs = np.zeros(0, np.int64)
        self.bad = np.zeros(0, bool)
        self.keyframes: list[SlamKeyframe] = []

    def __len__(self) -> int:
        return int((~self.bad).sum())

    def add_keyframe(self, T_C_W: Pose, frame: Frame) -> SlamKeyframe:
        kf = SlamKeyframe(index=len(self.keyframes), T_C_W=T_C_W, frame=frame,
                          points=np.full(len(frame), -1, np.int64))  # fmt: skip
        self.keyframes.append(kf)
        return kf

    def add_points(self, kf: SlamKeyframe, kps: IntArray) -> IntArray:
        """New map points from keyframe ``kf``'s keypoints ``kps`` (with a depth), observed there."""
        kps = np.asarray(kps, np.int64)
        ids = np.arange(len(self.X_W), len(self.X_W) + len(kps), dtype=np.int64)
        X = kf.T_C_W.inverse() @ kf.frame.points_C(kps) if len(kps) else np.zeros((0, 3))
        f = kf.frame.features
        self.X_W = np.vstack([self.X_W, X])
        self.descriptors = np.vstack([self.descriptors, f.descriptors[kps]])
        self.octave = np.r_[self.octave, f.octave[kps]]
        self.first_keyframe = np.r_[self.first_keyframe, np.full(len(kps), kf.index, np.int64)]
        self.n_obs = np.r_[self.n_obs, np.zeros(len(kps), np.int64)]
        self.bad = np.r_[self.bad, np.zeros(len(kps), bool)]
        self.observe(kf, kps, ids)
        return ids

    def add_triangulated(
        self, kfs: tuple[SlamKeyframe, SlamKeyframe], kps: tuple[IntArray, IntArray],
        X_W: FloatArray,
    ) -> IntArray:  # fmt: skip
        """New map points at ``X_W`` (M, 3), each seen by the two keyframes ``kfs`` at their
        keypoints ``kps``; made by the first (its descriptor and level)."""
        kf, other = kfs
        a, b = (np.asarray(k, np.int64) for k in kps)
        ids = np.arange(len(self.X_W), len(self.X_W) + len(a), dtype=np.int64)
        f = kf.frame.features
        self.X_W = np.vstack([self.X_W, np.asarray(X_W, np.float64).reshape(-1, 3)])
        self.descriptors = np.vstack([self.descriptors, f.descriptors[a]])
        self.octave = np.r_[self.octave, f.octave[a]]
        self.first_keyframe = np.r_[self.first_keyframe, np.full(len(a), kf.index, np.int64)]
        self.n_obs = np.r_[self.n_obs, np.zeros(len(a), np.int64)]
        self.bad = np.r_[self.bad, np.zeros(len(a), bool)]
        self.observe(kf, a, ids)
        self.observe(other, b, ids)
        return ids

    def observe(self, kf: SlamKeyframe, kps: IntArray, ids: IntArray) -> None:
        """Keyframe ``kf`` sees map points ``ids`` at its keypoints ``kps``."""
        kps = np.asarray(kps, np.int64)
        ids = np.broadcast_to(np.asarray(ids, np.int64), kps.shape)
        kf.points[kps] = ids
        np.add.at(self.n_obs, ids, 1)
        self._obs.add(kf.index, kps, ids, len(self.X_W))

    def replace(self, dup: int, keep: int) -> None:
        """Point ``dup`` is point ``keep`` seen again: every keyframe that observes ``dup``
        observes ``keep`` there instead (or forgets it, when it sees ``keep`` already), and
        ``dup`` is culled (ORB-SLAM2's ``MapPoint::Replace``)."""
        ks, hits, _ = self.observers(np.array([dup]))
        for k in np.unique(ks):
            other, hit = self.keyframes[int(k)], hits[ks == k]
            if (other.points == keep).any():
                self.forget(other, hit)
            else:
                self.observe(other, hit, np.full(len(hit), keep))
                self.n_obs[dup] -= len(hit)
        self.bad[dup] = True

    def observers(self, ids: IntArray) -> tuple[IntArray, IntArray, IntArray]:
        """Who observes the points ``ids`` now: (keyframe index, keypoint, point) per
        observation, each once."""
        ids = np.unique(np.asarray(ids, np.int64))
        k, kp, p = self._obs.entries(ids[(ids >= 0) & (ids < len(self.X_W))])
        if not len(k):
            return k, kp, p
        now = np.empty(len(k), np.int64)
        order = np.argsort(k, kind="stable")
        bounds = np.flatnonzero(np.r_[True, k[order][1:] != k[order][:-1], True])
        for a, b in itertools.pairwise(bounds.tolist()):
            sl = order[a:b]
            now[sl] = self.keyframes[int(k[sl[0]])].points[kp[sl]]
        keep = now == p
        k, kp, p = k[keep], kp[keep], p[keep]
        _, first = np.unique(k * (1 << 32) + kp, return_index=True)
        return k[first], kp[first], p[first]

    def forget(self, kf: SlamKeyframe, kps: IntArray) -> None:
        """Keyframe ``kf`` no longer sees the points at its keypoints ``kps`` (outliers)."""
        ids = kf.points[kps]
        ids = ids[ids >= 0]
        np.subtract.at(self.n_obs, ids, 1)
        kf.points[kps] = -1

    def cull(self, ids: IntArray) -> None:
        """Points ``ids`` are bad: no keyframe keeps them."""
        if len(ids) == 0:
            return
        self.bad[ids] = True
        k, kp, _ = self.observers(ids)
        for i in np.unique(k):
            self.keyframes[int(i)].points[kp[k == i]] = -1

    def marks(self, ids: IntArray) -> NDArray[np.bool_]:
        """A flag per map point, set at ``ids``, and one more (unset) at the end, so that a
        keyframe's ``points`` index it directly (its -1, no point, reads the unset one)."""
        mark = np.zeros(len(self.X_W) + 1, bool)
        mark[np.asarray(ids, np.int64)] = True
        return mark

    def local_points(self, keyframes: list[SlamKeyframe]) -> IntArray:
        """The good map points these keyframes observe."""
        ids = np.unique(
            np.concatenate(
                [kf.points[kf.points >= 0] for kf in keyframes] or [np.zeros(0, np.int64)]
            )
        )
        return np.asarray(ids[~self.bad[ids]], np.int64)

    def sharing(self, ids: IntArray, *, among: list[SlamKeyframe] | None = None) -> IntArray:
        """How many of the points ``ids`` each keyframe (of ``among``; default all) observes."""
        k, _, _ = self.observers(ids)
        counts = np.bincount(k, minlength=len(self.keyframes)).astype(np.int64)
        if among is None:
            return counts
        return counts[np.array([kf.index for kf in among], np.int64)]

    def covisible(self, kf: SlamKeyframe, n: int) -> list[SlamKeyframe]:
        """``kf`` and the ``n - 1`` keyframes that share the most of its points with it (ORB-
        SLAM2's covisibility), most first; those sharing none left out."""
        _, ids = kf.observed
        counts = self.sharing(ids[~self.bad[ids]])
        counts[kf.index] = -1
        order = [int(i) for i in np.argsort(-counts, kind="stable")[: max(n - 1, 0)]]
        return [kf, *(self.keyframes[i] for i in order if counts[i] > 0)]

    def nbytes(self) -> int:
        """The bytes the map's arrays hold: its points' (position, descriptor, level, maker,
        observers, culled) and its keyframes' (each keypoint's position, level, angle, score,
        size, descriptor, right coordinate, depth, closeness and point), not counting the
        objects around them."""
        points = (
            self.X_W,
            self.descriptors,
            self.octave,
            self.first_keyframe,
            self.n_obs,
            self.bad,
        )
        total = sum(a.nbytes for a in points)
        for kf in self.keyframes:
            f, st = kf.frame.features, kf.frame.stereo
            arrays = (f.uv_px, f.octave, f.angle_deg, f.response, f.size_px, f.descriptors,
                      st.u_right, st.depth_m, kf.frame.close, kf.points)  # fmt: skip
            total += sum(np.asarray(a).nbytes for a in arrays)
        return int(total)

    # -- as arrays, for a file -----------------------------------------------------------------
    def to_arrays(self, camera: StereoCamera) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """The head and arrays of the map (see the module)."""
        if not self.keyframes:
            raise SlamError("the map has no keyframe yet: nothing to save")
        kfs = self.keyframes
        head = {
            "format": SLAM_MAP_FORMAT, "version": SLAM_MAP_VERSION, "keyframes": len(kfs),
            "points": len(self), "camera": {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx,
                                             "cy": camera.cy, "baseline_m": camera.baseline_m},
        }  # fmt: skip
        arrays: dict[str, np.ndarray] = {
            "X_W": self.X_W, "descriptors": self.descriptors, "octave": self.octave,
            "first_keyframe": self.first_keyframe, "n_obs": self.n_obs, "bad": self.bad,
            "kf_t_ns": np.array([kf.frame.t_ns for kf in kfs], np.int64),
            "kf_T_C_W": np.stack([kf.T_C_W.matrix() for kf in kfs]),
            "kf_n": np.array([len(kf.frame) for kf in kfs], np.int64),
            "kf_bad": np.array([kf.bad for kf in kfs], bool),
            "kp_u_right": np.concatenate([kf.frame.stereo.u_right for kf in kfs]),
            "kp_depth_m": np.concatenate([_depth_in(kf.frame, camera) for kf in kfs]),
            "kp_close": np.concatenate([kf.frame.close for kf in kfs]),
            "kp_point": np.concatenate([kf.points for kf in kfs]),
            "scales": kfs[0].frame.features.scales,
        }  # fmt: skip
        for name in _KP:
            arrays[f"kp_{name}"] = np.concatenate([getattr(kf.frame.features, name) for kf in kfs])
        return head, arrays

    @classmethod
    def from_arrays(
        cls, head: dict[str, Any], arrays: dict[str, np.ndarray]
    ) -> tuple[SlamMap, StereoCamera]:
        """The map and the camera of :meth:`to_arrays`' output; a missing or inconsistent
        array is a :class:`SlamError`."""
        try:
            return _from_arrays(cls(), head, arrays)
        except (KeyError, ValueError, TypeError, IndexError) as exc:
            raise SlamError(
                f"the map's arrays are inconsistent ({type(exc).__name__}: {exc})"
            ) from None


def _depth_in(frame: Frame, camera: StereoCamera) -> NDArray[np.float64]:
    """A frame's keypoint depths in ``camera``: a stereo depth is ``fx b`` over the
    disparity, so a map saved in another focal length (a self-calibrated one) scales them."""
    d = frame.stereo.depth_m
    if camera.bf == frame.camera.bf:
        return d
    return np.where(d > 0, d * (camera.bf / frame.camera.bf), d)


def _from_arrays(
    m: SlamMap, head: dict[str, Any], a: dict[str, np.ndarray]
) -> tuple[SlamMap, StereoCamera]:
    c = head["camera"]
    camera = StereoCamera(fx=float(c["fx"]), fy=float(c["fy"]), cx=float(c["cx"]),
                          cy=float(c["cy"]), baseline_m=float(c["baseline_m"]))  # fmt: skip
    n_pts = len(a["X_W"])
    m.X_W = np.asarray(a["X_W"], np.float64).reshape(n_pts, 3)
    m.descriptors = np.asarray(a["descriptors"], np.uint8).reshape(n_pts, 32)
    for name, dtype in (("octave", np.int64), ("first_keyframe", np.int64), ("n_obs", np.int64),
                        ("bad", bool)):  # fmt: skip
        arr = np.asarray(a[name], dtype)
        if arr.shape != (n_pts,):
            raise ValueError(f"{name} has {arr.shape}, the map {n_pts} points")
        setattr(m, name, arr)
    if not np.isfinite(m.X_W).all():
        raise ValueError("X_W is not finite")
    ends = np.cumsum(np.r_[0, a["kf_n"]])
    if ends[-1] != len(a["kp_point"]) or len(a["kf_t_ns"]) != len(a["kf_n"]):
        raise ValueError("the keyframes' keypoint counts do not add up")
    if np.any(a["kp_point"] >= n_pts):
        raise ValueError("a keypoint observes a point the map has not")
    bad = np.asarray(a.get("kf_bad", np.zeros(len(a["kf_n"]), bool)), bool)
    for k, T in enumerate(np.asarray(a["kf_T_C_W"], np.float64)):
        sl = slice(int(ends[k]), int(ends[k + 1]))
        kp = {name: np.asarray(a[f"kp_{name}"][sl]) for name in _KP}
        features = OrbFeatures(scales=np.asarray(a["scales"], np.float64), **kp)
        stereo = StereoKeypoints(u_right=np.asarray(a["kp_u_right"][sl], np.float64),
                                 depth_m=np.asarray(a["kp_depth_m"][sl], np.float64))  # fmt: skip
        frame = Frame(t_ns=int(a["kf_t_ns"][k]), features=features, stereo=stereo,
                      close=np.asarray(a["kp_close"][sl], bool), camera=camera)  # fmt: skip
        points = np.asarray(a["kp_point"][sl], np.int64)
        m.keyframes.append(SlamKeyframe(index=k, T_C_W=Pose.from_matrix(T), frame=frame,
                                        points=points.copy(), bad=bool(bad[k])))  # fmt: skip
        seen = np.flatnonzero(points >= 0)
        m._obs.add(k, seen, points[seen], n_pts)
    return m, camera
