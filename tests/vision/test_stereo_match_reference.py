"""The row search in bulk (issue 24's speed work) against ORB-SLAM2's loop over left keypoints,
written out plainly here: on rendered rectified pairs and on the real Middlebury motorcycle pair,
every keypoint's right coordinate and depth must be the same, to the last bit."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from quadnav.vision.orb import OrbExtractor, OrbFeatures
from quadnav.vision.stereo_match import StereoConfig, stereo_keypoints


def _refine_one(fl: OrbFeatures, i: int, uR0: float, ll: list, lr: list, w: int) -> tuple | None:
    o = int(fl.octave[i])
    s = float(fl.scales[o])
    L, R = ll[o].astype(np.float32), lr[o].astype(np.float32)
    x, y, xr = round(fl.uv_px[i, 0] / s), round(fl.uv_px[i, 1] / s), round(uR0 / s)
    if y - w < 0 or y + w + 1 > L.shape[0] or x - w < 0 or x + w + 1 > L.shape[1]:
        return None
    if xr - 2 * w < 0 or xr + 2 * w + 1 > R.shape[1]:
        return None
    patch = L[y - w : y + w + 1, x - w : x + w + 1]
    patch = patch - patch[w, w]
    strip = R[y - w : y + w + 1, xr - 2 * w : xr + 2 * w + 1]
    sads = [float(np.abs(patch - (win - win[w, w])).sum())
            for win in (strip[:, k : k + 2 * w + 1] for k in range(2 * w + 1))]  # fmt: skip
    b = int(np.argmin(sads))
    if b in (0, 2 * w):
        return None
    d1, d2, d3 = sads[b - 1], sads[b], sads[b + 1]
    denom = 2.0 * (d1 + d3 - 2.0 * d2)
    delta = (d1 - d3) / denom if denom > 0 else 0.0
    return None if abs(delta) > 1 else (s * (xr + (b - w) + delta), d2)


def _loop(fl: OrbFeatures, fr: OrbFeatures, ll: list, lr: list, fx: float, b: float) -> tuple:
    """Each left keypoint in turn (fc857bd's matcher, ORB-SLAM2's ComputeStereoMatches)."""
    cfg = StereoConfig()
    n, rows = len(fl), ll[0].shape[0]
    u_right, depth, cost = np.full(n, -1.0), np.full(n, -1.0), np.full(n, np.inf)
    r = 2.0 * fr.scales[fr.octave]
    for i in range(n):
        y = min(max(round(fl.uv_px[i, 1]), 0), rows - 1)
        lo = np.clip(np.floor(fr.uv_px[:, 1] - r), 0, rows - 1)
        hi = np.clip(np.ceil(fr.uv_px[:, 1] + r), 0, rows - 1)
        uL, uR = fl.uv_px[i, 0], fr.uv_px[:, 0]
        c = np.flatnonzero((lo <= y) & (y <= hi) & (np.abs(fr.octave - fl.octave[i]) <= 1)
                           & (uR <= uL) & (uR > uL - fx))  # fmt: skip
        if len(c) == 0:
            continue
        d = np.unpackbits(fl.descriptors[i][None] ^ fr.descriptors[c], axis=1).sum(axis=1)
        k = int(np.argmin(d))
        out = _refine_one(fl, i, float(uR[c[k]]), ll, lr, cfg.window_px) if d[k] <= 75 else None
        if out is not None and 0 <= uL - out[0] < fx:
            u_right[i], depth[i], cost[i] = out[0], fx * b / max(uL - out[0], 0.01), out[1]
    good = np.isfinite(cost)
    bad = good & (cost > cfg.outlier_factor * np.median(cost[good]))
    u_right[bad], depth[bad] = -1.0, -1.0
    return u_right, depth


def _pairs() -> list[tuple[np.ndarray, np.ndarray, float]]:
    from skimage import data

    photo = cv2.resize(data.camera(), (672, 376))
    shifted = np.roll(photo, -7, axis=1)  # (a rectified pair 7 px apart, its edge unmatched)
    pairs = [(photo, shifted, 350.0)]
    try:
        left, right, _ = data.stereo_motorcycle()
    except Exception:  # (without the Middlebury pair: the photo alone)
        return pairs
    grey = [cv2.cvtColor(np.asarray(x), cv2.COLOR_RGB2GRAY) for x in (left, right)]
    return [*pairs, (grey[0], grey[1], 995.0)]


@pytest.mark.parametrize("k", [0, 1])
def test_the_row_search_in_bulk_is_the_loop_bit_for_bit(k: int) -> None:
    pairs = _pairs()
    if k >= len(pairs):
        pytest.skip("scikit-image's stereo_motorcycle pair not available")
    left, right, fx = pairs[k]
    ex = OrbExtractor()
    (fl, ll), (fr, lr) = ex.extract(left), ex.extract(right)
    # (ORB-SLAM2's loop: no uniqueness test, nothing nearer than one baseline)
    keys = stereo_keypoints(fl, fr, ll, lr, fx=fx, baseline_m=0.12,
                            config=StereoConfig(unique_ratio=1.0, min_depth_baselines=1.0))  # fmt: skip
    u_right, depth = _loop(fl, fr, ll, lr, fx, 0.12)
    assert keys.matched.sum() > 300
    np.testing.assert_array_equal(keys.u_right, u_right)
    np.testing.assert_array_equal(keys.depth_m, depth)
