"""Textures: scikit-image's photos load offline in grey, procedural ones are seeded and tile,
all have corners at several scales; bad names are clear errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from quadnav.errors import SimError
from quadnav.sim.textures import PHOTOS, PROCEDURAL, flat_texture, make_texture, photo


@pytest.mark.parametrize("name", PHOTOS)
def test_photos_load_grey_square_and_stretched(name: str) -> None:
    img = photo(name)
    assert img.shape == (512, 512) and img.dtype == np.uint8
    assert not img.flags.writeable and photo(name) is img  # cached and shared read-only
    assert img.std() > 20 and img.min() < 40 and img.max() > 210


@pytest.mark.parametrize("kind", sorted(PROCEDURAL))
def test_procedural_textures_are_seeded_and_tile_without_seams(kind: str) -> None:
    a, b, c = make_texture(kind, 1), make_texture(kind, 1), make_texture(kind, 2)
    assert a is b and not np.array_equal(a, c)
    f = a.astype(float)
    for g in (f, f.T):  # across columns, then across rows
        steps = np.abs(np.diff(g, axis=1)).mean(axis=0)  # one per pair of neighbouring columns
        seam = np.abs(g[:, 0] - g[:, -1]).mean()  # across the tile edge, as when repeated
        assert seam <= 1.1 * steps.max()


@pytest.mark.parametrize("kind", [*sorted(PROCEDURAL), "brick", "gravel", "grass"])
def test_textures_have_corners_at_several_scales(kind: str) -> None:
    img = make_texture(kind, 3)
    for level in range(3):  # 512, 256, 128 texels: near, middle and far
        found = cv2.goodFeaturesToTrack(img, 200, 0.01, 5)
        assert found is not None and len(found) >= 20, f"level {level}"
        img = cv2.pyrDown(img)


def test_flat_texture_is_texture_poor() -> None:
    flat = flat_texture(4)
    assert flat.std() < 5 and 80 < flat.mean() < 210
    assert make_texture("noise", 4).std() > 20


def test_unknown_texture_and_bad_size_are_clear_errors() -> None:
    with pytest.raises(SimError, match=r"unknown texture 'marble'.*noise"):
        make_texture("marble")
    with pytest.raises(SimError, match="unknown photo texture"):
        photo("lena")
    with pytest.raises(SimError, match="power of two"):
        make_texture("noise", 0, 300)
