"""Drawing on frames: marker outlines and ids, the world axes, and a status line (thesis 000
figure 3.5)."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.rotations import Pose
from quadnav.vision.camera import PinholeCamera
from quadnav.vision.markers import MarkerDetections, to_gray

__all__ = ["draw_overlay"]


def draw_overlay(
    image: NDArray[Any],
    detections: MarkerDetections,
    camera: PinholeCamera,
    T_C_W: Pose | None,
    *,
    axis_m: float = 0.1,
    text: str = "",
) -> NDArray[np.uint8]:
    """A BGR copy of ``image`` with the markers outlined and numbered and, when the pose is
    known, the world frame's axes (x red, y green, z blue)."""
    img = (
        cv2.cvtColor(to_gray(image), cv2.COLOR_GRAY2BGR)
        if np.asarray(image).ndim == 2
        else np.array(image[..., :3], np.uint8)
    )
    if len(detections):
        corners, ids = detections.as_opencv()
        cv2.aruco.drawDetectedMarkers(img, corners, ids)
    if T_C_W is not None:
        rvec = T_C_W.R_A_B.as_rotvec()
        cv2.drawFrameAxes(img, camera.K, camera.dist, rvec, T_C_W.p_A_B, axis_m, 2)
    if text:
        cv2.putText(
            img, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 255, 255), 1, cv2.LINE_AA
        )
    return np.asarray(img, np.uint8)
