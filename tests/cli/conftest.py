"""Synthetic frames of marker 5 for the ``quadnav markers`` tests."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from quadnav.experiments.markers import look_at
from quadnav.geometry.camera import PinholeCamera, thesis_camera
from quadnav.geometry.rotations import Pose
from quadnav.io.opencv_yaml import write_camera_yaml
from quadnav.sim.camera import RenderSettings, SyntheticCamera, marker_object
from quadnav.vision.markers import get_dictionary


def marker_views(camera: PinholeCamera, n: int) -> tuple[list[np.ndarray], list[Pose]]:
    """``n`` renders of marker 5 (0.2335 m, DICT_4X4_250) from a camera drifting 1.2 m and
    up above it, and the camera poses ``T_W_C``."""
    scene = SyntheticCamera(camera, [marker_object(get_dictionary("DICT_4X4_250"), 5, 0.2335, Pose.identity())], RenderSettings(noise_sigma=2.0))  # fmt: skip
    truth = [
        look_at(np.array([0.02 * k, -0.01 * k, 1.2 + 0.04 * k]), np.zeros(3), 0.1 * k)
        for k in range(n)
    ]
    return [scene.render(T) for T in truth], truth


@pytest.fixture(scope="module")
def frames(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, list[Pose]]:
    """Ten renders of marker 5 from the thesis camera, the fourth one replaced by garbage
    bytes, as a folder of PNGs; and the camera's calibration file."""
    root = tmp_path_factory.mktemp("markers")
    cam = thesis_camera()
    images, truth = marker_views(cam, 10)
    folder = root / "frames"
    folder.mkdir()
    for k, img in enumerate(images):
        cv2.imwrite(str(folder / f"f{k:03d}.png"), img)
    (folder / "f003.png").write_bytes(b"\x89PNG garbage \x00\x01")
    cal = root / "cal.yml"
    write_camera_yaml(cal, cam)
    return folder, cal, truth
