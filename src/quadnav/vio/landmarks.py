"""The landmark life cycle of the sliding window (thesis 003 §3.3), without a solver: which
tracks enter as landmarks and with which point, which observations are new for the graph, which
landmarks go bad, and what happens to a landmark when its first keyframe is marginalised.

A track enters once seen in ``landmark_min_observations`` keyframes (or two with enough
parallax), triangulated (DLT) from the current estimates, only with a positive depth in every
view, a sane range and a small reprojection error; with a stereo rig a pair of views near enough
(``stereo_max_depth_baselines``) is enough. A landmark is anchored in its first keyframe and
leaves with it, as VINS-Mono marginalises the features anchored in its oldest frame. A track
still seen goes on as a new landmark once the observations the marginal prior does not hold yet
would make one: the old estimate is its starting value only (a prior from it would count those
observations twice and, fixed in the world, tie the window's position and yaw, which the data
cannot observe). After each solve, the landmarks behind a camera or far from their pixels are
marked bad for good: the graph drops their projections.

Everything here works on 3x4 camera matrices ``K [R_C_W | t_C_W]`` of the window's keyframes
(``K`` the correction the window has for the stated intrinsics, the identity unless
the intrinsics are refined: the observations are normalised with the stated ones) and on the
:class:`~quadnav.vio.frontend.FeatureManager`'s tracks; :mod:`quadnav.vio.window` turns what it
decides into factors.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.multiview import reprojection_errors, triangulate
from quadnav.vio.config import VioConfig
from quadnav.vio.frontend import FeatureManager

__all__ = ["Admission", "LandmarkBook", "NewLandmark", "Observation"]

FloatArray = NDArray[np.float64]
Cameras = dict[int, FloatArray]  # keyframe index -> 3x4 [R_C_W | t_C_W]
#: A track an admission looks at: its id, its views in both cameras, and its views' summary
#: (None for a landmark, whose views are all it has, those outside the window included).
_Candidate = tuple[
    int, dict[int, FloatArray], dict[int, FloatArray], tuple[int, int, int, int] | None
]
#: A view: a keyframe index, or (keyframe index, camera) for a stereo rig's two cameras.
V = TypeVar("V", bound=Hashable)


@dataclass(frozen=True, slots=True)
class NewLandmark:
    """A track that enters: its landmark's key number, first point (``W``) and the keyframe it
    is anchored in (the first of its views the marginal prior does not hold)."""

    track: int
    key: int
    point_W: FloatArray
    anchor: int


@dataclass(frozen=True, slots=True)
class Observation:
    """A projection factor to add: landmark key number, keyframe, normalised point, camera
    (0 the window's camera, 1 a stereo rig's second)."""

    key: int
    keyframe: int
    xy: FloatArray
    side: int


@dataclass(slots=True)
class Admission:
    """What a solve adds: new landmarks and the new observations of every landmark."""

    new: list[NewLandmark] = field(default_factory=list)
    observations: list[Observation] = field(default_factory=list)


def camera_centres(P: Cameras) -> dict[int, FloatArray]:
    """Each camera's centre in ``W`` from its ``K [R_C_W | t_C_W]`` (``K`` an intrinsics
    correction, or the identity)."""
    if not P:
        return {}
    Ps = np.array(list(P.values()))
    c = -np.linalg.solve(Ps[:, :, :3], Ps[:, :, 3:])[..., 0]  # each matrix as on its own
    return {k: np.asarray(ck, np.float64) for k, ck in zip(P, c, strict=True)}


def _bearing_angles(tracks: list[dict[int, FloatArray]], P: Cameras) -> FloatArray:
    """The angle (rad) between the world bearings of each track's first and last observations
    (each track seen in at least one view)."""
    if not tracks:
        return np.zeros(0)
    ends = [(min(obs), max(obs)) for obs in tracks]
    A = np.array([[P[k0][:, :3], P[k1][:, :3]] for k0, k1 in ends])  # (n, 2, 3, 3)
    x = np.array([[obs[k0], obs[k1]] for obs, (k0, k1) in zip(tracks, ends, strict=True)])
    rays = np.concatenate([x, np.ones((*x.shape[:2], 1))], axis=2)[..., None]
    b = np.linalg.solve(A, rays)[..., 0]  # (n, 2, 3)
    norms = np.linalg.norm(b, axis=2)
    c = np.einsum("ij,ij->i", b[:, 0], b[:, 1]) / (norms[:, 0] * norms[:, 1])
    out: FloatArray = np.arccos(np.clip(c, -1.0, 1.0))
    return out


def _dlt_points(
    tracks: list[dict[V, FloatArray]], P: Mapping[V, FloatArray]
) -> list[FloatArray | None]:
    """Each track's DLT point from its views (None if degenerate), triangulated together by
    number of views: the same point, to the bit, as one at a time."""
    out: list[FloatArray | None] = [None] * len(tracks)
    by_views: dict[int, list[int]] = {}
    for i, obs in enumerate(tracks):
        by_views.setdefault(len(obs), []).append(i)
    for v, idx in by_views.items():
        if v < 2:
            continue
        xy = np.array([list(tracks[i].values()) for i in idx], np.float64)
        Pm = np.array([[P[k] for k in tracks[i]] for i in idx], np.float64)
        pts, _ = triangulate(xy, Pm)
        for i, p in zip(idx, pts, strict=True):
            out[i] = p if bool(np.isfinite(p).all()) else None
    return out


@dataclass(slots=True)
class _Geometry:
    """Per track, computed for all tracks of an admission at once: its fresh views (those the
    marginal prior does not hold; in the second camera, for a track seen there), their parallax
    angle and, where it is enough to triangulate, their DLT point; with views in the second
    camera too, the DLT point of all its fresh views in both, where it may enter."""

    fresh: dict[int, dict[int, FloatArray]] = field(default_factory=dict)
    rfresh: dict[int, dict[int, FloatArray]] = field(default_factory=dict)
    angle: dict[int, float] = field(default_factory=dict)
    point: dict[int, FloatArray | None] = field(default_factory=dict)
    #: the DLT points that may enter (:meth:`LandmarkBook._triangulated`), and whether each
    #: track's seed may (:meth:`LandmarkBook._landmarks_ok` on its fresh views); the stereo
    #: points that may (:meth:`LandmarkBook._stereo_points`)
    triangulated: dict[int, FloatArray | None] = field(default_factory=dict)
    seed_ok: dict[int, bool] = field(default_factory=dict)
    stereo_point: dict[int, FloatArray | None] = field(default_factory=dict)


class LandmarkBook:
    """The window's landmarks and what it knows of each track (see the module)."""

    def __init__(self, config: VioConfig, focal_px: float, baseline_m: float = 0.0) -> None:
        self.config = config
        self.focal_px = float(focal_px)
        self.baseline_m = float(baseline_m)
        self.landmarks: dict[int, FloatArray] = {}
        self.bad_tracks: set[int] = set()
        self._seed: dict[int, FloatArray] = {}  # starting points (an initialisation's, a
        # marginalised landmark's last estimate)
        self._next_key = 0
        self.clear()

    def clear(self) -> None:
        """A new window: no landmarks, nothing in a prior (seeds stay: an initialisation's)."""
        self.landmarks = {}
        self._seen: dict[int, set[int]] = {}  # track -> keyframes with its factor in
        self._seen_r: dict[int, set[int]] = {}  # the same in the second camera
        self._key: dict[int, int] = {}  # track -> the number of its landmark's key
        self._used: dict[int, set[int]] = {}  # track -> keyframes already in the prior
        self._used_r: dict[int, set[int]] = {}  # the same in the second camera
        self._tried: dict[int, tuple[int, ...]] = {}  # track -> its views when it last failed

    def seed(self, points_W: dict[int, FloatArray]) -> None:
        """Points (an initialisation's) to start tracks from instead of triangulating them."""
        self._seed.update({int(j): np.asarray(p, np.float64) for j, p in points_W.items()})

    def key(self, track: int) -> int:
        """The key number of a track's landmark (a landmark in the window)."""
        return self._key[track]

    @property
    def sizes(self) -> dict[str, int]:
        """What is kept per track: every book must stay bounded on a long run."""
        return {
            "landmarks": len(self.landmarks), "seed": len(self._seed), "used": len(self._used),
            "bad": len(self.bad_tracks), "tried": len(self._tried),
        }  # fmt: skip

    def position(self, track: int) -> FloatArray | None:
        """Where the window puts a track's landmark (in ``W``): its estimate, or the last one
        it had when its first keyframe was marginalised; None if it has none (or a bad one)."""
        if track in self.bad_tracks:
            return None
        p = self.landmarks.get(track)
        return p if p is not None else self._seed.get(track)

    # -- admission --------------------------------------------------------------------------
    def admit(self, features: FeatureManager, P: Cameras, PR: Cameras) -> Admission:
        """New landmarks, and the observations of landmarks not in the graph yet, given the
        window's camera matrices (``PR``: the second camera's, empty for mono)."""
        out = Admission()
        todo = self._candidates(features, P, PR)
        geo = self._geometry([c for c in todo if c[3] is not None], P, PR)
        keys, seen_of, seen_r_of = self._key, self._seen, self._seen_r
        add = out.observations.append
        for j, obs, robs, views in todo:
            if views is not None:  # not a landmark yet
                new = self._enter(j, P, PR, geo)
                if new is None:
                    self._tried[j] = views
                    continue
                self._tried.pop(j, None)
                out.new.append(new)
            key, seen = keys[j], seen_of[j]
            for k, xy in obs.items():
                if k not in seen and k in P:
                    add(Observation(key, k, xy, 0))
                    seen.add(k)
            seen_r = seen_r_of.setdefault(j, set())
            for k, xy in robs.items():
                if k not in seen_r and k in PR:
                    add(Observation(key, k, xy, 1))
                    seen_r.add(k)
        return out

    def _candidates(self, features: FeatureManager, P: Cameras, PR: Cameras) -> list[_Candidate]:
        """The tracks an admission looks at, in the feature manager's order: the landmarks (with
        all their views: the admission takes those in the window's keyframes), and the tracks
        not bad with views they have not failed to enter with (their views in the window's
        keyframes, both cameras, and what the book remembers them by)."""
        right, bad, landmarks, tried = features.right, self.bad_tracks, self.landmarks, self._tried
        none: dict[int, FloatArray] = {}
        out: list[_Candidate] = []
        for j, obs_all in features.tracks.items():
            if j in bad:
                continue
            r = right.get(j, none)
            if j in landmarks:
                out.append((j, obs_all, r, None))
                continue
            views = (max(obs_all, default=-1), len(obs_all), *((max(r), len(r)) if r else (-1, 0)))
            if tried.get(j) == views:
                continue  # it could not enter with these views: it waits for another
            obs = {k: xy for k, xy in obs_all.items() if k in P}
            robs = {k: xy for k, xy in r.items() if k in PR} if r else none
            out.append((j, obs, robs, views))
        return out

    def _geometry(self, tracks: list[_Candidate], P: Cameras, PR: Cameras) -> _Geometry:
        """The views of the tracks the marginal prior does not hold (their fresh views), their
        parallax, and the DLT point of those with enough; the DLT point of the fresh views in
        both cameras of those seen in the second."""
        geo = _Geometry()
        used_of, used_r_of = self._used, self._used_r
        mono: list[tuple[int, dict[int, FloatArray]]] = []
        both: list[tuple[int, dict[tuple[int, int], FloatArray]]] = []
        for j, obs, robs, _ in tracks:
            used = used_of.get(j)
            fresh = {k: xy for k, xy in obs.items() if k not in used} if used else obs
            geo.fresh[j] = fresh
            if len(fresh) >= 2:
                mono.append((j, fresh))
            if robs:
                used_r = used_r_of.get(j)
                rfresh = {k: xy for k, xy in robs.items() if k not in used_r} if used_r else robs
                geo.rfresh[j] = rfresh
                if rfresh:
                    views = {(k, 0): xy for k, xy in fresh.items()}
                    both.append((j, views | {(k, 1): xy for k, xy in rfresh.items()}))
        angles = _bearing_angles([f for _, f in mono], P)
        geo.angle = {j: float(a) for (j, _), a in zip(mono, angles, strict=True)}
        enough = [(j, f) for j, f in mono if geo.angle[j] >= self._parallax_needed(len(f))]
        points = _dlt_points([f for _, f in enough], P)
        geo.point = {j: p for (j, _), p in zip(enough, points, strict=True)}
        geo.triangulated = self._triangulated(enough, P, geo)
        seeded = [(j, self._seed[j], f) for j, f in geo.fresh.items() if f and j in self._seed]
        ok = self._landmarks_ok([(p, f) for _, p, f in seeded], P)
        geo.seed_ok = {j: bool(good) for (j, _, _), good in zip(seeded, ok, strict=True)}
        if both:
            Pv = {(k, 0): Pk for k, Pk in P.items()} | {(k, 1): Pk for k, Pk in PR.items()}
            geo.stereo_point = self._stereo_points(both, Pv, _dlt_points([v for _, v in both], Pv))
        return geo

    def _enter(
        self,
        j: int,
        P: Cameras,
        PR: Cameras,
        geo: _Geometry,
    ) -> NewLandmark | None:
        """A track's landmark if it may enter (from its fresh views, which :meth:`_geometry`
        found: a track whose landmark was marginalised enters again as a new track would, no
        prior from the old estimate)."""
        used = self._used.get(j)
        fresh, rfresh = geo.fresh[j], geo.rfresh.get(j)
        mono = len(fresh) >= 2 and (not used or self._enough_parallax(j, fresh, geo))
        if not mono and not rfresh:
            return None
        p = self._seed.get(j)
        if p is None or not geo.seed_ok.get(j, False):
            p = geo.triangulated.get(j) if mono else None
        if p is None and rfresh:
            p = geo.stereo_point[j]
        if p is None:
            return None
        self._seed.pop(j, None)
        self.landmarks[j] = p
        self._seen[j] = set(used or ())  # already in the prior: not again
        self._seen_r[j] = set(self._used_r.get(j, ()))
        self._key[j] = self._next_key
        self._next_key += 1
        return NewLandmark(track=j, key=self._key[j], point_W=p, anchor=min(fresh))

    def _parallax_needed(self, views: int) -> float:
        """The angle (rad) between a track's first and last views it needs to enter."""
        cfg = self.config
        px = 3.0 if views >= cfg.landmark_min_observations else cfg.landmark_min_parallax_px
        return px / cfg.parallax_focal_px

    def _enough_parallax(self, j: int, fresh: dict[int, FloatArray], geo: _Geometry) -> bool:
        """Track ``j``'s fresh views (those :meth:`_geometry` measured) are far enough apart."""
        return len(fresh) >= 2 and geo.angle[j] >= self._parallax_needed(len(fresh))

    def _triangulated(
        self, tracks: list[tuple[int, dict[int, FloatArray]]], P: Cameras, geo: _Geometry
    ) -> dict[int, FloatArray | None]:
        """Each track's DLT point (``geo.point``) from its fresh views if it may enter: the
        angle between its first view's ray to the point and another's at least the parallax it
        needs, in front, near its pixels; together by number of views."""
        centres = camera_centres(P)
        out: dict[int, FloatArray | None] = {}
        found: list[tuple[int, FloatArray, dict[int, FloatArray]]] = []
        for j, fresh in tracks:
            p = geo.point[j]
            if p is None or not np.isfinite(p).all():
                out[j] = None
            else:
                found.append((j, p, fresh))
        by_views: dict[int, list[int]] = {}
        for i, (_, _, fresh) in enumerate(found):
            by_views.setdefault(len(fresh), []).append(i)
        seen = np.zeros(len(found), dtype=bool)
        for idx in by_views.values():
            pts = np.array([found[i][1] for i in idx])
            rays = pts[:, None, :] - np.array([[centres[k] for k in found[i][2]] for i in idx])
            norms = np.linalg.norm(rays, axis=2)  # (tracks, views)
            with np.errstate(divide="ignore", invalid="ignore"):
                cos = np.einsum("nj,nvj->nv", rays[:, 0], rays[:, 1:]) / (
                    norms[:, :1] * norms[:, 1:]
                )
            angle = np.arccos(np.clip(cos.min(axis=1), -1.0, 1.0))
            need = np.array([self._parallax_needed(len(found[i][2])) for i in idx])
            seen[idx] = (norms.min(axis=1) >= 1e-9) & (angle >= need)
        ok = self._landmarks_ok([(p, f) for _, p, f in found], P) & seen
        out.update({j: p if good else None for (j, p, _), good in zip(found, ok, strict=True)})
        return out

    def _landmarks_ok(
        self, points: list[tuple[FloatArray, dict[int, FloatArray]]], P: Cameras
    ) -> NDArray[np.bool_]:
        """Each point in front of every camera it was seen in (its views, at least one) at a
        sane range and near every pixel it was seen at; together by number of views."""
        cfg = self.config
        ok = np.zeros(len(points), dtype=bool)
        by_views: dict[int, list[int]] = {}
        for i, (_, obs) in enumerate(points):
            by_views.setdefault(len(obs), []).append(i)
        for idx in by_views.values():
            Ps = np.array([[P[k] for k in points[i][1]] for i in idx])  # (n, views, 3, 4)
            pts = np.array([points[i][0] for i in idx])[:, None, :]
            xy = np.array([list(points[i][1].values()) for i in idx])
            err, z = reprojection_errors(Ps, pts, xy)
            ok[idx] = (
                (z >= cfg.landmark_min_depth_m).all(axis=1)
                & (z <= cfg.landmark_max_depth_m).all(axis=1)
                & (err * self.focal_px <= cfg.max_reprojection_px).all(axis=1)
            )
        return ok

    def _stereo_points(
        self,
        tracks: list[tuple[int, dict[tuple[int, int], FloatArray]]],
        Pv: dict[tuple[int, int], FloatArray],
        points: list[FloatArray | None],
    ) -> dict[int, FloatArray | None]:
        """Each track's DLT point from its fresh views in both cameras (a stereo pair is
        enough) if it may enter: within ``stereo_max_depth_baselines`` of a camera that sees it
        in stereo, in front of every view and near every pixel; together by number of views."""
        cfg = self.config
        far = min(cfg.landmark_max_depth_m, cfg.stereo_max_depth_baselines * self.baseline_m)
        out: dict[int, FloatArray | None] = {j: None for j, _ in tracks}
        found = [(j, p, v) for (j, v), p in zip(tracks, points, strict=True) if p is not None]
        by_views: dict[int, list[int]] = {}
        for i, (_, _, views) in enumerate(found):
            by_views.setdefault(len(views), []).append(i)
        for idx in by_views.values():
            group = [found[i] for i in idx]
            err, z = reprojection_errors(
                np.array([[Pv[v] for v in views] for _, _, views in group]),
                np.array([p for _, p, _ in group])[:, None, :],
                np.array([list(views.values()) for _, _, views in group]),
            )
            # the second camera's views whose keyframe's first camera saw the track too
            pair = np.array(
                [[c == 1 and (k, 0) in views for k, c in views] for _, _, views in group]
            )
            ok = np.asarray(
                (pair & (z <= far)).any(axis=1)
                & (z >= cfg.landmark_min_depth_m).all(axis=1)
                & (err * self.focal_px <= cfg.max_reprojection_px).all(axis=1),
                dtype=bool,
            )
            out.update({j: p for (j, p, _), good in zip(group, ok, strict=True) if good})
        return out

    # -- after a solve ----------------------------------------------------------------------
    def read_back(
        self, estimate: Callable[[int], FloatArray | None], features: FeatureManager
    ) -> None:
        """The solved points in (``estimate(key)``, None once marginalised); a landmark
        marginalised with its first keyframe goes on as a track to enter again, from the
        observations the prior does not hold yet; ended tracks leave every book."""
        for j in list(self.landmarks):
            p = estimate(self._key[j])
            if p is not None:
                self.landmarks[j] = p
                continue
            self._seed[j] = self.landmarks.pop(j)
            self._used[j] = self._seen.pop(j)
            self._used_r[j] = self._seen_r.pop(j, set())
            del self._key[j]
        for j in [j for j in self._used if j not in features.tracks]:
            del self._used[j]
            self._used_r.pop(j, None)
            self._seed.pop(j, None)
        self.bad_tracks.intersection_update(features.tracks)  # an ended track's verdict goes
        for j in [j for j in self._tried if j not in features.tracks]:
            del self._tried[j]

    def mark_bad(self, features: FeatureManager, P: Cameras, PR: Cameras) -> set[int]:
        """The landmarks behind or too near or far from a camera, or too far from a pixel, in
        the views they have projection factors in (either camera), marked bad for good: the
        key numbers whose projections the graph must drop."""
        cfg = self.config
        # the views as rows of one stack of camera matrices, the landmarks as rows of another
        rows = ({k: i for i, k in enumerate(P)}, {k: len(P) + i for i, k in enumerate(PR)})
        none: dict[int, FloatArray] = {}
        owner = [j for j in self.landmarks if j not in self.bad_tracks]
        owners: list[int] = []
        cams: list[int] = []
        meas: list[FloatArray] = []
        for side, book, held_of in (
            (0, features.tracks, self._used),
            (1, features.right, self._used_r),
        ):
            row = rows[side]
            if not row:
                continue
            for i, j in enumerate(owner):
                held = held_of.get(j)
                for k, xy in book.get(j, none).items():
                    c = row.get(k)
                    if c is not None and (not held or k not in held):
                        owners.append(i)
                        cams.append(c)
                        meas.append(xy)
        if not owners:
            return set()
        stack = np.array([*P.values(), *PR.values()])
        pts = np.array([self.landmarks[j] for j in owner])[owners]
        e, z = reprojection_errors(stack[cams], pts, np.array(meas))
        wrong = ~(
            (z >= cfg.landmark_min_depth_m)
            & (z <= cfg.landmark_max_depth_m)
            & (e * self.focal_px <= cfg.max_reprojection_px)
        )
        bad = {owner[owners[i]] for i in np.flatnonzero(wrong)}
        self.bad_tracks.update(bad)
        return {self._key[j] for j in bad}
