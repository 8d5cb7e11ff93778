"""The realism study's pieces: the sway has its peak rate, a warped view is the rotated camera's."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from quadnav.experiments.track_study import crop_camera, image_stats, sway, warped_views


def test_the_sway_turns_at_its_peak_rate() -> None:
    rots = sway(60.0, 400, 200.0)
    rates = [np.degrees((a.inv() * b).magnitude()) * 200.0 for a, b in itertools.pairwise(rots)]
    assert max(rates) == pytest.approx(60.0, rel=0.15)


def test_a_warped_view_is_what_the_turned_camera_sees() -> None:
    """A bright dot straight ahead moves to f tan(yaw) left of centre when the camera yaws."""
    K = np.array([[400.0, 0.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]])
    img = np.zeros((480, 640), np.uint8)
    img[238:243, 318:323] = 255  # a dot at the principal point
    view = crop_camera(K, 321, 241)
    from scipy.spatial.transform import Rotation

    (same,) = warped_views(img, K, view, [Rotation.identity()])
    ys, xs = np.nonzero(same > 128)
    assert (xs.mean(), ys.mean()) == pytest.approx((160.0, 120.0), abs=0.01)
    (turned,) = warped_views(img, K, view, [Rotation.from_euler("Y", 5.0, degrees=True)])
    ys, xs = np.nonzero(turned > 128)
    # yaw right (about +y, down) by 5 deg: what was ahead is now 400 tan(5 deg) px to the left
    assert xs.mean() == pytest.approx(160.0 - 400.0 * np.tan(np.radians(5.0)), abs=0.3)


def test_image_statistics_tell_flat_from_textured() -> None:
    rng = np.random.default_rng(0)
    flat = [np.full((120, 160), 128, np.uint8)] * 3
    busy = [rng.integers(0, 256, (120, 160), dtype=np.uint8) for _ in range(3)]
    f, b = image_stats(iter(flat)), image_stats(iter(busy))
    assert f.contrast == 0.0 and f.corners == 0 and f.gradient == 0.0
    assert b.contrast > 60 and b.corners > 50 and b.gradient > 20
    assert f.mean_grey == 128.0
