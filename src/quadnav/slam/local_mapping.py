"""The SLAM's local mapping (ORB-SLAM2's ``LocalMapping``), run after each keyframe: new map
points triangulated between the keyframe and its covisible ones from keypoints that observe none
(:func:`create_points`), the recent map points culled (a point made two or more keyframes ago
that fewer than two keyframes see: ORB-SLAM2's stereo rule, three observations or fewer with a
stereo one counting twice), the keyframe's points fused with its neighbours'
(:func:`fuse_neighbours`), then the local bundle adjustment
(:func:`~quadnav.slam.optimizer.local_bundle_adjustment`) over the newest keyframe, its most
covisible ones and the points they see, the other keyframes that see those points held; its
outlier observations are forgotten and points seen by no keyframe culled. Last, the keyframe culling: a keyframe covisible
with the newest (not the first, not the newest) whose close points are seen by at least three
other keyframes for ``redundancy`` (90 %) of them or more is culled (ORB-SLAM2's
``KeyFrameCulling``; the scale condition left out)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from quadnav.slam.map import SlamKeyframe, SlamMap
from quadnav.slam.optimizer import (
    BundleProblem,
    SelfCalibration,
    local_bundle_adjustment,
    self_calibrating_adjustment,
)

__all__ = [
    "GlobalAdjustment",
    "LocalMappingReport",
    "create_points",
    "cull_keyframes",
    "fuse_neighbours",
    "global_bundle_adjustment",
    "local_mapping",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class LocalMappingReport:
    """What one pass did: points culled, keyframes adjusted and held, observations dropped."""

    culled: int
    adjusted: int
    held: int
    dropped: int
    keyframes_culled: int = 0
    created: int = 0


def local_mapping(
    slam_map: SlamMap,
    *,
    local_keyframes: int = 5,
    min_observations: int = 2,
    max_held: int = 5,
    redundancy: float = 0.9,
    neighbours: int = 10,
    fuse: bool = True,
) -> LocalMappingReport:
    """One pass after the newest keyframe (see the module)."""
    newest = slam_map.keyframes[-1].index
    m = slam_map
    near = m.covisible(m.keyframes[-1], neighbours + 1)[1:]
    made = create_points(m, m.keyframes[-1], near)
    recent = (newest - m.first_keyframe >= 2) & (m.n_obs < min_observations) & ~m.bad
    culled = np.flatnonzero(recent)
    m.cull(culled)
    if fuse:
        fuse_neighbours(m, m.keyframes[-1], near)
    covisible = m.covisible(m.keyframes[-1], local_keyframes)
    local = sorted((kf for kf in covisible if not kf.bad), key=lambda kf: kf.index)
    if len(local) < 2:
        return LocalMappingReport(culled=len(culled), adjusted=0, held=0, dropped=0, created=made)
    pts = m.local_points(local)
    local_ids = {kf.index for kf in local}
    mark = m.marks(pts)
    held = list(itertools.islice(
        (kf for kf in reversed(m.keyframes)
         if kf.index not in local_ids and not kf.bad and mark[kf.points].any()), max_held,
    ))  # fmt: skip
    if not held:  # (the first keyframes: the oldest local one holds the frame)
        held, local = [local[0]], local[1:]
    kfs = [*held, *local]
    problem, rows = _problem(m, kfs, pts, n_held=len(held))
    out = local_bundle_adjustment(problem, kfs[0].frame.camera.intrinsics)
    for k, kf in enumerate(kfs):
        if not problem.fixed[k]:
            kf.T_C_W = out.T_W_C[k].inverse()
    m.X_W[pts] = out.X_W
    dropped = 0
    for k, kf in enumerate(kfs):
        bad = rows[k][~out.inliers[problem.obs_kf == k]]
        m.forget(kf, bad)
        dropped += len(bad)
    gone = pts[m.n_obs[pts] <= 0]
    m.cull(gone)
    n_kf = cull_keyframes(m, m.covisible(m.keyframes[-1], 20)[1:], redundancy=redundancy)
    return LocalMappingReport(culled=len(culled) + len(gone), adjusted=len(local), held=len(held),
                              dropped=dropped, keyframes_culled=n_kf, created=made)  # fmt: skip


class GlobalAdjustment(NamedTuple):
    """What :func:`global_bundle_adjustment` did: keyframes and points adjusted, and the left
    rectified camera's refined ``(fx, fy, cx, cy, fx b)`` when it estimated them (else None),
    with the rest of what it found (``calibration``: the distortion left, the rig)."""

    keyframes: int
    points: int
    intrinsics: tuple[float, float, float, float, float] | None = None
    calibration: SelfCalibration | None = None


def global_bundle_adjustment(
    m: SlamMap, *, iterations: int = 10, newest: int | None = None, intrinsics: bool = False,
    max_held: int | None = None,
) -> GlobalAdjustment:  # fmt: skip
    """ORB-SLAM2's ``GlobalBundleAdjustemnt`` after a loop: every keyframe (the first held) and
    every point they see, adjusted together (``iterations`` a pass, two passes, the second
    without the first's outliers); the map takes the result. ``newest``: only the newest so
    many keyframes and their points, the older keyframes that see those points held (a long
    run's adjustment bounded), the ``max_held`` of them that see the most of the points when
    given (the others' observations left out: in a place the run keeps coming back to, every
    older keyframe sees them). ``intrinsics``: the pair's intrinsics estimated too
    (:func:`~quadnav.slam.optimizer.self_calibrating_adjustment`; the map's camera is not
    changed: the result says them)."""
    kfs = [kf for kf in m.keyframes if not kf.bad]
    n_held = 1
    if newest is not None and len(kfs) > newest + 1:
        local = kfs[-newest:]
        pts = m.local_points(local)
        older = kfs[:-newest]
        counts = m.sharing(pts, among=older)
        seen = [i for i in np.argsort(-counts, kind="stable") if counts[i] > 0]
        held = [older[i] for i in sorted(seen[:max_held] if max_held is not None else seen)]
        if not held:
            held, local = [local[0]], local[1:]
        kfs, n_held = [*held, *local], len(held)
    else:
        pts = m.local_points(kfs)
    if len(kfs) - n_held < 1 or len(pts) == 0:
        return GlobalAdjustment(0, 0)
    problem, _ = _problem(m, kfs, pts, n_held=n_held)
    cam = kfs[0].frame.camera.intrinsics
    found = None
    if intrinsics:
        out, found = self_calibrating_adjustment(problem, cam)
    else:
        out = local_bundle_adjustment(problem, cam, iterations=iterations)
    for kf, T_W_C in zip(kfs[n_held:], out.T_W_C[n_held:], strict=True):
        kf.T_C_W = T_W_C.inverse()
    m.X_W[pts] = out.X_W
    refined = None if found is None else found.intrinsics
    return GlobalAdjustment(len(kfs) - n_held, len(pts), refined, found)


def cull_keyframes(
    m: SlamMap, candidates: list[SlamKeyframe], *, redundancy: float = 0.9, observers: int = 3
) -> int:
    """Cull the ``candidates`` (not the first keyframe) whose close points are seen by
    ``observers`` other keyframes for ``redundancy`` of them or more: they forget their points
    and are marked bad; points left unseen are culled. How many were culled."""
    n = 0
    for kf in candidates:
        if kf.bad or kf.index == 0 or kf.index == m.keyframes[-1].index:
            continue
        kp, ids = kf.observed
        sel = ~m.bad[ids] & kf.frame.close[kp]
        if not sel.any() or np.mean(m.n_obs[ids[sel]] - 1 >= observers) < redundancy:
            continue
        parents = [p for p in m.covisible(kf, 2)[1:] if not p.bad] or [
            p for p in reversed(m.keyframes[: kf.index]) if not p.bad
        ][:1]
        if parents:
            kf.parent, kf.T_C_P = parents[0].index, kf.T_C_W @ parents[0].T_C_W.inverse()
        m.forget(kf, kp)
        kf.bad = True
        n += 1
        m.cull(ids[(m.n_obs[ids] <= 0) & ~m.bad[ids]])
    return n


def _problem(
    m: SlamMap, kfs: list[SlamKeyframe], pts: np.ndarray, *, n_held: int
) -> tuple[BundleProblem, list[np.ndarray]]:
    """The adjustment's problem, and each keyframe's keypoints in its observation order."""
    where = {int(p): j for j, p in enumerate(pts)}
    kf_i, pt_i, uv, ur, s2, rows = [], [], [], [], [], []
    for k, kf in enumerate(kfs):
        kp, ids = kf.observed
        sel = np.isin(ids, pts)
        kp, ids = kp[sel], ids[sel]
        f = kf.frame.features
        kf_i.append(np.full(len(kp), k, np.int64))
        pt_i.append(np.array([where[int(i)] for i in ids], np.int64))
        uv.append(f.uv_px[kp])
        ur.append(kf.frame.stereo.u_right[kp])
        s2.append(f.scales[f.octave[kp]] ** 2)
        rows.append(kp)
    problem = BundleProblem(
        T_W_C=tuple(kf.T_C_W.inverse() for kf in kfs),
        fixed=np.arange(len(kfs)) < n_held,
        X_W=m.X_W[pts], obs_kf=np.concatenate(kf_i), obs_pt=np.concatenate(pt_i),
        obs_uv=np.concatenate(uv).reshape(-1, 2), obs_ur=np.concatenate(ur),
        obs_sigma2=np.concatenate(s2),
    )  # fmt: skip
    return problem, rows


def create_points(
    m: SlamMap,
    kf: SlamKeyframe,
    neighbours: list[SlamKeyframe],
    *,
    max_hamming: int = 50,
    ratio: float = 0.8,
    min_parallax_deg: float = 2.0,
    chi2: float = 5.991,
) -> int:
    """ORB-SLAM2's ``CreateNewMapPoints``: the keypoints of ``kf`` that observe no point,
    matched by descriptor (within ``max_hamming`` bits, ``ratio`` to the second nearest) to
    those of each neighbour that observe none, triangulated where the two rays part by
    ``min_parallax_deg`` or more, kept in front of both cameras and within the ``chi2`` gate of
    each keypoint's level (px). How many points were made."""
    from quadnav.geometry.multiview import reprojection_errors, triangulate
    from quadnav.place.verification import match_descriptors

    made = 0
    for nb in neighbours:
        if nb.bad:
            continue
        a_free, b_free = np.flatnonzero(kf.points < 0), np.flatnonzero(nb.points < 0)
        fa, fb = kf.frame.features, nb.frame.features
        ia, ib = match_descriptors(fa.descriptors[a_free], fb.descriptors[b_free],
                                   max_hamming=max_hamming, ratio=ratio)  # fmt: skip
        if len(ia) == 0:
            continue
        a, b = a_free[ia], b_free[ib]
        xa, xb = _normalised(kf, a), _normalised(nb, b)
        P = np.stack([kf.T_C_W.matrix()[:3], nb.T_C_W.matrix()[:3]])
        X, _ = triangulate(np.stack([xa, xb], axis=1), P)
        ok = np.isfinite(X).all(axis=1)
        X = np.nan_to_num(X)
        c = kf.frame.camera
        for k, (x, f, kps) in enumerate(((xa, fa, a), (xb, fb, b))):
            err, _ = reprojection_errors(P[k], X, x)
            sigma = f.scales[f.octave[kps]] / c.fx
            ok &= err**2 < chi2 * sigma**2
        ca, cb = kf.T_C_W.inverse().p_A_B, nb.T_C_W.inverse().p_A_B
        ra, rb = X - ca, X - cb
        cos = np.sum(ra * rb, axis=1) / np.maximum(
            np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1), 1e-12
        )
        ok &= cos < np.cos(np.radians(min_parallax_deg))
        if ok.any():
            m.add_triangulated((kf, nb), (a[ok], b[ok]), X[ok])
            made += int(ok.sum())
    return made


def _normalised(kf: SlamKeyframe, kps: np.ndarray) -> np.ndarray:
    c, uv = kf.frame.camera, kf.frame.features.uv_px[kps]
    return np.column_stack([(uv[:, 0] - c.cx) / c.fx, (uv[:, 1] - c.cy) / c.fy])


def fuse_neighbours(
    m: SlamMap, kf: SlamKeyframe, neighbours: list[SlamKeyframe], *, second: int = 5,
    radius_px: float = 3.0, max_hamming: int = 50,
) -> int:  # fmt: skip
    """ORB-SLAM2's ``SearchInNeighbors``: ``kf``'s points projected into its ``neighbours``
    and the ``second`` most covisible of each, and theirs into ``kf``, each fused with the
    point a keypoint there already observes (the one fewer keyframes see replaced by the
    other) or observed there. A place seen again makes its points again where tracking missed
    the old ones; fused, the map keeps one of each, its keyframes share them (covisibility,
    culling) and the adjustments join their views. How many points were fused or observed."""
    targets: dict[int, SlamKeyframe] = {}
    for nb in neighbours:
        for t in [nb, *m.covisible(nb, second + 1)[1:]]:
            if not t.bad and t.index != kf.index:
                targets.setdefault(t.index, t)
    n = 0
    for t in targets.values():
        n += _fuse_into(m, t, kf.points, radius_px=radius_px, max_hamming=max_hamming)
    theirs = np.concatenate([t.points for t in targets.values()] or [np.zeros(0, np.int64)])
    n += _fuse_into(m, kf, theirs, radius_px=radius_px, max_hamming=max_hamming)
    return n


def _fuse_into(
    m: SlamMap, kf: SlamKeyframe, ids: np.ndarray, *, radius_px: float, max_hamming: int
) -> int:
    """Points ``ids`` (not culled, not observed by ``kf`` yet) projected into ``kf`` and fused
    there (see :func:`fuse_neighbours`), within ORB-SLAM2's chi-square gate of the keypoint's
    level (5.991 for a keypoint without a right coordinate, 7.815 with one)."""
    from quadnav.slam.tracking import search_by_projection

    ids = np.unique(ids[ids >= 0])
    ids = ids[~m.bad[ids] & ~m.marks(kf.points[kf.points >= 0])[ids]]
    if len(ids) == 0:
        return 0
    kp, j, _ = search_by_projection(kf.frame, m.X_W[ids], m.descriptors[ids], m.octave[ids],
                                    kf.T_C_W, radius_px, max_hamming)  # fmt: skip
    p = ids[j]
    c, f = kf.frame.camera, kf.frame.features
    X = kf.T_C_W @ m.X_W[p]
    z = np.maximum(X[:, 2], 1e-9)
    u, v = c.fx * X[:, 0] / z + c.cx, c.fy * X[:, 1] / z + c.cy
    ur, kur = u - c.bf / z, kf.frame.stereo.u_right[kp]
    e2 = (u - f.uv_px[kp, 0]) ** 2 + (v - f.uv_px[kp, 1]) ** 2
    e2 = e2 + np.where(kur >= 0, (ur - kur) ** 2, 0.0)
    gate = np.where(kur >= 0, 7.815, 5.991) * f.scales[f.octave[kp]] ** 2
    n = 0
    for k, pt in zip(kp[e2 < gate].tolist(), p[e2 < gate].tolist(), strict=True):
        if m.bad[pt] or (kf.points == pt).any():  # (fused away, or found at another keypoint)
            continue
        q = int(kf.points[k])
        if q < 0:
            m.observe(kf, np.array([k]), np.array([pt]))
        elif m.n_obs[q] >= m.n_obs[pt]:
            m.replace(pt, q)
        else:
            m.replace(q, pt)
        n += 1
    return n
