"""Binary descriptors at given keypoints (ORB's rotated BRIEF, OpenCV): what a keyframe's
tracked corners carry for place recognition and map matching (VINS-Mono describes its
keyframes' corners with BRIEF the same way, after tracking them by KLT)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VisionError
from quadnav.vision.tracking import as_grey

__all__ = ["ORB_BYTES", "orb_at"]

#: Bytes of an ORB descriptor (256 bits).
ORB_BYTES = 32
#: ORB's patch (BRIEF's pairs lie within it).
_PATCH_PX = 31
#: Unsteered, BRIEF's pairs reach 15 px from the keypoint: one closer to the border than this
#: is not described (ORB's default, 31, is for pairs rotated by any angle).
_BORDER_PX = 16


def orb_at(
    image: NDArray[np.uint8], uv_px: NDArray[np.float64]
) -> tuple[NDArray[np.uint8], NDArray[np.bool_]]:
    """ORB's BRIEF descriptors ``(N, 32)`` at the pixels ``uv_px`` ``(N, 2)`` of ``image`` (grey
    or colour), unsteered (angle 0, as VINS-Mono's BRIEF: a hovering vehicle's image turns
    little between visits), and which keypoints could be described
    (those within 16 px of the border, or non-finite, get a row of zeros and False)."""
    import cv2

    uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
    out = np.zeros((len(uv), ORB_BYTES), np.uint8)
    ok = np.zeros(len(uv), bool)
    if len(uv) == 0:
        return out, ok
    grey = as_grey(image)
    if grey.ndim != 2 or min(grey.shape) <= 2 * _PATCH_PX:
        raise VisionError(f"an image of {grey.shape} is too small to describe keypoints in")
    finite = np.flatnonzero(np.isfinite(uv).all(axis=1))
    kps = [
        cv2.KeyPoint(x, y, _PATCH_PX, 0.0, 0, 0, i)
        for (x, y), i in zip(uv[finite].tolist(), finite.tolist(), strict=True)
    ]
    orb = cv2.ORB.create(edgeThreshold=_BORDER_PX, patchSize=_PATCH_PX)
    kept, desc = orb.compute(grey, kps)
    if desc is None or not kept:
        return out, ok
    idx = np.array([k.class_id for k in kept], np.int64)
    out[idx] = desc
    ok[idx] = True
    return out, ok
