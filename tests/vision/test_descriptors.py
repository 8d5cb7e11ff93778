"""ORB descriptors at given corners: described where the patch fits, zeros and False elsewhere,
and the same corner in a shifted image gets the same descriptor."""

from __future__ import annotations

import numpy as np
import pytest
from skimage import data

from quadnav.errors import VisionError
from quadnav.vision.descriptors import orb_at


def test_described_inside_not_at_the_border_nor_nan() -> None:
    img = np.ascontiguousarray(data.camera()[:480, :512])
    uv = np.array([[100.0, 120.0], [5.0, 200.0], [300.0, 470.0], [np.nan, 10.0], [250.0, 250.0]])
    d, ok = orb_at(img, uv)
    assert ok.tolist() == [True, False, False, False, True]
    assert not d[~ok].any() and d[ok].any(axis=1).all()


def test_a_shifted_image_gives_the_same_descriptor() -> None:
    img = np.ascontiguousarray(data.camera()[:400, :400])
    shifted = np.ascontiguousarray(data.camera()[7:407, 11:411])
    uv = np.array([[200.0, 150.0], [120.0, 300.0]])
    a, _ = orb_at(img, uv)
    b, _ = orb_at(shifted, uv - [11.0, 7.0])
    assert np.array_equal(a, b)
    c, _ = orb_at(img, uv[::-1])  # another corner's: far from it
    assert np.unpackbits(a ^ c, axis=1).sum(axis=1).min() > 40


def test_too_small_an_image_is_one_error() -> None:
    with pytest.raises(VisionError, match="too small"):
        orb_at(np.zeros((40, 40), np.uint8), np.array([[20.0, 20.0]]))
