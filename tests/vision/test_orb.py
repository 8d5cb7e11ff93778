"""ORB in a scale pyramid, spread over the image (issue 24, item 1): ORB-SLAM2's share of
features per level, and the spread against OpenCV's plain ORB on the same picture."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from skimage import data

from quadnav.errors import VisionError
from quadnav.vision.orb import OrbConfig, OrbExtractor, _Grid, level_shares, spread


@pytest.fixture(scope="module")
def photo() -> np.ndarray:
    return cv2.resize(data.camera(), (752, 480))


def test_each_level_gets_orb_slam_s_share() -> None:
    s = level_shares(OrbConfig())
    # ORB-SLAM2: n (1 - 1/s^2) / (1 - 1/s^16) at level 0, then 1/1.44 of the one before
    assert s.sum() == 1200 and s[0] == round(1200 * (1 - 1 / 1.44) / (1 - 1.44**-8))
    assert np.allclose(s[1:7] / s[:6], 1 / 1.44, atol=0.015)  # (rounded to whole features)
    assert level_shares(OrbConfig(n_features=10, n_levels=1)).tolist() == [10]


def test_features_per_level_descriptors_and_positions(photo: np.ndarray) -> None:
    f, levels = OrbExtractor().extract(photo)
    assert len(f) == 1200 and len(levels) == 8
    assert np.bincount(f.octave, minlength=8).tolist() == level_shares(OrbConfig()).tolist()
    assert f.descriptors.shape == (1200, 32) and f.descriptors.dtype == np.uint8
    assert ((f.uv_px >= 0) & (f.uv_px < [752, 480])).all()
    assert np.allclose(f.size_px, 31 * f.scales[f.octave])
    # a level-3 keypoint read back at level 3 lies on a FAST corner of that level's image
    k = np.flatnonzero(f.octave == 3)[0]
    x, y = np.rint(f.uv_px[k] / f.scales[3]).astype(int)
    fast = cv2.FastFeatureDetector.create(7).detect(levels[3])
    assert min(np.hypot(p.pt[0] - x, p.pt[1] - y) for p in fast) <= 1.0


def test_spread_over_the_picture_better_than_plain_orb(photo: np.ndarray) -> None:
    """Level 0's features in a 10 x 6 grid: more cells hold one, and the fullest holds fewer,
    than OpenCV's ORB with the same budget (which takes the strongest corners wherever)."""
    f, _ = OrbExtractor().extract(photo)
    ours = f.uv_px[f.octave == 0]
    plain = cv2.ORB.create(nfeatures=1200, scaleFactor=1.2, nlevels=8).detect(photo)
    theirs = np.array([k.pt for k in plain if k.octave == 0])

    def cells(uv: np.ndarray) -> np.ndarray:
        c = (uv[:, 1] // 80).astype(int) * 10 + (uv[:, 0] // 75.2).astype(int)
        return np.bincount(c, minlength=60)

    a, b = cells(ours), cells(theirs)
    assert (a > 0).sum() > (b > 0).sum()
    assert a.max() / len(ours) < 0.7 * b.max() / len(theirs)


def test_spread_takes_weak_corners_where_a_cell_has_no_strong_one() -> None:
    rng = np.random.default_rng(0)
    strong = rng.uniform(0, 50, (200, 2))  # all in the top-left cell area
    weak = rng.uniform(50, 400, (100, 2))
    uv = np.vstack([strong, weak])
    score = np.r_[np.full(200, 60.0), np.full(100, 10.0)]
    keep = spread(uv, score, 64, (400, 400), strong=20.0)
    assert len(keep) == 64
    assert (keep >= 200).sum() >= 40  # most of the picture is weak texture: it is kept


def test_bad_settings_and_images_are_one_line() -> None:
    with pytest.raises(VisionError, match="scale_factor"):
        OrbConfig(scale_factor=1.0)
    with pytest.raises(VisionError, match="min_fast <= ini_fast"):
        OrbConfig(min_fast=30, ini_fast=20)
    with pytest.raises(VisionError, match="too small"):
        OrbExtractor().extract(np.zeros((20, 20), np.uint8))
    f, _ = OrbExtractor().extract(np.zeros((480, 752), np.uint8))  # no texture: no features
    assert len(f) == 0 and f.descriptors.shape == (0, 32)


@pytest.mark.parametrize("theta_deg", [0.0, 37.0, 90.0, 163.0, 250.0, 321.0])
def test_orientation_points_to_the_bright_side(theta_deg: float) -> None:
    """A bright half-plane turned by theta about the keypoint: the intensity centroid of the
    disc lies along theta (to 1.5 degrees: the pixel grid); a keypoint whose disc leaves the
    image gets -1."""
    from quadnav.vision.orb import orientations

    t = np.radians(theta_deg)
    yy, xx = np.mgrid[0:100, 0:120].astype(float)
    side = (xx - 60.0) * np.cos(t) + (yy - 50.0) * np.sin(t)  # (a smooth edge through it)
    img = np.rint(115.0 + 85.0 * np.tanh(side / 2.0)).astype(np.uint8)
    got = orientations(img, np.array([[60.0, 50.0], [10.0, 50.0], [60.0, 90.0]]))
    assert abs((got[0] - theta_deg + 180.0) % 360.0 - 180.0) < 1.5, got[0]
    assert got[1] == -1.0 and got[2] == -1.0


def _every_corner_then_spread(ex: OrbExtractor, img: np.ndarray, want: int) -> np.ndarray:
    """The reference for the extractor's candidates: FAST at ``min_fast`` over the whole level
    (inside ORB's border), then :func:`spread` (what the extractor did before it looked for weak
    corners only where a cell lacks a strong one)."""
    fast = cv2.FastFeatureDetector.create(ex.config.min_fast, nonmaxSuppression=True)
    h, w = img.shape
    found = fast.detect(img)
    uv = np.array([k.pt for k in found], np.float64).reshape(-1, 2)
    score = np.array([k.response for k in found], np.float64)
    e = 19
    ok = (uv[:, 0] >= e) & (uv[:, 0] < w - e) & (uv[:, 1] >= e) & (uv[:, 1] < h - e)
    uv, score = uv[ok], score[ok]
    return uv[spread(uv, score, want, (w, h), ex.config.ini_fast)]


def _half_blank(photo: np.ndarray) -> np.ndarray:
    img = photo.copy()
    img[:, 300:] = cv2.GaussianBlur(img[:, 300:], (0, 0), 6)  # weak texture: weak corners
    img[300:, :200] = 90  # no texture at all
    return img


@pytest.mark.parametrize("case", ["photo", "half_blank", "astronaut", "noise"])
def test_weak_corners_looked_for_only_where_needed_choose_the_same_features(
    photo: np.ndarray, case: str
) -> None:
    """The extractor runs FAST at ``min_fast`` only in the grid cells with no corner at
    ``ini_fast``; the features it keeps must be exactly those the whole level's corners give."""
    img = {
        "photo": photo,
        "half_blank": _half_blank(photo),
        "astronaut": cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2GRAY)[::2, ::2],
        "noise": np.random.default_rng(3).integers(0, 40, (240, 376)).astype(np.uint8),
    }[case]
    ex = OrbExtractor()
    levels = ex.pyramid(img)
    n_weak_cells = 0
    for k, level in enumerate(levels):
        want = int(level_shares(ex.config)[k])
        expected = _every_corner_then_spread(ex, level, want)
        for _ in range(2):  # (the second time, the way the first chose: one pass or two)
            uv, score = ex._candidates(level, want, k)
            size = (level.shape[1], level.shape[0])
            picked = uv[spread(uv, score, want, size, ex.config.ini_fast)]
            np.testing.assert_array_equal(picked, expected)
        n_weak_cells += int((score < ex.config.ini_fast).sum())
    assert set(ex._weak_share) == set(range(len(levels)))
    if case == "half_blank":
        assert n_weak_cells > 0  # (the case exercises the weak cells' search)


