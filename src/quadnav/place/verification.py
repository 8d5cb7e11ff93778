"""Geometric verification of a recognised place (VINS-Mono's and DLoopDetector's checks): a
candidate that the vocabulary ranked high becomes a loop only when the two keyframes' features
agree in geometry.

1. **Descriptor matches**: each of the old keyframe's keypoints that carries a landmark is matched
   to the query keyframe's described keypoints by Hamming distance (OpenCV's brute force),
   kept when the best is within ``max_hamming`` bits and clearly better than the second best
   (``ratio``), and when no other old keypoint claims the same query keypoint.
2. **2-D to 2-D**: a fundamental matrix by RANSAC (OpenCV) on the matched normalised
   coordinates, scaled by the focal length so that the threshold is in pixels.
3. **3-D to 2-D**: the old keyframe's landmarks (in its odometry's world) against the query's
   normalised coordinates, PnP by RANSAC (:func:`quadnav.geometry.multiview.pnp`): the query
   body's pose in the old keyframe's world.
4. **Sanity** (VINS-Mono: 30 degrees, 20 m): the query's pose so found must be within
   ``max_yaw_deg`` of heading and ``max_translation_m`` of the old keyframe; a place seen from
   the other side of the room is a different view of it, not a loop to close.

At least ``min_inliers`` (VINS-Mono: 25) must survive each of steps 2 and 3. Every rejection says
at which step, so that a run can count them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import PlaceError
from quadnav.geometry.multiview import pnp, pnp_covariance
from quadnav.geometry.rotations import Pose, yaw_of
from quadnav.odometry import KeyframeRecord

__all__ = ["LoopMatch", "Verification", "VerificationConfig", "match_descriptors", "verify_place"]

IntArray = NDArray[np.int64]

Stage = Literal["accepted", "descriptors", "matches", "fundamental", "pnp", "sanity"]


@dataclass(frozen=True, slots=True, kw_only=True)
class VerificationConfig:
    """When a recognised place counts as a loop (VINS-Mono's values where it has them):
    descriptor matches within ``max_hamming`` bits and at most ``ratio`` times the second best;
    RANSAC thresholds of the fundamental matrix and of the PnP (px); ``min_inliers`` each
    geometric step must keep; the query's heading within ``max_yaw_deg`` and its position within
    ``max_translation_m`` of the old keyframe; RANSAC's ``seed`` (verification is repeatable).
    A plain validated dataclass until a command takes it with ``--set``."""

    max_hamming: int = 80
    ratio: float = 0.9
    fundamental_threshold_px: float = 3.0
    pnp_threshold_px: float = 8.0
    min_inliers: int = 25
    max_yaw_deg: float = 30.0
    max_translation_m: float = 20.0
    seed: int = 0

    def __post_init__(self) -> None:
        checks = (
            ("max_hamming", 1 <= self.max_hamming <= 256),
            ("ratio", 0.0 < self.ratio <= 1.0),
            ("fundamental_threshold_px", 0.0 < self.fundamental_threshold_px <= 50.0),
            ("pnp_threshold_px", 0.0 < self.pnp_threshold_px <= 50.0),
            ("min_inliers", 8 <= self.min_inliers <= 10_000),
            ("max_yaw_deg", 0.0 < self.max_yaw_deg <= 180.0),
            ("max_translation_m", 0.0 < self.max_translation_m <= 1e4),
            ("seed", self.seed >= 0),
        )
        for name, ok in checks:
            if not ok:
                raise PlaceError(
                    f"VerificationConfig.{name} is out of range: {getattr(self, name)}"
                )


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopMatch:
    """A verified loop: the query keyframe's body pose ``T_Wo_Bq`` in the old keyframe's world
    (its odometry frame), the relative pose ``T_Bo_Bq`` a pose graph takes as a loop edge, its
    4-DoF covariance ``cov_4dof`` (the position of the query in the old keyframe's body frame,
    then the yaw: what the PnP's inliers and their residuals fix), and the inlier
    correspondences (rows of each keyframe's keypoints)."""

    old_index: int
    query_index: int
    T_Wo_Bq: Pose
    T_Bo_Bq: Pose
    cov_4dof: NDArray[np.float64]
    old_rows: IntArray
    query_rows: IntArray


@dataclass(frozen=True, slots=True, kw_only=True)
class Verification:
    """What verification found: the ``stage`` it stopped at (``accepted`` when it passed all),
    how many correspondences each step kept, and the loop when accepted."""

    stage: Stage
    n_matches: int = 0
    n_fundamental: int = 0
    n_pnp: int = 0
    yaw_deg: float | None = None
    translation_m: float | None = None
    loop: LoopMatch | None = None

    @property
    def accepted(self) -> bool:
        return self.loop is not None


def _descriptors(rec: KeyframeRecord, name: str) -> tuple[NDArray[np.uint8], IntArray]:
    """A keyframe's described rows and their descriptors."""
    if rec.descriptors is None:
        return np.zeros((0, 32), np.uint8), np.zeros(0, np.int64)
    d = np.ascontiguousarray(rec.descriptors)
    if d.shape[1] != 32:
        raise PlaceError(
            f"{name} keyframe {rec.index}: descriptors must be 32 bytes, got {d.shape}"
        )
    ok = np.ones(len(d), bool) if rec.described is None else np.asarray(rec.described, bool)
    rows = np.flatnonzero(ok).astype(np.int64)
    return d[rows], rows


def match_descriptors(
    a: NDArray[np.uint8], b: NDArray[np.uint8], *, max_hamming: int, ratio: float
) -> tuple[IntArray, IntArray]:
    """Rows of ``a`` and of ``b`` (binary descriptors, ``(n, 32)`` uint8) that match: each row of
    ``a`` to its nearest in ``b`` by Hamming distance, within ``max_hamming`` bits, at most
    ``ratio`` times the second nearest, and no row of ``b`` taken twice (the closer one keeps
    it; a tie drops both)."""
    import cv2

    none = np.zeros(0, np.int64)
    if len(a) == 0 or len(b) == 0:
        return none, none
    for name, x in (("a", a), ("b", b)):
        if x.dtype != np.uint8 or x.ndim != 2 or x.shape[1] != 32:
            raise PlaceError(f"descriptors {name} must be (n, 32) uint8, got {x.dtype} {x.shape}")
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(a, b, k=min(2, len(b)))
    ia, ib, dist = [], [], []
    for m in knn:
        if not m or m[0].distance > max_hamming:
            continue
        if len(m) > 1 and m[0].distance > ratio * m[1].distance:
            continue
        ia.append(m[0].queryIdx)
        ib.append(m[0].trainIdx)
        dist.append(m[0].distance)
    if not ia:
        return none, none
    best: dict[int, int] = {}  # row of b -> the match that keeps it
    ties: set[int] = set()
    for k in np.argsort(np.array(dist), kind="stable").tolist():
        j = ib[k]
        if j in best:
            if dist[best[j]] == dist[k]:
                ties.add(j)
            continue
        best[j] = k
    keep = sorted(k for j, k in best.items() if j not in ties)
    return np.array([ia[k] for k in keep], np.int64), np.array([ib[k] for k in keep], np.int64)


def _fundamental_inliers(
    xa: NDArray[np.float64], xb: NDArray[np.float64], focal_px: float, cfg: VerificationConfig
) -> NDArray[np.bool_]:
    import cv2

    cv2.setRNGSeed(int(cfg.seed))
    F, mask = cv2.findFundamentalMat(
        xa * focal_px, xb * focal_px, cv2.FM_RANSAC, cfg.fundamental_threshold_px, 0.99
    )
    if F is None or mask is None:
        return np.zeros(len(xa), bool)
    return np.asarray(mask).ravel() > 0


def _four_dof_covariance(C6: NDArray[np.float64], T_Wo_Bo: Pose) -> NDArray[np.float64]:
    """A camera pose's covariance (world-frame rotation, then position) as a 4-DoF loop's: the
    position in the old keyframe's body frame, the yaw (the rotation about the world's z)."""
    Rt = T_Wo_Bo.R_A_B.as_matrix().T
    J = np.zeros((4, 6))
    J[:3, 3:] = Rt
    J[3, 2] = 1.0
    C = J @ C6 @ J.T
    return np.asarray(0.5 * (C + C.T), dtype=np.float64)


def verify_place(
    query: KeyframeRecord,
    old: KeyframeRecord,
    *,
    focal_px: float,
    T_B_C: Pose,
    config: VerificationConfig | None = None,
) -> Verification:
    """Whether keyframe ``query`` sees the place keyframe ``old`` saw (see the module's steps).
    ``focal_px`` turns the pixel thresholds into normalised ones; ``T_B_C``: the query's camera
    extrinsic where its record carries none."""
    cfg = config or VerificationConfig()
    if not (np.isfinite(focal_px) and focal_px > 0):
        raise PlaceError(f"verify_place: focal_px must be a positive number, got {focal_px}")
    dq, rows_q = _descriptors(query, "query")
    do, rows_o = _descriptors(old, "old")
    with_point = np.isin(old.ids[rows_o], old.landmark_ids)
    dq_o, rows_o = do[with_point], rows_o[with_point]
    if len(rows_q) < cfg.min_inliers or len(rows_o) < cfg.min_inliers:
        return Verification(stage="descriptors")
    io, iq = match_descriptors(dq_o, dq, max_hamming=cfg.max_hamming, ratio=cfg.ratio)
    n = len(io)
    if n < cfg.min_inliers:
        return Verification(stage="matches", n_matches=n)
    ro, rq = rows_o[io], rows_q[iq]
    f_ok = _fundamental_inliers(old.xy[ro], query.xy[rq], focal_px, cfg)
    n_f = int(f_ok.sum())
    if n_f < cfg.min_inliers:
        return Verification(stage="fundamental", n_matches=n, n_fundamental=n_f)
    ro, rq = ro[f_ok], rq[f_ok]
    where = {int(i): k for k, i in enumerate(old.landmark_ids)}
    X = old.landmarks_W[[where[int(i)] for i in old.ids[ro]]]
    res = pnp(X, query.xy[rq], ransac_threshold=cfg.pnp_threshold_px / focal_px,
              min_points=cfg.min_inliers, seed=cfg.seed)  # fmt: skip
    n_p = 0 if res is None else int(res.inliers.sum())
    if res is None or n_p < cfg.min_inliers:
        return Verification(stage="pnp", n_matches=n, n_fundamental=n_f, n_pnp=n_p)
    T_Wo_Bq = res.T_W_C @ (query.T_B_C or T_B_C).inverse()
    T_Bo_Bq = old.T_W_B.inverse() @ T_Wo_Bq
    dyaw = yaw_of(T_Wo_Bq.R_A_B.as_matrix()) - yaw_of(old.T_W_B.R_A_B.as_matrix())
    yaw = float(np.degrees(abs((dyaw + np.pi) % (2 * np.pi) - np.pi)))
    dist = float(np.linalg.norm(T_Bo_Bq.p_A_B))
    counts = Verification(
        stage="sanity", n_matches=n, n_fundamental=n_f, n_pnp=n_p, yaw_deg=yaw, translation_m=dist
    )
    if yaw > cfg.max_yaw_deg or dist > cfg.max_translation_m:
        return counts
    C6 = pnp_covariance(
        res.T_W_C, X[res.inliers], query.xy[rq][res.inliers], min_sigma=1 / focal_px
    )
    loop = LoopMatch(
        old_index=old.index, query_index=query.index, T_Wo_Bq=T_Wo_Bq, T_Bo_Bq=T_Bo_Bq,
        cov_4dof=_four_dof_covariance(C6, old.T_W_B), old_rows=ro[res.inliers],
        query_rows=rq[res.inliers],
    )  # fmt: skip
    return replace(counts, stage="accepted", loop=loop)
