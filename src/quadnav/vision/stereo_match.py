"""Stereo and RGB-D keypoints for the SLAM (ORB-SLAM2's ``ComputeStereoMatches`` and
``ComputeStereoFromRGBD``, issue 24).

On a rectified pair a left keypoint's partner lies on its row. Each right keypoint is listed on
the rows within ``2 s`` of its own (``s``: its scale); a left keypoint looks at those on its
row, at scales within one level of its own, with a disparity in ``[0, fx)`` (points nearer
than one baseline are not matched), and takes the nearest descriptor if it is within
``max_hamming``. The match is refined to a fraction of a pixel by a window correlation at the
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
    ``(TH_HIGH + TH_LOW) / 2``), the correlation's half window ``w`` and the robust cut."""

    max_hamming: int = 75
    window_px: int = 5
    outlier_factor: float = 1.5 * 1.4

    def __post_init__(self) -> None:
        if not 0 <= self.max_hamming <= 256 or self.window_px < 1 or self.outlier_factor <= 0:
            raise VisionError("StereoConfig: 0 <= max_hamming <= 256, window_px >= 1, factor > 0")


@dataclass(frozen=True, slots=True, kw_only=True)
class StereoKeypoints:
    """Per left keypoint: ``u_right`` (px, -1 without a partner) and ``depth_m`` (-1 without)."""

    u_right: FloatArray
    depth_m: FloatArray

    @property
    def matched(self) -> NDArray[np.bool_]:
        return self.depth_m > 0


def _row_index(right: OrbFeatures, rows: int) -> list[list[int]]:
    """For each image row, the right keypoints within ``2 s`` rows of it."""
    out: list[list[int]] = [[] for _ in range(rows)]
    v = right.uv_px[:, 1]
    r = 2.0 * right.scales[right.octave]
    lo = np.clip(np.floor(v - r), 0, rows - 1).astype(int)
    hi = np.clip(np.ceil(v + r), 0, rows - 1).astype(int)
    for i, (a, b) in enumerate(zip(lo.tolist(), hi.tolist(), strict=True)):
        for y in range(a, b + 1):
            out[y].append(i)
    return out


def _hamming(a: NDArray[np.uint8], b: NDArray[np.uint8]) -> NDArray[np.int64]:
    return np.asarray(np.unpackbits(a[None, :] ^ b, axis=1).sum(axis=1), np.int64)


def stereo_keypoints(
    left: OrbFeatures, right: OrbFeatures, left_levels: list[NDArray[np.uint8]],
    right_levels: list[NDArray[np.uint8]], *, fx: float, baseline_m: float,
    config: StereoConfig | None = None,
) -> StereoKeypoints:  # fmt: skip
    """Each left keypoint's partner on a rectified pair (see the module): the features and the
    pyramids of :meth:`quadnav.vision.orb.OrbExtractor.extract`, the rectified focal length
    (px) and the baseline (m)."""
    cfg = config or StereoConfig()
    if not (np.isfinite(fx) and fx > 0 and np.isfinite(baseline_m) and baseline_m > 0):
        raise VisionError(f"stereo needs fx > 0 and a baseline > 0, got {fx}, {baseline_m}")
    n = len(left)
    u_right, depth, cost = np.full(n, -1.0), np.full(n, -1.0), np.full(n, np.inf)
    if n == 0 or len(right) == 0:
        return StereoKeypoints(u_right=u_right, depth_m=depth)
    rows = left_levels[0].shape[0]
    by_row = _row_index(right, rows)
    max_d = fx  # (fx b / b: nothing nearer than one baseline)
    for i in range(n):
        uL, vL = left.uv_px[i]
        cand = by_row[min(max(round(vL), 0), rows - 1)]
        if not cand:
            continue
        c = np.asarray(cand, np.int64)
        uR = right.uv_px[c, 0]
        ok = (np.abs(right.octave[c] - left.octave[i]) <= 1) & (uR <= uL) & (uR > uL - max_d)
        c = c[ok]
        if len(c) == 0:
            continue
        d = _hamming(left.descriptors[i], right.descriptors[c])
        best = int(np.argmin(d))
        if d[best] > cfg.max_hamming:
            continue
        refined = _refine(left, i, float(right.uv_px[c[best], 0]), left_levels, right_levels, cfg)
        if refined is None:
            continue
        u, sad = refined
        disparity = uL - u
        if not 0 <= disparity < max_d:
            continue
        u_right[i], depth[i], cost[i] = u, fx * baseline_m / max(disparity, 0.01), sad
    good = np.isfinite(cost)
    if good.any():
        cut = cfg.outlier_factor * float(np.median(cost[good]))
        bad = good & (cost > cut)
        u_right[bad], depth[bad] = -1.0, -1.0
    return StereoKeypoints(u_right=u_right, depth_m=depth)


def _refine(
    left: OrbFeatures, i: int, uR0: float, left_levels: list[NDArray[np.uint8]],
    right_levels: list[NDArray[np.uint8]], cfg: StereoConfig,
) -> tuple[float, float] | None:  # fmt: skip
    """The right coordinate refined by correlation at the keypoint's level, and its best sum of
    absolute differences (None at a border or when the minimum is at the window's end)."""
    o = int(left.octave[i])
    s = float(left.scales[o])
    L, R = left_levels[o].astype(np.float32), right_levels[o]
    w = cfg.window_px
    x, y = round(left.uv_px[i, 0] / s), round(left.uv_px[i, 1] / s)
    xr = round(uR0 / s)
    if y - w < 0 or y + w + 1 > L.shape[0] or x - w < 0 or x + w + 1 > L.shape[1]:
        return None
    if xr - 2 * w < 0 or xr + 2 * w + 1 > R.shape[1]:
        return None
    patch = L[y - w : y + w + 1, x - w : x + w + 1]
    patch = patch - patch[w, w]
    strip = R[y - w : y + w + 1, xr - 2 * w : xr + 2 * w + 1].astype(np.float32)
    sads = np.empty(2 * w + 1, np.float64)
    for k in range(2 * w + 1):  # shifts -w..w
        win = strip[:, k : k + 2 * w + 1]
        sads[k] = float(np.abs(patch - (win - win[w, w])).sum())
    b = int(np.argmin(sads))
    if b == 0 or b == 2 * w:
        return None
    d1, d2, d3 = sads[b - 1], sads[b], sads[b + 1]
    denom = 2.0 * (d1 + d3 - 2.0 * d2)
    delta = (d1 - d3) / denom if denom > 0 else 0.0
    if not -1.0 <= delta <= 1.0:
        return None
    return s * (xr + (b - w) + delta), float(d2)


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