@pytest.mark.parametrize(
    ("w", "h", "want"), [(640, 480, 108), (752, 480, 388), (1280, 720, 250), (101, 57, 7)]
)
def test_a_cells_box_holds_exactly_the_pixels_the_grid_puts_in_it(
    w: int, h: int, want: int
) -> None:
    """The weak corners are looked for in boxes of whole pixels; each cell's box must hold the
    pixels :func:`spread`'s grid places in that cell and no other, also where the cell's size is
    a fraction whose multiple falls a hair short of a whole number (640x480 for 108 features:
    3 x 53.33... is 160.0, yet pixel 160 is in cell 2)."""
    grid = _Grid((w, h), want)
    xs, ys = np.meshgrid(np.arange(w), np.arange(h))
    cell = grid.cell_of(np.column_stack([xs.ravel(), ys.ravel()]).astype(float)).reshape(h, w)
    for c in range(grid.n_cells):
        one = np.zeros(grid.n_cells, bool)
        one[c] = True
        ((x0, y0, x1, y1),) = grid.runs(one)
        box = (xs >= x0) & (xs < x1) & (ys >= y0) & (ys < y1)
        assert ((cell == c) == box).all(), c


def test_a_weak_corner_on_a_cells_first_column_is_found() -> None:
    """A weak corner alone in its cell on the column where the cell begins (the case a box edge
    one pixel off missed: 333 features at 640x480, level 0's cells 53.33... wide)."""
    ex = OrbExtractor(OrbConfig(n_features=333))
    img = np.full((480, 640), 100, np.uint8)
    img[:, 175:] = np.random.default_rng(1).integers(0, 255, (480, 465))  # strong, to the right
    img[200, 160] = 110  # one weak corner in the third column of cells
    want = int(level_shares(ex.config)[0])
    assert any((_every_corner_then_spread(ex, img, want) == [160, 200]).all(axis=1))
    features, _ = ex.extract(img)
    assert (np.abs(features.uv_px - [160, 200]).sum(axis=1) < 1e-9).any()
