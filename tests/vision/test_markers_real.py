"""OpenCV's ArUco tutorial photos (../shared/data/aruco, with the ids and corners OpenCV's own
test asserts)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from quadnav.errors import IoError, VisionError
from quadnav.geometry.rotations import Pose
from quadnav.io.opencv_yaml import read_camera_yaml, read_opencv_yaml
from quadnav.vision.markers import (
    CharucoSpec,
    CharucoTarget,
    DiamondSpec,
    MarkerDetector,
    custom_dictionary,
    detect_diamonds,
    detector_parameters,
    get_dictionary,
)
from quadnav.vision.pipeline import MapDiamond, MarkerMap, MarkerPipeline
from tests.shared_data import SHARED, needs

DATA = SHARED / "aruco"
needs_data = needs(DATA)


def expected() -> dict:
    return json.loads((DATA / "expected.json").read_text())


def tutorial_dictionary() -> cv2.aruco.Dictionary:
    y = read_opencv_yaml(DATA / "tutorial_dict.yml")
    n, size = y["nmarkers"], y["markersize"]
    assert isinstance(n, int) and isinstance(size, int)
    return custom_dictionary([str(y[f"marker_{i}"]) for i in range(n)], size)


def assert_corners(ids, corners, want: dict) -> None:
    assert sorted(int(i) for i in ids) == sorted(int(k) for k in want)
    for i, c in zip(ids, corners, strict=True):
        np.testing.assert_allclose(c, np.array(want[str(int(i))], dtype=float), atol=1.0)


@needs_data
def test_single_markers_ids_and_corners_within_1px() -> None:
    det = MarkerDetector(get_dictionary("DICT_6X6_250")).detect(
        cv2.imread(str(DATA / "singlemarkersoriginal.jpg"))
    )
    assert_corners(det.ids, det.corners, expected()["singlemarkersoriginal.jpg"]["corners"])


@needs_data
def test_grid_board_in_a_custom_dictionary() -> None:
    det = MarkerDetector(tutorial_dictionary()).detect(cv2.imread(str(DATA / "gboriginal.png")))
    assert_corners(det.ids, det.corners, expected()["gboriginal.png"]["corners"])


@needs_data
@pytest.mark.parametrize("name", ["choriginal.jpg", "chocclusion_original.jpg"])
def test_charuco_markers_and_corners(name: str) -> None:
    b = expected()["choriginal.jpg"]["charuco_board"]
    target = CharucoTarget(
        CharucoSpec(
            b["squares_x"], b["squares_y"], b["square_length"], b["marker_length"], "DICT_6X6_250"
        )
    )
    det = target.detect(cv2.imread(str(DATA / name)))
    assert_corners(det.markers.ids, det.markers.corners, expected()[name]["corners"])
    # chessboard corners are interpolated between the markers found: 24 on the full board
    assert len(det.corner_ids) == (24 if name == "choriginal.jpg" else len(det.corner_ids))
    assert len(det.corner_ids) >= 12


@needs_data
def test_diamonds_with_the_tutorial_detector_parameters() -> None:
    params, unknown = detector_parameters(read_opencv_yaml(DATA / "detector_params.yml"))
    assert "minMarkerDistance" in unknown  # an aruco-3 era key this OpenCV does not have
    found = detect_diamonds(
        cv2.imread(str(DATA / "diamondmarkers.png")), tutorial_dictionary(), 1.6, params
    )
    want = {tuple(x) for x in expected()["diamondmarkers.png"]["diamond"]["expected_diamond_ids"]}
    assert {d.ids for d in found} == want


def test_apriltag_family_detected_on_a_generated_tag() -> None:
    d = get_dictionary("APRILTAG_36h11")
    tag = cv2.aruco.generateImageMarker(d, 17, 200)
    img = cv2.copyMakeBorder(tag, 60, 60, 60, 60, cv2.BORDER_CONSTANT, value=255)
    det = MarkerDetector(d).detect(img)
    assert det.ids.tolist() == [17]
    np.testing.assert_allclose(det.corners[0][0], [59.5, 59.5], atol=1.0)


def test_dictionary_names_and_bad_input() -> None:
    assert get_dictionary("DICT_4X4_250").markerSize == 4
    assert get_dictionary(2).markerSize == 4  # the thesis's dict_type: 2
    assert get_dictionary("6x6_250").markerSize == 6
    with pytest.raises(VisionError, match="unknown ArUco dictionary 'DICT_7X7_9'"):
        get_dictionary("DICT_7X7_9")
    with pytest.raises(VisionError, match="36 bits"):
        custom_dictionary(["0101"], 6)
    with pytest.raises(VisionError, match="not an image"):
        MarkerDetector(get_dictionary(2)).detect(np.zeros((0, 0), np.uint8))


def test_camera_yaml_errors_are_one_line(tmp_path: Path) -> None:
    with pytest.raises(IoError, match="no such file"):
        read_camera_yaml(tmp_path / "missing.yml")
    bad = tmp_path / "bad.yml"
    bad.write_text("%YAML:1.0\nfoo: 1\n")
    with pytest.raises(IoError, match="missing camera_matrix"):
        read_camera_yaml(bad)
    garbage = tmp_path / "garbage.yml"
    garbage.write_bytes(b"\x00\xff{{{not yaml")
    with pytest.raises(IoError):
        read_camera_yaml(garbage)


def test_thesis_detector_parameter_file_is_applied() -> None:
    thesis = DATA.parent / "thesis_rig" / "detector_params.yml"
    if not thesis.exists():
        pytest.skip(f"shared test data not found at {thesis}")
    params, unknown = detector_parameters(read_opencv_yaml(thesis))
    assert params.cornerRefinementMethod == cv2.aruco.CORNER_REFINE_SUBPIX
    assert params.adaptiveThreshWinSizeMax == 23 and params.errorCorrectionRate == pytest.approx(
        0.6
    )
    # keys of older ArUco versions are reported, not fatal
    assert {"nmarkers", "minMarkerDistance", "minCornerDistance"} <= set(unknown)
    with pytest.raises(VisionError, match="adaptiveThreshWinSizeMax"):
        detector_parameters({"adaptiveThreshWinSizeMax": "big"})


@needs_data
def test_diamonds_face_the_camera_in_the_tutorial_photo() -> None:
    """The three diamonds printed on one sheet: each one's z (out of the face) points at the
    camera, and the three agree, as a marker's would."""
    camera = read_camera_yaml(DATA / "tutorial_camera_params.yml")
    params, _ = detector_parameters(read_opencv_yaml(DATA / "detector_params.yml"))
    image = cv2.imread(str(DATA / "diamondmarkers.png"))
    normals = []
    for ids in expected()["diamondmarkers.png"]["diamond"]["expected_diamond_ids"]:
        mmap = MarkerMap(0, diamonds=[MapDiamond(DiamondSpec(0.04, 0.025, tuple(ids)), Pose.identity())])  # fmt: skip
        pipe = MarkerPipeline(camera, mmap, Pose.identity(), params=params, dictionary=tutorial_dictionary())  # fmt: skip
        fp = pipe.process(image)
        assert fp.pose is not None and fp.rms_px < 1.0, ids
        R_C_D = fp.pose.T_W_B.R_A_B.inv()  # the camera is the body: T_W_C with W the diamond
        normals.append(R_C_D.apply([0.0, 0.0, 1.0]))
        assert normals[-1][2] < -0.5, ids  # towards the camera (camera z looks away from it)
    for n in normals[1:]:
        assert np.degrees(np.arccos(np.clip(n @ normals[0], -1, 1))) < 20
