"""Camera calibration from ChArUco views (``cv2.calibrateCamera`` on the interpolated
chessboard corners), rejecting views that would spoil it: too few corners, corners on one
line, or a reprojection error far above the others'."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VisionError
from quadnav.geometry.camera import PinholeCamera
from quadnav.vision.markers import CharucoDetections, CharucoTarget, get_dictionary

__all__ = ["BoardNames", "Calibration", "calibrate_charuco", "charuco_board_problem"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Calibration:
    """The camera, the overall RMS reprojection error (px), each used view's RMS error, and
    the views left out with the reason."""

    camera: PinholeCamera
    rms_px: float
    per_view_rms_px: dict[int, float]
    rejected: dict[int, str]


@dataclass(frozen=True, slots=True)
class BoardNames:
    """What the user calls a ChArUco board's settings (options or configuration keys)."""

    squares_x: str
    squares_y: str
    square_m: str
    marker_m: str
    dictionary: str


def charuco_board_problem(
    squares: tuple[int, int],
    square_m: float,
    marker_m: float,
    dictionary: str | int,
    names: BoardNames,
) -> str | None:
    """Why this ChArUco board cannot exist, in the user's own ``names``; ``None`` if it can.

    Checked before any work: at least 2x2 squares, positive finite sides with the marker
    inside its square, a known dictionary with a marker for every white square."""
    nx, ny = squares
    if min(nx, ny) < 2:
        if names.squares_x == names.squares_y:
            return f"{names.squares_x} must be at least 2 2 (across, down), got {nx} {ny}"
        name, n = (names.squares_x, nx) if nx < 2 else (names.squares_y, ny)
        return f"{name} must be at least 2, got {n}"
    for name, v in ((names.square_m, square_m), (names.marker_m, marker_m)):
        if not math.isfinite(v):
            return f"{name} must be a finite number of metres, got {v}"
        if v <= 0:
            return f"{name} must be positive, got {v:g}"
    if marker_m >= square_m:
        return (
            f"{names.marker_m} ({marker_m:g} m) must be smaller than "
            f"{names.square_m} ({square_m:g} m): the marker sits inside its square"
        )
    try:
        size = int(get_dictionary(dictionary).bytesList.shape[0])
    except VisionError as exc:
        return f"{names.dictionary}: {exc}"
    if nx * ny // 2 > size:
        squares_names = " and ".join(dict.fromkeys((names.squares_x, names.squares_y)))
        return (
            f"a {nx}x{ny} board needs {nx * ny // 2} markers, the dictionary {dictionary} has "
            f"{size}: fewer {squares_names} or a larger {names.dictionary}"
        )
    return None


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
