"""ORB features in a scale pyramid, spread over the image (ORB-SLAM2's extractor, issue 24): the
features of the stereo and RGB-D SLAM.

The image is scaled down ``n_levels`` times by ``scale_factor``; each level gets a share of the
``n_features`` in proportion to its area (ORB-SLAM2: ``n (1 - 1/s^2) / (1 - 1/s^(2 L))`` at level
0, each next level 1/s^2 of the one before). FAST corners are found at ``ini_fast`` over the
level, and at ``min_fast`` only in the cells of the level's grid (about one cell per feature
wanted) that have none: in each cell the corners at ``ini_fast`` are taken, the weaker ones only
where a cell has none (ORB-SLAM2 lowers the threshold per cell so). Each cell keeps its best, then the
level is filled by score: the features spread over the picture, not bunched on its strongest
texture. Each keypoint gets its orientation (intensity centroid) and rotated BRIEF from OpenCV
on its level's image; positions are given at level 0.
"""

from __future__ import annotations

import operator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VisionError
from quadnav.vision.tracking import as_grey

__all__ = ["OrbConfig", "OrbExtractor", "OrbFeatures", "level_shares", "orientations"]

FloatArray = NDArray[np.float64]
#: ORB's patch (pixels at the keypoint's level) and the border it needs.
PATCH_PX = 31
EDGE_PX = 19  # ORB-SLAM2's EDGE_THRESHOLD: the patch turned any way, plus the FAST circle


@dataclass(frozen=True, slots=True, kw_only=True)
class OrbConfig:
    """ORB-SLAM2's ``ORBextractor`` settings (the thesis's Jetson used 1,200 features, section
    5.7); ``cell_px``: the grid's cell at level 0, about the spacing of the features wanted."""

    n_features: int = 1200
    scale_factor: float = 1.2
    n_levels: int = 8
    ini_fast: int = 20
    min_fast: int = 7

    def __post_init__(self) -> None:
        if self.n_features < 1 or self.n_levels < 1:
            raise VisionError("OrbConfig: n_features and n_levels must be >= 1")
        if not 1.0 < self.scale_factor <= 4.0:
            raise VisionError(f"OrbConfig.scale_factor must lie in (1, 4], got {self.scale_factor}")
        if not 1 <= self.min_fast <= self.ini_fast <= 255:
            raise VisionError("OrbConfig: 1 <= min_fast <= ini_fast <= 255")

    def scales(self) -> FloatArray:
        """Each level's scale (level 0: 1)."""
        return np.asarray(self.scale_factor ** np.arange(self.n_levels), dtype=np.float64)


@dataclass(frozen=True, slots=True, kw_only=True)
class OrbFeatures:
    """Keypoints at level 0: ``uv_px`` (N, 2), ``octave`` (N,), ``angle_deg`` (N,),
    ``response`` (N,, the FAST score), ``size_px`` (N,, the patch at level 0), and their
    ``descriptors`` (N, 32) uint8; ``scales`` the pyramid's (a keypoint's scale is
    ``scales[octave]``)."""

    uv_px: FloatArray
    octave: NDArray[np.int64]
    angle_deg: FloatArray
    response: FloatArray
    size_px: FloatArray
    descriptors: NDArray[np.uint8]
    scales: FloatArray

    def __len__(self) -> int:
        return len(self.uv_px)


def level_shares(config: OrbConfig) -> NDArray[np.int64]:
    """The features wanted at each level (ORB-SLAM2's geometric series by area, the rest to the
    last level so that they add up to ``n_features``)."""
    f = 1.0 / config.scale_factor**2
    n, L = config.n_features, config.n_levels
    first = n * (1 - f) / (1 - f**L) if L > 1 else float(n)
    shares = [round(first * f**k) for k in range(L - 1)]
    shares.append(max(n - sum(shares), 0))
    return np.asarray(shares, dtype=np.int64)


