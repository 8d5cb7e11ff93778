"""Calibration from OpenCV's tutorial ChArUco views (../shared/data/aruco)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from quadnav.errors import VisionError
from quadnav.experiments.markers import look_at
from quadnav.geometry.camera import PinholeCamera, thesis_camera
from quadnav.geometry.rotations import Pose
from quadnav.io.opencv_yaml import read_camera_yaml
from quadnav.sim.camera import RenderSettings, SyntheticCamera, board_object
from quadnav.vision.calibration import calibrate_charuco, judge_calibration
from quadnav.vision.markers import CharucoDetections, CharucoSpec, CharucoTarget
from quadnav.vision.pose import solve_pnp
from tests.shared_data import SHARED, needs

DATA = SHARED / "aruco"
needs_data = needs(DATA)
VIEWS = ["img_00.jpg", "img_02.jpg", "img_03.jpg"]


@needs_data
def test_calibration_from_the_tutorial_views_fits_them_as_well_as_opencvs() -> None:
    target = CharucoTarget(CharucoSpec(5, 7, 0.04, 0.02, "DICT_6X6_250"))
    views = [target.detect(cv2.imread(str(DATA / f))) for f in VIEWS]
    cal = calibrate_charuco(views, target, (640, 480))
    ref = read_camera_yaml(DATA / "tutorial_camera_charuco.yml")
    assert cal.rms_px < 0.25  # OpenCV's own: 0.18 px
    assert not cal.rejected
    # Focal lengths: 3.3 % and 2.3 % above OpenCV's (the 2 % is not met). OpenCV used a
    # fourth view, img_01, that is not shipped; with these three, both calibrations fit every
    # view equally well (checked below), so the focal length is not determined any closer.
    assert abs(cal.camera.fx / ref.fx - 1) < 0.04 and abs(cal.camera.fy / ref.fy - 1) < 0.04
    for v in views:
        ours = solve_pnp(target.chessboard_corners[v.corner_ids], v.corners, cal.camera).rms_px
        theirs = solve_pnp(target.chessboard_corners[v.corner_ids], v.corners, ref).rms_px
        assert ours <= theirs + 0.02


@needs_data
def test_bad_views_are_rejected_with_a_reason() -> None:
    target = CharucoTarget(CharucoSpec(5, 7, 0.04, 0.02, "DICT_6X6_250"))
    views = [target.detect(cv2.imread(str(DATA / f))) for f in VIEWS]
    img = cv2.imread(str(DATA / "img_00.jpg"))
    img[:, 200:] = 255  # most of the board hidden: too few corners
    views.append(target.detect(img))
    # a view with corners shifted by 6 px: it would spoil the calibration
    bad = target.detect(cv2.imread(str(DATA / "img_02.jpg")))
    views.append(
        type(bad)(
            bad.corner_ids,
            bad.corners + np.where(bad.corner_ids[:, None] % 2 == 0, 6.0, -6.0),
            bad.markers,
        )
    )
    cal = calibrate_charuco(views, target, (640, 480), min_views=3)
    assert "corners" in cal.rejected[3]
    assert "reprojection error" in cal.rejected[4]
    assert cal.rms_px < 0.25
    with pytest.raises(VisionError, match="at least 3 good views"):
        calibrate_charuco(views[3:], target, (640, 480))


def _tutorial() -> tuple[CharucoTarget, list[CharucoDetections]]:
    target = CharucoTarget(CharucoSpec(5, 7, 0.04, 0.02, "DICT_6X6_250"))
    return target, [target.detect(cv2.imread(str(DATA / f))) for f in VIEWS]


@needs_data
def test_the_tutorial_calibration_is_kept_with_its_weaknesses_said() -> None:
    """Issue 21, item 13: the three tutorial views make a usable calibration, but a weak one:
    the solver's 1-sigma of fx is about 3 %, and OpenCV's own result (four views) lies within
    3 sigma of ours; the board reaches a third of the image, at nearly one angle. All said."""
    target, views = _tutorial()
    cal = calibrate_charuco(views, target, (640, 480))
    ref = read_camera_yaml(DATA / "tutorial_camera_charuco.yml")
    sd = cal.std_intrinsics
    for name, ours, theirs in (("fx", cal.camera.fx, ref.fx), ("fy", cal.camera.fy, ref.fy),
                               ("cx", cal.camera.K[0, 2], ref.K[0, 2]),
                               ("cy", cal.camera.K[1, 2], ref.K[1, 2])):  # fmt: skip
        assert sd[name] > 0 and abs(ours - theirs) < 3 * sd[name], (name, ours, theirs, sd[name])
    assert 0.02 < sd["fx"] / cal.camera.fx < 0.05
    assert 0.2 < cal.coverage < 0.5 and cal.spread_deg < 10
    said = " | ".join(cal.warnings)
    assert "focal length is known to +-3." in said and "reach 31% of the image" in said
    assert "nearly one angle" in said and len(cal.warnings) == 3


@needs_data
def test_views_all_from_one_pose_are_refused_with_the_reason() -> None:
    """The same view three times gave fx = 160 px (OpenCV's 453) with 0.11 px and exit 0."""
    target, views = _tutorial()
    with pytest.raises(VisionError, match="from only 1 distinct pose") as info:
        calibrate_charuco([views[0]] * 3, target, (640, 480))
    assert "\n" not in str(info.value) and "3 views used, none rejected" in str(info.value)


@needs_data
def test_too_few_views_are_refused_with_the_rejections_counted_by_reason() -> None:
    """Two good views (the least is 3, now said) and three bad ones: the refusal counts the
    rejections by reason instead of only their number."""
    target, views = _tutorial()
    img = cv2.imread(str(DATA / "img_00.jpg"))
    hidden = [img.copy() for _ in range(3)]
    for k, h in enumerate(hidden):
        h[:, 150 + 30 * k :] = 255  # most of the board hidden: too few corners
    bad = [target.detect(h) for h in hidden]
    with pytest.raises(VisionError) as info:
        calibrate_charuco([views[0], *bad, views[1]], target, (640, 480))
    msg = str(info.value)
    counted = "got 2 of 5 (3 rejected: 3 too few corners)"
    assert msg.startswith(f"calibration needs at least 3 good views, {counted}"), msg
    assert "8 or more of the board's corners" in msg and "\n" not in msg


def _three_poses() -> list[tuple[np.ndarray, np.ndarray]]:
    return [(np.array([0.4 * k - 0.4, 0.3, 0.0]), np.array([0.0, 0.0, 0.5])) for k in range(3)]


def test_an_impossible_camera_is_refused_and_a_weak_one_warned() -> None:
    """The issue's 4-view result (k3 = -5439, fx/fy 1499/1334): its distortion folds back
    inside the image and its pixels are 12 % from square: refused, each reason said. The same
    camera with a lens that grows monotonically and fx = fy passes those checks."""
    grid = np.stack(np.meshgrid(np.linspace(150, 490, 8), np.linspace(110, 370, 6)), -1)
    corners = [grid.reshape(-1, 2)] * 3
    sd = {"fx": 5.0, "fy": 5.0, "cx": 2.0, "cy": 2.0}
    K = np.array([[1499.0, 0, 320], [0, 1334.0, 240], [0, 0, 1]])
    bad = PinholeCamera(K, np.array([0.5, -30.0, 0, 0, -5439.0]), 640, 480)
    j = judge_calibration(bad, sd, 0.3, {0: 0.3, 1: 0.3, 2: 0.3}, corners, _three_poses())
    assert any("folds back" in r for r in j.refusals)
    assert any("fx and fy differ by 12%" in r for r in j.refusals)
    K[1, 1] = 1499.0
    good = PinholeCamera(K, np.array([0.1, -0.2, 0, 0, 0.1]), 640, 480)
    j = judge_calibration(good, sd, 0.3, {0: 0.3, 1: 0.3, 2: 0.3}, corners, _three_poses())
    assert j.refusals == () and j.distinct_poses == 3 and j.spread_deg > 10
    K_outside = np.array([[500.0, 0, -120], [0, 500.0, 240], [0, 0, 1]])
    outside = PinholeCamera(K_outside, np.zeros(5), 640, 480)
    loose = {**sd, "fx": 80.0}  # 16 % of fx
    j = judge_calibration(outside, loose, 2.5, {0: 2.5, 1: 2.0, 2: 3.1}, corners, _three_poses())
    said = " | ".join(j.refusals)
    assert "principal point (-120, 240) px is outside the 640x480 image" in said
    assert "do not determine fx 500 +- 80 px" in said
    assert any("RMS reprojection error 2.50 px" in w and "3.10 px" in w for w in j.warnings)


TUTORIAL_BOARD = CharucoSpec(5, 7, 0.04, 0.02, "DICT_6X6_250")
BOARD_CENTRE = np.array([0.1, 0.14, 0.0])  # of the 0.2 x 0.28 m board, in its face frame


def _render(eye: np.ndarray, aim: np.ndarray, roll_rad: float, seed: int = 0) -> np.ndarray:
    """The thesis camera's image of the tutorial board (the project's board renderer)."""
    board = board_object(CharucoTarget(TUTORIAL_BOARD).board, (0.2, 0.28), Pose.identity())
    scene = SyntheticCamera(thesis_camera(), [board], RenderSettings(noise_sigma=2.0, seed=seed))
    return scene.render(look_at(eye, aim, roll_rad))


def test_renders_from_twelve_poses_calibrate_the_thesis_camera_without_a_warning() -> None:
    """Twelve renders, 0.3 m away, tilted 20-32 deg in twelve directions, aimed round the
    board so its corners reach most of the image: the thesis camera's intrinsics to 0.2 %,
    nothing to warn about."""
    target, views = CharucoTarget(TUTORIAL_BOARD), []
    for k in range(12):
        a, tilt = 2 * np.pi * k / 12, 0.35 + 0.1 * (k % 3)
        direction = [np.sin(tilt) * np.cos(a), np.sin(tilt) * np.sin(a), np.cos(tilt)]
        eye = BOARD_CENTRE + 0.3 * np.array(direction)
        aim = BOARD_CENTRE + 0.07 * np.array([np.cos(3 * a), np.sin(3 * a), 0.0])
        views.append(target.detect(_render(eye, aim, 0.3 * k)))
    cal = calibrate_charuco(views, target, (640, 480))
    truth = thesis_camera()
    assert abs(cal.camera.fx / truth.fx - 1) < 0.002 and abs(cal.camera.fy / truth.fy - 1) < 0.002
    assert np.allclose(cal.camera.K[:2, 2], truth.K[:2, 2], atol=1.0)
    assert cal.warnings == () and not cal.rejected and cal.coverage > 0.5


def test_renders_from_one_pose_are_refused_as_one_pose() -> None:
    """Three frames from one pose (fresh sensor noise in each): one pose, refused."""
    target = CharucoTarget(TUTORIAL_BOARD)
    eye = BOARD_CENTRE + np.array([0.1, 0.05, 0.4])
    views = [target.detect(_render(eye, BOARD_CENTRE, 0.2, seed)) for seed in range(3)]
    with pytest.raises(VisionError, match="from only 1 distinct pose"):
        calibrate_charuco(views, target, (640, 480))
