"""Camera calibration from a source's ChArUco views (``quadnav.experiments.calibration``, the
work behind ``quadnav calibrate``), on three real views of OpenCV's tutorial board."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import pytest

from quadnav.errors import IoError, VisionError
from quadnav.experiments.calibration import calibrate_source, write_source_calibration
from quadnav.vision.markers import CharucoSpec
from tests.shared_data import SHARED, needs

ARUCO = SHARED / "aruco"
BOARD = CharucoSpec(5, 7, 0.04, 0.02, "DICT_6X6_250")  # the cli's default board


def _views(folder: Path, broken: bool = True) -> Path:
    folder.mkdir()
    for f in ("img_00.jpg", "img_02.jpg", "img_03.jpg"):
        (folder / f).write_bytes((ARUCO / f).read_bytes())
    if broken:
        (folder / "broken.jpg").write_bytes(b"not a jpeg")
    return folder


@needs(ARUCO)
def test_a_source_is_calibrated_and_its_unreadable_frames_listed(tmp_path: Path) -> None:
    folder = _views(tmp_path / "views")
    seen: list[tuple[int, int]] = []
    res = calibrate_source(str(folder), BOARD, progress=lambda k, n, _: seen.append((k, n)))
    assert res.frames_read == 4
    assert len(res.unreadable) == 1 and res.unreadable[0].startswith("frame 0:")  # broken.jpg
    assert len(res.calibration.per_view_rms_px) == 3 and not res.calibration.rejected
    assert 440 < res.calibration.camera.fx < 480
    assert seen[-1] == (4, 4)
    out = tmp_path / "camera.yml"
    write_source_calibration(out, res)
    fs = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    assert fs.getNode("camera_matrix").mat()[0, 0] == pytest.approx(res.calibration.camera.fx)
    assert fs.getNode("avg_reprojection_error").real() == pytest.approx(res.calibration.rms_px)


@needs(ARUCO)
def test_every_nth_frame_skips_the_others_and_too_few_views_name_the_source(
    tmp_path: Path,
) -> None:
    folder = _views(tmp_path / "views", broken=False)
    (folder / "img_04.jpg").write_bytes((ARUCO / "img_00.jpg").read_bytes())
    # frames 0 and 2 of 4: two views, one short of a calibration
    with pytest.raises(
        VisionError, match=re.escape(f"{folder}: calibration needs at least 3 good views, got 2")
    ):
        calibrate_source(str(folder), BOARD, every=2)


def test_a_source_with_no_readable_image_is_refused_by_name(tmp_path: Path) -> None:
    folder = tmp_path / "views"
    folder.mkdir()
    (folder / "broken.jpg").write_bytes(b"not a jpeg")
    with pytest.raises(IoError, match=re.escape(f"{folder}: none of the 1 images can be decoded")):
        calibrate_source(str(folder), BOARD)


@needs(ARUCO)
def test_several_sources_are_read_in_turn_and_an_image_of_another_size_set_aside(
    tmp_path: Path,
) -> None:
    """Image files as sources (the shell's img_0*.jpg): numbered on across the sources, the
    rejected and used views keyed by those numbers; a frame of another size is not mixed in."""
    small = tmp_path / "small.jpg"
    cv2.imwrite(str(small), cv2.resize(cv2.imread(str(ARUCO / "img_00.jpg")), (320, 240)))
    first, *rest = (str(ARUCO / f) for f in ("img_00.jpg", "img_02.jpg", "img_03.jpg"))
    sources = [first, str(small), *rest]
    res = calibrate_source(sources, BOARD)
    assert res.frames_read == 4
    assert res.unreadable == (f"frame 1 of {small}: 320x240, not 640x480",)
    assert sorted(res.calibration.per_view_rms_px) == [0, 2, 3]
    assert res.calibration.camera.width == 640 and 440 < res.calibration.camera.fx < 480
