"""Camera calibration from ChArUco views (``cv2.calibrateCamera`` on the interpolated
chessboard corners), rejecting views that would spoil it: too few corners, corners on one
line, or a reprojection error far above the others'."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VisionError
from quadnav.geometry.camera import PinholeCamera
from quadnav.vision.markers import CharucoDetections, CharucoTarget

__all__ = ["Calibration", "calibrate_charuco"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Calibration:
    """The camera, the overall RMS reprojection error (px), each used view's RMS error, and
    the views left out with the reason."""

    camera: PinholeCamera
    rms_px: float
    per_view_rms_px: dict[int, float]
    rejected: dict[int, str]


def calibrate_charuco(
    views: list[CharucoDetections],
    target: CharucoTarget,
    image_size: tuple[int, int],
    *,
    min_corners: int = 8,
    outlier_factor: float = 3.0,
    min_views: int = 3,
) -> Calibration:
    """Calibrate from ChArUco detections (one per view; ``image_size`` = (width, height))."""
    rejected: dict[int, str] = {}
    obj_all: dict[int, NDArray[np.float32]] = {}
    img_all: dict[int, NDArray[np.float32]] = {}
    for k, det in enumerate(views):
        if len(det.corner_ids) < min_corners:
            rejected[k] = f"{len(det.corner_ids)} corners (< {min_corners})"
            continue
        if target.board.checkCharucoCornersCollinear(
            det.corner_ids.reshape(-1, 1).astype(np.int32)
        ):
            rejected[k] = "corners on one line"
            continue
        obj_all[k] = target.chessboard_corners[det.corner_ids].astype(np.float32).reshape(-1, 1, 3)
        img_all[k] = det.corners.astype(np.float32).reshape(-1, 1, 2)
    used = list(obj_all)
    for _ in range(3):
        if len(used) < min_views:
            raise VisionError(
                f"calibration needs at least {min_views} good views, got {len(used)} ({len(rejected)} rejected)"
            )
        rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(
            [obj_all[k] for k in used], [img_all[k] for k in used], image_size, None, None
        )
        per_view: dict[int, float] = {}
        for k, rv, tv in zip(used, rvecs, tvecs, strict=True):
            proj, _ = cv2.projectPoints(obj_all[k], rv, tv, K, dist)
            per_view[k] = float(np.sqrt(np.mean(np.sum((proj - img_all[k]) ** 2, axis=2))))
        limit = max(outlier_factor * float(np.median(list(per_view.values()))), 1.0)
        bad = [k for k, e in per_view.items() if e > limit]
        if not bad or len(used) - len(bad) < min_views:
            break
        for k in bad:
            rejected[k] = f"reprojection error {per_view[k]:.2f} px > {limit:.2f}"
        used = [k for k in used if k not in bad]
    cam = PinholeCamera(
        np.asarray(K, np.float64), np.asarray(dist, np.float64).ravel(), *image_size
    )
    return Calibration(cam, float(rms), per_view, rejected)
