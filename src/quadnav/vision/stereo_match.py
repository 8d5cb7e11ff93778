"""Stereo and RGB-D keypoints for the SLAM (ORB-SLAM2's ``ComputeStereoMatches`` and
``ComputeStereoFromRGBD``, issue 24).

On a rectified pair a left keypoint's partner lies on its row. Each right keypoint is listed on
the rows within ``2 s`` of its own (``s``: its scale); a left keypoint looks at those on its
row, at scales within one level of its own, with a disparity in ``[0, fx / k)`` (points nearer
than ``k = min_depth_baselines`` baselines, 2.5, are not matched; ORB-SLAM2: 1), and takes the
nearest descriptor if it is within ``max_hamming`` and clearly nearer than the best candidate
elsewhere on the row (``unique_ratio``: an exact copy of a texture further along is ambiguous,
not a match). The match is refined to a fraction of a pixel by a window correlation at the
keypoint's level (sum of absolute differences over ``2 w + 1`` pixels square, the window slid
``w`` pixels either way, a parabola through the best three), and refused if the parabola's
minimum leaves the middle pixel. Last, the matches whose correlation is worse than 1.5 x 1.4
times the median (a robust 1.5 sigma) are refused. Each matched keypoint gets ``u_right`` and
``depth_m = fx b / disparity``; the others -1.

With a depth image, ``u_right = u_left - fx b / depth`` (the virtual right coordinate), so the
SLAM treats RGB-D as stereo. A keypoint is *close* when its depth is under ``th_depth`` (ORB-
SLAM2's ThDepth: 40 baselines by default; 22 was best on the thesis's Jetson): close points are
triangulated from one frame, far ones need two.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VisionError
from quadnav.vision.orb import OrbFeatures

__all__ = ["StereoConfig", "StereoKeypoints", "close_points", "rgbd_keypoints", "stereo_keypoints"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class StereoConfig:
    """ORB-SLAM2's matching thresholds: the Hamming distance a match may have (its
    ``(TH_HIGH + TH_LOW) / 2``), the correlation's half window ``w`` and the robust cut; and
    ours: ``unique_ratio``, how much nearer the best candidate must be than the best one
    elsewhere on the row (more than ``unique_px`` times the keypoint's scale away), or the
    match is ambiguous and refused (a texture repeated along the row, whose copies pair a
    corner with the wrong one: ORB-SLAM2 takes the first; 1 or more: no such test);
    ``min_depth_baselines``: no match nearer than this (ORB-SLAM2: 1 baseline; a ZED measures
    from 0.3 m, 2.5 of its baselines: nearer, a copy of the texture one period along the row
    is taken for a point a hand's width away)."""

    max_hamming: int = 75
    window_px: int = 5
    outlier_factor: float = 1.5 * 1.4
    unique_ratio: float = 0.9
    unique_px: float = 3.0
    min_depth_baselines: float = 2.5

    def __post_init__(self) -> None:
        if not 0 <= self.max_hamming <= 256 or self.window_px < 1 or self.outlier_factor <= 0:
            raise VisionError("StereoConfig: 0 <= max_hamming <= 256, window_px >= 1, factor > 0")
        if not (self.unique_ratio > 0 and self.unique_px > 0 and self.min_depth_baselines > 0):
            raise VisionError(
                "StereoConfig: unique_ratio, unique_px and min_depth_baselines must be > 0"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class StereoKeypoints:
    """Per left keypoint: ``u_right`` (px, -1 without a partner) and ``depth_m`` (-1 without)."""

    u_right: FloatArray
    depth_m: FloatArray

    @property
    def matched(self) -> NDArray[np.bool_]:
        return self.depth_m > 0


def _hamming(a: NDArray[np.uint8], b: NDArray[np.uint8]) -> NDArray[np.int64]:
    """Row-wise Hamming distances of ``(N, 32)`` uint8 descriptors (popcounts of 64-bit words)."""
    x = np.bitwise_xor(
        np.ascontiguousarray(a).view(np.uint64), np.ascontiguousarray(b).view(np.uint64)
    )
    return np.asarray(np.bitwise_count(x).sum(axis=1), np.int64)


def _row_candidates(
    left: OrbFeatures, right: OrbFeatures, rows: int, max_d: float
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """All (left, right) pairs the row search looks at: the right keypoint lies within ``2 s``
    rows of the left one's row (``s``: its scale), one level apart at most, with a disparity in
    ``[0, max_d)``; by left keypoint, then right keypoint."""
    v = right.uv_px[:, 1]
    r = 2.0 * right.scales[right.octave]
    lo = np.clip(np.floor(v - r), 0, rows - 1).astype(np.int64)
    hi = np.clip(np.ceil(v + r), 0, rows - 1).astype(np.int64)
    by_lo = np.argsort(lo, kind="stable")
    lo_sorted = lo[by_lo]
    y = np.clip(np.rint(left.uv_px[:, 1]), 0, rows - 1).astype(np.int64)
    span = int((hi - lo).max())
    a = np.searchsorted(lo_sorted, y - span, side="left")
    b = np.searchsorted(lo_sorted, y, side="right")
    counts = b - a
    i = np.repeat(np.arange(len(left), dtype=np.int64), counts)
    start = np.repeat(a - np.r_[0, np.cumsum(counts)[:-1]], counts)
    j = by_lo[np.arange(len(i), dtype=np.int64) + start]
    uL, uR = left.uv_px[i, 0], right.uv_px[j, 0]
    ok = (hi[j] >= y[i]) & (np.abs(right.octave[j] - left.octave[i]) <= 1)
    ok &= (uR <= uL) & (uR > uL - max_d)
    i, j = i[ok], j[ok]
    order = np.lexsort((j, i))
    return i[order], j[order]


def stereo_keypoints(
    left: OrbFeatures, right: OrbFeatures, left_levels: list[NDArray[np.uint8]],
    right_levels: list[NDArray[np.uint8]], *, fx: float, baseline_m: float,
    config: StereoConfig | None = None,
) -> StereoKeypoints:  # fmt: skip
    """Each left keypoint's partner on a rectified pair (see the module): the features and the
    pyramids of :meth:`quadnav.vision.orb.OrbExtractor.extract`, the rectified focal length
    (px) and the baseline (m). All keypoints at once: the candidates by row, their Hamming
    distances, each left keypoint's nearest (the lower right index on a tie), the correlation
    per pyramid level."""
    cfg = config or StereoConfig()
    if not (np.isfinite(fx) and fx > 0 and np.isfinite(baseline_m) and baseline_m > 0):
        raise VisionError(f"stereo needs fx > 0 and a baseline > 0, got {fx}, {baseline_m}")
    n = len(left)
    u_right, depth, cost = np.full(n, -1.0), np.full(n, -1.0), np.full(n, np.inf)
    if n == 0 or len(right) == 0:
        return StereoKeypoints(u_right=u_right, depth_m=depth)
    max_d = fx / cfg.min_depth_baselines  # (fx b / (k b): nothing nearer than k baselines)
    i, j = _row_candidates(left, right, left_levels[0].shape[0], max_d)
    d = _hamming(left.descriptors[i], right.descriptors[j])
    order = np.lexsort((j, d, i))  # per left keypoint: the nearest, then the lower index
    first = np.r_[True, i[order][1:] != i[order][:-1]] if len(order) else np.zeros(0, bool)
    best = order[first]
    keep = d[best] <= cfg.max_hamming
    if cfg.unique_ratio < 1:
        keep &= _unique(left, right, i, j, d, order, first, cfg)
    best = best[keep]
    i, j = i[best], j[best]
    u, sad, ok = _refine(left, i, right.uv_px[j, 0], left_levels, right_levels, cfg)
    disparity = left.uv_px[i, 0] - u
    ok &= (disparity >= 0) & (disparity < max_d)
    i, u, sad, disparity = i[ok], u[ok], sad[ok], disparity[ok]
    u_right[i], depth[i], cost[i] = u, fx * baseline_m / np.maximum(disparity, 0.01), sad
    good = np.isfinite(cost)
    if good.any():
        cut = cfg.outlier_factor * float(np.median(cost[good]))
        bad = good & (cost > cut)
        u_right[bad], depth[bad] = -1.0, -1.0
    return StereoKeypoints(u_right=u_right, depth_m=depth)


def _unique(
    left: OrbFeatures, right: OrbFeatures, i: NDArray[np.int64], j: NDArray[np.int64],
    d: NDArray[np.int64], order: NDArray[np.int64], first: NDArray[np.bool_], cfg: StereoConfig,
) -> NDArray[np.bool_]:  # fmt: skip
    """Per left keypoint (in ``order``'s groups): whether its best candidate is nearer than
    ``unique_ratio`` times the best one more than ``unique_px`` (its scale) along the row."""
    group = np.cumsum(first) - 1
    starts = np.flatnonzero(first)
    u = right.uv_px[j[order], 0]
    u_best = u[starts][group]
    s = left.scales[left.octave[i[order]]]
    far = np.abs(u - u_best) > cfg.unique_px * s
    d_far = np.where(far, d[order], 10**6)
    second = np.minimum.reduceat(d_far, starts)
    return np.asarray(d[order][starts] < cfg.unique_ratio * second, bool)


def _refine(
    left: OrbFeatures, i: NDArray[np.int64], uR0: FloatArray, left_levels: list[NDArray[np.uint8]],
    right_levels: list[NDArray[np.uint8]], cfg: StereoConfig,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:  # fmt: skip
    """The right coordinates ``uR0`` of left keypoints ``i`` refined by correlation at each
    keypoint's level, their best sums of absolute differences, and which were refined (not at a
    border, the minimum not at the window's end, the parabola's within a pixel)."""
    u, sad, ok = np.zeros(len(i)), np.zeros(len(i)), np.zeros(len(i), bool)
    w = cfg.window_px
    for o in np.unique(left.octave[i]):
        at = np.flatnonzero(left.octave[i] == o)
        s = float(left.scales[o])
        L, R = left_levels[o], right_levels[o]
        x = np.rint(left.uv_px[i[at], 0] / s).astype(np.int64)
        y = np.rint(left.uv_px[i[at], 1] / s).astype(np.int64)
        xr = np.rint(uR0[at] / s).astype(np.int64)
        inside = (y - w >= 0) & (y + w + 1 <= min(L.shape[0], R.shape[0]))
        inside &= (x - w >= 0) & (x + w + 1 <= L.shape[1])
        inside &= (xr - 2 * w >= 0) & (xr + 2 * w + 1 <= R.shape[1])
        at, x, y, xr = at[inside], x[inside], y[inside], xr[inside]
        if len(at) == 0:
            continue
        sads = _sads(L, R, x, y, xr, w)
        b = np.argmin(sads, axis=1)
        inner = (b > 0) & (b < 2 * w)
        at, b, sads, xr = at[inner], b[inner], sads[inner], xr[inner]
        rows = np.arange(len(at))
        d1, d2, d3 = sads[rows, b - 1], sads[rows, b], sads[rows, b + 1]
        denom = 2.0 * (d1 + d3 - 2.0 * d2)
        delta = np.where(denom > 0, (d1 - d3) / np.where(denom > 0, denom, 1.0), 0.0)
        fine = np.abs(delta) <= 1.0
        at = at[fine]
        u[at] = s * ((xr[fine] + (b[fine] - w)) + delta[fine])
        sad[at], ok[at] = d2[fine], True
    return u, sad, ok


def _sads(
    L: NDArray[np.uint8], R: NDArray[np.uint8], x: NDArray[np.int64], y: NDArray[np.int64],
    xr: NDArray[np.int64], w: int,
) -> FloatArray:  # fmt: skip
    """(n, 2 w + 1): the sum of absolute differences of each left window (centred on its middle
    pixel) against the right window shifted -w..w about ``xr`` (each centred on its own)."""
    k = np.arange(-w, w + 1)
    rows = ((y[:, None] + k) * L.shape[1])[:, :, None]  # (flat indices: one gather each)
    patch = L.ravel()[rows + (x[:, None] + k)[:, None, :]].astype(np.int16)
    patch -= patch[:, w : w + 1, w : w + 1]
    cols = (xr[:, None] + np.arange(-2 * w, 2 * w + 1))[:, None, :]
    strip = R.ravel()[rows // L.shape[1] * R.shape[1] + cols].astype(np.int16)
    sads = np.empty((len(x), 2 * w + 1), np.int32)
    for s in range(2 * w + 1):  # (a shift at a time: small arrays, |differences| <= 510)
        d = patch - strip[:, :, s : s + 2 * w + 1]
        d += strip[:, w : w + 1, w + s : w + s + 1]  # (the window centred on its middle)
        np.abs(d, out=d)
        sads[:, s] = d.sum(axis=(1, 2), dtype=np.int32)
    return np.asarray(sads, np.float64)


def rgbd_keypoints(
    left: OrbFeatures, depth_image_m: NDArray[np.floating], *, fx: float, baseline_m: float
) -> StereoKeypoints:
    """RGB-D as stereo: each keypoint's depth read from the registered depth image at its pixel
    (no depth there, zero or not finite: -1), and its virtual right coordinate
    ``u_left - fx b / depth`` (``baseline_m``: the sensor's, e.g. 0.08 for a Kinect)."""
    if not (np.isfinite(fx) and fx > 0 and np.isfinite(baseline_m) and baseline_m > 0):
        raise VisionError(f"RGB-D needs fx > 0 and a baseline > 0, got {fx}, {baseline_m}")
    D = np.asarray(depth_image_m)
    if D.ndim != 2:
        raise VisionError(f"a depth image must be 2-D, got shape {D.shape}")
    uv = np.rint(left.uv_px).astype(np.int64)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < D.shape[1]) & (uv[:, 1] >= 0) & (uv[:, 1] < D.shape[0])
    z = np.full(len(left), -1.0)
    z[inside] = D[uv[inside, 1], uv[inside, 0]]
    ok = np.isfinite(z) & (z > 0)
    z = np.where(ok, z, -1.0)
    u_right = np.where(ok, left.uv_px[:, 0] - fx * baseline_m / np.where(ok, z, 1.0), -1.0)
    return StereoKeypoints(u_right=u_right, depth_m=z)


def close_points(
    keys: StereoKeypoints, *, baseline_m: float, th_depth_baselines: float = 40.0
) -> NDArray[np.bool_]:
    """Which keypoints are close (a depth under ``th_depth_baselines`` baselines: ORB-SLAM2's
    ThDepth): triangulated from one frame; the far and unmatched ones are not."""
    if not th_depth_baselines > 0:
        raise VisionError(f"th_depth_baselines must be > 0, got {th_depth_baselines}")
    return keys.matched & (keys.depth_m < th_depth_baselines * baseline_m)