class OrbExtractor:
    """ORB in a scale pyramid, spread over a grid (see the module). :meth:`extract` also gives
    the pyramid, which the stereo matcher reads patches from."""

    def __init__(self, config: OrbConfig | None = None) -> None:
        import cv2

        self.config = config or OrbConfig()
        self._fast = cv2.FastFeatureDetector.create(self.config.min_fast, nonmaxSuppression=True)
        self._strong = cv2.FastFeatureDetector.create(self.config.ini_fast, nonmaxSuppression=True)
        self._orb = cv2.ORB.create(edgeThreshold=EDGE_PX, patchSize=PATCH_PX)
        self._shares = level_shares(self.config)
        #: each level's share of grid cells without a corner at ini_fast in the last image
        self._weak_share: dict[int, float] = {}

    def pyramid(self, image: object) -> list[NDArray[np.uint8]]:
        """The grey image at each level (level 0: itself)."""
        import cv2

        grey = as_grey(image)
        if min(grey.shape) <= 2 * EDGE_PX + 1:
            raise VisionError(f"an image of {grey.shape} is too small for ORB")
        levels = [grey]
        for s in self.config.scales()[1:]:
            size = (round(grey.shape[1] / s), round(grey.shape[0] / s))
            if min(size) <= 2 * EDGE_PX + 1:
                break
            levels.append(
                np.asarray(cv2.resize(grey, size, interpolation=cv2.INTER_LINEAR), np.uint8)
            )
        return levels

    def extract(self, image: object) -> tuple[OrbFeatures, list[NDArray[np.uint8]]]:
        """The image's features and its pyramid."""
        levels = self.pyramid(image)
        scales = self.config.scales()
        parts = [self._level(img, int(self._shares[k]), k) for k, img in enumerate(levels)]
        octave = np.concatenate([np.full(len(p[0]), k, np.int64) for k, p in enumerate(parts)])
        if len(octave) == 0:
            return _empty(scales), levels
        uv, angle, score, desc = (np.concatenate([p[i] for p in parts]) for i in range(4))
        s = scales[octave]
        return (
            OrbFeatures(
                uv_px=uv * s[:, None], octave=octave, angle_deg=angle, response=score,
                size_px=PATCH_PX * s, descriptors=desc.astype(np.uint8), scales=scales,
            ),
            levels,
        )  # fmt: skip

    def _level(
        self, img: NDArray[np.uint8], want: int, level: int = 0
    ) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.uint8]]:
        """One level's keypoints (in its pixels) spread over its grid, oriented, described:
        positions (n, 2), angles, FAST scores (as OpenCV's keypoints hold them, in float32) and
        descriptors (n, 32)."""
        import cv2

        if want <= 0:
            return np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 32), np.uint8)
        uv, score = self._candidates(img, want, level)
        if len(uv) == 0:
            return np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 32), np.uint8)
        h, w = img.shape
        keep = spread(uv, score, want, (w, h), self.config.ini_fast)
        uv, score = uv[keep], score[keep]
        angle = orientations(img, uv).astype(np.float32).astype(np.float64)
        chosen = [
            cv2.KeyPoint(x, y, float(PATCH_PX), a, r, 0)  # (described on its level's image)
            for x, y, a, r in zip(uv[:, 0].tolist(), uv[:, 1].tolist(), angle.tolist(),
                                  score.tolist(), strict=True)
        ]  # fmt: skip
        got, desc = self._orb.compute(img, chosen)
        if desc is None or not got:
            return np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 32), np.uint8)
        if len(got) != len(chosen):  # (OpenCV dropped some: read back the ones it kept)
            uv = np.array([k.pt for k in got], np.float64)
            angle = np.array([k.angle for k in got], np.float64)
            score = np.array([k.response for k in got], np.float64)
        return uv, angle, score, np.asarray(desc, np.uint8)

    def _candidates(
        self, img: NDArray[np.uint8], want: int, level: int = 0
    ) -> tuple[FloatArray, FloatArray]:
        """The corners :func:`spread` chooses from, in FAST's raster order. Where 70 % of the
        cells of the level's grid or more had a corner at ``ini_fast`` in the last image: those
        corners, and
        those at ``min_fast`` only in the cells that have none (the rest could not be chosen;
        with too few, every corner at ``min_fast``, as :func:`spread` then fills in with them).
        Else, as in a weakly textured image, every corner at ``min_fast``: one pass costs as
        little there. Either way :func:`spread` keeps the same features; FAST at ``min_fast`` over a
        well-textured level finds about three times the corners and took most of the time."""
        h, w = img.shape
        if self._weak_share.get(level, 0.0) >= 0.3:
            uv, score = self._fast_in(self._fast, img, [(0, 0, w, h)])
            grid = _Grid((w, h), want)
            strong = np.zeros(grid.n_cells, bool)
            strong[grid.cell_of(uv[score >= self.config.ini_fast])] = True
            self._weak_share[level] = 1.0 - float(strong.mean())
            return uv, score
        grid = _Grid((w, h), want)
        uv, score = self._fast_in(self._strong, img, [(0, 0, w, h)])
        weak_cells = np.ones(grid.n_cells, bool)
        weak_cells[grid.cell_of(uv)] = False
        self._weak_share[level] = float(weak_cells.mean())
        if weak_cells.any():
            wuv, wscore = self._fast_in(self._fast, img, grid.runs(weak_cells))
            mine = weak_cells[grid.cell_of(wuv)]
            uv, score = np.concatenate([uv, wuv[mine]]), np.concatenate([score, wscore[mine]])
        if len(uv) < want:  # (spread would fill in with the strong cells' weaker corners)
            return self._fast_in(self._fast, img, [(0, 0, w, h)])
        order = np.argsort(uv[:, 1].astype(np.int64) * w + uv[:, 0].astype(np.int64))
        return uv[order], score[order]

    @staticmethod
    def _fast_in(
        fast: object, img: NDArray[np.uint8], boxes: list[tuple[int, int, int, int]]
    ) -> tuple[FloatArray, FloatArray]:
        """The corners ``fast`` finds at least ``EDGE_PX`` from the level's border and inside
        one of ``boxes`` (x0, y0, x1, y1; not overlapping): positions (n, 2) in the level's
        pixels, FAST scores. FAST runs on each box and 4 px around it, so that a corner's
        circle and the neighbours its non-maximum suppression compares it with are all seen:
        the same corners as over the whole image."""
        import cv2

        h, w = img.shape
        m = 4
        found: list[Any] = []
        spans = []
        for x0, y0, x1, y1 in boxes:
            x0, y0, x1, y1 = max(x0, EDGE_PX), max(y0, EDGE_PX), min(x1, w - EDGE_PX), min(
                y1, h - EDGE_PX)  # fmt: skip
            if x1 > x0 and y1 > y0:
                got = fast.detect(img[y0 - m : y1 + m, x0 - m : x1 + m])  # type: ignore[attr-defined]
                found.extend(got)
                spans.append((x0, y0, x1, y1, len(got)))
        if not found:
            return np.zeros((0, 2)), np.zeros(0)
        box = np.repeat(np.asarray(spans, np.int64)[:, :4], [s[4] for s in spans], axis=0)
        uv = np.asarray(cv2.KeyPoint.convert(found), np.float64).reshape(-1, 2) + box[:, :2] - m
        score = np.fromiter(map(_RESPONSE, found), np.float64, len(found))
        inside = (uv[:, 0] >= box[:, 0]) & (uv[:, 0] < box[:, 2])
        inside &= (uv[:, 1] >= box[:, 1]) & (uv[:, 1] < box[:, 3])
        return uv[inside], score[inside]


