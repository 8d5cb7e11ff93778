"""The overlay: world axes clipped to the image (no OpenCV warning on the terminal), nothing
drawn for axes behind the camera, rejected candidates outlined."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.geometry.camera import thesis_camera
from quadnav.geometry.rotations import Pose
from quadnav.vision.markers import MarkerDetections
from quadnav.vision.overlay import axis_polylines, draw_overlay

NONE = MarkerDetections.from_opencv((), None)


def _colour_mask(img: np.ndarray, bgr: tuple[int, int, int]) -> np.ndarray:
    return np.all(np.abs(img.astype(int) - np.array(bgr)) < 60, axis=2)


def test_axes_leaving_the_image_are_clipped_without_a_warning(
    capfd: pytest.CaptureFixture[str],
) -> None:
    cam = thesis_camera()
    # the world origin 1 m ahead, near the right edge: its 1 m x axis runs far out of the image
    T_C_W = Pose(Rotation.identity(), np.array([0.5, 0.0, 1.0]))
    img = draw_overlay(np.zeros((480, 640), np.uint8), NONE, cam, T_C_W, axis_m=1.0)
    err = capfd.readouterr().err
    assert "drawFrameAxes" not in err and "WARN" not in err, err
    origin = cam.project(np.array([[0.5, 0.0, 1.0]]))[0]
    red = _colour_mask(img, (0, 0, 255))
    ys, xs = np.nonzero(red)
    # the x axis is drawn from the origin to the image's right edge, and only there
    assert xs.min() == pytest.approx(origin[0], abs=3) and xs.max() >= 638
    assert np.all(np.abs(ys - origin[1]) < 25)


def test_axes_behind_the_camera_are_not_drawn(capfd: pytest.CaptureFixture[str]) -> None:
    cam = thesis_camera()
    T_C_W = Pose(Rotation.identity(), np.array([0.0, 0.0, -0.5]))  # world origin behind
    assert axis_polylines(cam, T_C_W, 0.1) == []
    img = draw_overlay(np.zeros((480, 640), np.uint8), NONE, cam, T_C_W)
    assert not img.any()
    # far off to the side (70 degrees), where the distortion polynomial would fold the
    # projection back into the image
    T_side = Pose(Rotation.identity(), np.array([2.75, 0.0, 1.0]))
    assert axis_polylines(cam, T_side, 0.1) == []
    assert "WARN" not in capfd.readouterr().err


def test_rejected_candidates_are_outlined() -> None:
    cam = thesis_camera()
    quad = np.array([[[100.0, 100.0], [200.0, 100.0], [200.0, 200.0], [100.0, 200.0]]])
    img = draw_overlay(np.zeros((480, 640), np.uint8), NONE, cam, None, rejected=quad)
    pink = _colour_mask(img, (100, 0, 255))
    assert pink[100, 150] and pink[150, 200] and not pink[150, 150] and pink.sum() < 1200
    assert not draw_overlay(np.zeros((480, 640), np.uint8), NONE, cam, None).any()
