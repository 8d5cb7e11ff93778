"""Drawing on frames: marker outlines and ids, rejected candidates, the world axes, and a
status line (thesis 000 figure 3.5)."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.vision.markers import MarkerDetections, to_gray

__all__ = ["axis_polylines", "draw_overlay"]

FloatArray = NDArray[np.float64]

#: Points sampled along each axis: enough for the lens distortion to bend them as it should.
_AXIS_SAMPLES = 24


def _view_radius(camera: PinholeCamera) -> float:
    """The largest normalized radius (tan of the angle off the optical axis) at which a
    projection can be trusted: inside the image's corners and inside the range where the
    radial distortion still grows with the radius. Beyond the latter the polynomial folds
    back, and a point far outside the view projects into the image."""
    d = np.zeros(8)
    d[: min(8, camera.dist.size)] = camera.dist[:8]
    k1, k2, _, _, k3, k4, k5, k6 = d
    r = np.linspace(0.0, 4.0, 4001)
    r2 = r * r
    den = 1.0 + k4 * r2 + k5 * r2**2 + k6 * r2**3
    with np.errstate(divide="ignore", invalid="ignore"):
        rd = r * (1.0 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / den
    bad = (np.diff(rd) <= 0) | (den[1:] <= 0) | ~np.isfinite(rd[1:])
    n = int(np.argmax(bad)) + 1 if bad.any() else len(r)
    w, h = camera.width, camera.height
    corners = np.array([[0.0, 0.0, 1.0], [w, 0.0, 1.0], [w, h, 1.0], [0.0, h, 1.0]])
    rd_corner = float(np.max(np.linalg.norm((np.linalg.solve(camera.K, corners.T))[:2], axis=0)))
    if rd_corner >= rd[n - 1]:
        return float(r[n - 1])
    return float(np.interp(rd_corner, rd[:n], r[:n]))


def axis_polylines(
    camera: PinholeCamera, T_C_W: Pose, axis_m: float
) -> list[tuple[int, NDArray[np.int32]]]:
    """The parts of the world's x, y, z axes (``axis_m`` long) that the camera sees, as
    (axis index, pixel polyline) pairs; an axis out of view or behind the camera gives none.
    OpenCV's ``drawFrameAxes`` instead projects only the end points (wrong when they leave the
    view, and it warns on the terminal each time)."""
    r_max = _view_radius(camera)
    s = np.linspace(0.0, axis_m, _AXIS_SAMPLES)
    out: list[tuple[int, NDArray[np.int32]]] = []
    for k in range(3):
        p_W = np.zeros((_AXIS_SAMPLES, 3))
        p_W[:, k] = s
        p_C = T_C_W @ p_W
        z = p_C[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.linalg.norm(p_C[:, :2], axis=1) / z
        seen = (z > 1e-6) & (r < r_max)
        if seen.sum() < 2:
            continue
        px = camera.project(p_C[seen])
        # the longest run of consecutive samples in view (an axis enters the view once)
        idx = np.flatnonzero(seen)
        breaks = np.flatnonzero(np.diff(idx) > 1)
        starts = np.concatenate([[0], breaks + 1])
        ends = np.concatenate([breaks + 1, [len(idx)]])
        j = int(np.argmax(ends - starts))
        run = px[starts[j] : ends[j]]
        if len(run) >= 2:
            out.append((k, np.round(run).astype(np.int32).reshape(-1, 1, 2)))
    return out


def draw_overlay(
    image: NDArray[Any],
    detections: MarkerDetections,
    camera: PinholeCamera,
    T_C_W: Pose | None,
    *,
    axis_m: float = 0.1,
    text: str = "",
    rejected: FloatArray | None = None,
) -> NDArray[np.uint8]:
    """A BGR copy of ``image`` with the markers outlined and numbered, the ``rejected``
    candidates (N, 4, 2) outlined in pink (the thesis's ``show_rejected``) and, when the pose
    is known, the world frame's axes (x red, y green, z blue), clipped to the image."""
    img = (
        cv2.cvtColor(to_gray(image), cv2.COLOR_GRAY2BGR)
        if np.asarray(image).ndim == 2
        else np.array(image[..., :3], np.uint8)
    )
    if rejected is not None and len(rejected):
        cand = tuple(c.reshape(1, 4, 2).astype(np.float32) for c in rejected)
        cv2.aruco.drawDetectedMarkers(img, cand, None, (100, 0, 255))
    if len(detections):
        corners, ids = detections.as_opencv()
        cv2.aruco.drawDetectedMarkers(img, corners, ids)
    if T_C_W is not None:
        colours = ((0, 0, 255), (0, 255, 0), (255, 0, 0))
        for k, line in axis_polylines(camera, T_C_W, axis_m):
            cv2.polylines(img, [line], False, colours[k], 2, cv2.LINE_AA)
    if text:
        cv2.putText(
            img, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 255, 255), 1, cv2.LINE_AA
        )
    return np.asarray(img, np.uint8)