_RESPONSE = operator.attrgetter("response")


class _Grid:
    """The grid :func:`spread` spreads over: about ``want`` square cells over an image of
    ``size`` (w, h), the last row and column taking what is left."""

    def __init__(self, size: tuple[int, int], want: int) -> None:
        w, h = size
        self.size = size
        self.cell = max(np.sqrt(w * h / max(want, 1)), 8.0)
        self.nx = max(int(np.ceil(w / self.cell)), 1)
        self.ny = max(int(np.ceil(h / self.cell)), 1)
        self.n_cells = self.nx * self.ny
        # each cell's first whole pixel (column, row) as cell_of places pixels: k * cell in
        # floating point can fall a hair short of a whole number its division does not reach
        # (cell 53.33...: 3 * cell == 160.0, yet 160 // cell == 2)
        self.x_edges = self._edges(w, self.nx)
        self.y_edges = self._edges(h, self.ny)

    def _edges(self, size: int, n: int) -> list[int]:
        at = np.minimum(np.arange(size + 1) // self.cell, n - 1)
        return np.searchsorted(at, np.arange(n + 1), side="left").tolist()  # type: ignore[no-any-return]

    def cell_of(self, uv: FloatArray) -> NDArray[np.int64]:
        """Each point's cell (row-major)."""
        row = np.minimum((uv[:, 1] // self.cell).astype(np.int64), self.ny - 1)
        col = np.minimum((uv[:, 0] // self.cell).astype(np.int64), self.nx - 1)
        return np.asarray(row * self.nx + col, np.int64)

    def runs(self, cells: NDArray[np.bool_]) -> list[tuple[int, int, int, int]]:
        """The boxes (x0, y0, x1, y1) of the runs of marked cells along each row of the grid:
        the whole pixels in them, the boxes not overlapping."""
        w, h = self.size
        xe, ye = self.x_edges, self.y_edges
        marked = cells.reshape(self.ny, self.nx)
        boxes = []
        for r in np.flatnonzero(marked.any(axis=1)).tolist():
            y0, y1 = ye[r], h if r == self.ny - 1 else ye[r + 1]
            cols = np.flatnonzero(marked[r]).tolist()
            start = cols[0]
            for prev, col in zip(cols, cols[1:] + [-1], strict=True):
                if col != prev + 1:  # (a run ends at prev)
                    boxes.append((xe[start], y0, w if prev == self.nx - 1 else xe[prev + 1], y1))
                    start = col
        return boxes


def spread(
    uv: FloatArray, score: FloatArray, want: int, size: tuple[int, int], strong: float
) -> NDArray[np.int64]:
    """Which of the corners ``uv`` (N, 2) with FAST scores ``score`` to keep, ``want`` at most,
    spread over a grid of about ``want`` cells in an image of ``size`` (w, h): in each cell its
    corners scoring ``strong`` or more if it has any (else its weaker ones), the best of each cell
    first, then the next best of every cell, by rounds, until ``want`` are kept."""
    n = len(uv)
    if n <= want:
        return np.arange(n, dtype=np.int64)
    cid = _Grid(size, want).cell_of(uv)
    has_strong = np.zeros(cid.max() + 1, bool)
    has_strong[cid[score >= strong]] = True
    usable = (score >= strong) | ~has_strong[cid]
    idx = np.flatnonzero(usable)
    order = idx[_by_then_best(cid[idx], score[idx])]  # by cell, best first
    cells = cid[order]
    first = np.r_[0, np.flatnonzero(np.diff(cells)) + 1]
    rank = np.arange(len(order)) - np.repeat(first, np.diff(np.r_[first, len(order)]))
    # round by round (each cell's best, then its second...), the stronger first in a round
    picked = order[_by_then_best(rank, score[order])][:want]
    if len(picked) < want:  # (too few usable: the weaker corners of strong cells fill in)
        rest = np.setdiff1d(np.arange(n), picked)
        picked = np.r_[picked, rest[np.argsort(-score[rest])][: want - len(picked)]]
    return np.sort(picked).astype(np.int64)


def _by_then_best(major: NDArray[np.int64], score: FloatArray) -> NDArray[np.int64]:
    """The order by ``major``, then by ``score`` high to low, then as given (a stable
    ``lexsort((-score, major))``); FAST's scores, whole numbers in [0, 255], in one key."""
    if len(score) and score.min() >= 0 and score.max() <= 255 and (score == np.rint(score)).all():
        key = major.astype(np.int64) * 256 + (255 - score.astype(np.int64))
        return np.argsort(key, kind="stable").astype(np.int64)
    return np.lexsort((-score, major)).astype(np.int64)


#: the offsets 1..15 from the disc's centre, and the disc's half-width at each (a row's or a
#: column's: the disc of radius 15 is symmetric)
_OFFSET = np.arange(1, PATCH_PX // 2 + 1)
_HALF = np.floor(np.sqrt((PATCH_PX // 2) ** 2 - _OFFSET**2) + 1e-9).astype(np.int64)


def orientations(img: NDArray[np.uint8], uv: FloatArray) -> FloatArray:
    """ORB's orientation (degrees in [0, 360)) of the keypoints ``uv`` (N, 2) of ``img``: the
    angle of the intensity centroid of the disc of radius 15 around each (rounded to its pixel);
    -1 where the disc leaves the image. The moments from the image's integral: ``m01`` sums
    each row of the disc times its offset, ``m10`` each column (whole numbers: exact)."""
    import cv2

    r = PATCH_PX // 2
    x = np.rint(uv[:, 0]).astype(np.int64)
    y = np.rint(uv[:, 1]).astype(np.int64)
    h, w = img.shape
    ok = (x - r >= 0) & (x + r < w) & (y - r >= 0) & (y + r < h)
    S = np.asarray(cv2.integral(img, sdepth=cv2.CV_32S)).ravel()  # (h + 1, w + 1), exact
    xo, yo, d, a = x[ok, None], y[ok, None], _OFFSET[None, :], _HALF[None, :]

    def box(y0: NDArray[np.int64], y1: NDArray[np.int64], x0: NDArray[np.int64],
            x1: NDArray[np.int64]) -> NDArray[np.int64]:  # fmt: skip
        """The sum of img[y0:y1, x0:x1]."""
        W = w + 1
        return np.asarray(S[y1 * W + x1] - S[y0 * W + x1] - S[y1 * W + x0] + S[y0 * W + x0])

    m01 = d * (
        box(yo + d, yo + d + 1, xo - a, xo + a + 1) - box(yo - d, yo - d + 1, xo - a, xo + a + 1)
    )
    m10 = d * (
        box(yo - a, yo + a + 1, xo + d, xo + d + 1) - box(yo - a, yo + a + 1, xo - d, xo - d + 1)
    )
    angle = np.full(len(uv), -1.0)
    m01_sum = m01.sum(axis=1).astype(np.float64)
    m10_sum = m10.sum(axis=1).astype(np.float64)
    angle[ok] = np.degrees(np.arctan2(m01_sum, m10_sum)) % 360.0
    return angle


def _empty(scales: FloatArray) -> OrbFeatures:
    z = np.zeros(0)
    return OrbFeatures(
        uv_px=np.zeros((0, 2)), octave=np.zeros(0, np.int64), angle_deg=z, response=z,
        size_px=z, descriptors=np.zeros((0, 32), np.uint8), scales=scales,
    )  # fmt: skip
