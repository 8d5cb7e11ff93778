"""Corners and their binary descriptors for a keyframe's image: what place recognition describes
besides an odometry's tracked corners (VINS-Mono's loop closure adds 500 corners of its own to the
tracked ones before describing them with BRIEF)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import PlaceError
from quadnav.vision.descriptors import orb_at
from quadnav.vision.tracking import as_grey

__all__ = ["describe_image"]


def describe_image(
    image: object,
    *,
    max_corners: int = 400,
    min_distance_px: float = 8.0,
    quality_level: float = 0.005,
) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """Up to ``max_corners`` Shi-Tomasi corners of ``image`` (grey or colour) at least
    ``min_distance_px`` apart, and their ORB/BRIEF descriptors: ``(N, 2)`` pixels and ``(N, 32)``
    uint8, only the corners that could be described (not at the border)."""
    import cv2

    if max_corners < 1 or not min_distance_px > 0 or not 0 < quality_level < 1:
        raise PlaceError(
            "describe_image: max_corners >= 1, min_distance_px > 0, 0 < quality_level < 1"
        )
    grey = as_grey(image)
    corners = cv2.goodFeaturesToTrack(
        grey, max_corners, quality_level, min_distance_px, blockSize=3
    )
    if corners is None:
        return np.zeros((0, 2)), np.zeros((0, 32), np.uint8)
    uv = corners.reshape(-1, 2).astype(np.float64)
    desc, ok = orb_at(grey, uv)
    return uv[ok], desc[ok]
