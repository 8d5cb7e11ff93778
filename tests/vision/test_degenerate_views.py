"""Views that fix no pose (one column of a board's corners, too few points, NaN out of the PnP)
are refused with a reason, frame by frame, and never abort a run."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.experiments.markers_run import run_markers
from quadnav.geometry.rotations import Pose
from quadnav.sim.camera import RenderSettings, SyntheticCamera, board_object
from quadnav.vision.config import MarkersConfig
from quadnav.vision.markers import CharucoSpec, CharucoTarget
from quadnav.vision.pipeline import MapBoard, MarkerMap, MarkerPipeline
from quadnav.vision.pose import DegeneratePoseError, check_point_set, solve_pnp
from tests.vision.test_pose_synthetic import THESIS_CAMERA

# a board two squares wide: its inner corners are one column, on one line
COLUMN = CharucoSpec(2, 5, 0.07, 0.05, "DICT_4X4_250")
T_B_C = Pose(Rotation.from_euler("x", 180, degrees=True), np.zeros(3))  # looking down


def _column_scene() -> tuple[SyntheticCamera, Pose]:
    obj = board_object(CharucoTarget(COLUMN).board, (0.14, 0.35), Pose.identity())
    T_W_B = Pose(Rotation.from_euler("z", 0.2), np.array([0.07, 0.175, 0.6]))
    return SyntheticCamera(THESIS_CAMERA, [obj], RenderSettings(noise_sigma=1.0)), T_W_B


def test_collinear_and_too_few_points_are_refused_before_the_pnp() -> None:
    column = np.array([[0.066, 0.066 * k, 0.0] for k in range(1, 7)])
    T_C_O = Pose(Rotation.from_euler("x", 170, degrees=True), np.array([0.0, 0.0, 1.2]))
    px = THESIS_CAMERA.project(T_C_O @ column)
    with pytest.raises(DegeneratePoseError, match="object points lie on one line") as e:
        solve_pnp(column, px, THESIS_CAMERA)
    assert e.value.reason == "collinear"
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    with pytest.raises(DegeneratePoseError, match="4 distinct points, got 3") as e:
        check_point_set(square[[0, 1, 2, 2]], np.zeros((4, 2)) + np.arange(4)[:, None])
    assert e.value.reason == "too_few_points"
    with pytest.raises(DegeneratePoseError, match="pixels lie on one line"):
        check_point_set(square, np.column_stack([np.arange(4.0), 2 * np.arange(4.0)]))
    with pytest.raises(DegeneratePoseError, match="non-finite"):
        check_point_set(square, np.full((4, 2), np.nan))


def test_one_column_of_corners_falls_back_to_the_markers_or_is_refused() -> None:
    scene, T_W_B = _column_scene()
    image = scene.render(T_W_B @ T_B_C)
    mmap = MarkerMap("DICT_4X4_250", boards=[MapBoard(COLUMN, Pose.identity())])
    refused = MarkerPipeline(THESIS_CAMERA, mmap, T_B_C, board_marker_fallback=False).process(image)
    assert refused.pose is None and refused.reason == "collinear" and refused.n_points >= 4
    fp = MarkerPipeline(THESIS_CAMERA, mmap, T_B_C).process(image)
    assert fp.pose is not None and fp.n_points >= 8  # the markers' corners
    np.testing.assert_allclose(fp.pose.T_W_B.p_A_B, T_W_B.p_A_B, atol=0.01)


def write_camera_yaml(path: Path) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", THESIS_CAMERA.width)
    fs.write("image_height", THESIS_CAMERA.height)
    fs.write("camera_matrix", THESIS_CAMERA.K)
    fs.write("distortion_coefficients", THESIS_CAMERA.dist.reshape(1, -1))
    fs.release()
    return path


def test_a_run_counts_degenerate_frames_and_keeps_its_rows_when_stopped(tmp_path: Path) -> None:
    scene, T_W_B = _column_scene()
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(4):
        T = Pose(T_W_B.R_A_B, T_W_B.p_A_B + [0.0, 0.01 * k, 0.0])
        cv2.imwrite(str(folder / f"frame_{k:03d}.png"), scene.render(T @ T_B_C))
    cfg = MarkersConfig(
        target="charuco", dictionary="DICT_4X4_250", video=False, mount_rpy_deg=(180.0, 0.0, 0.0),
        camera_file=str(write_camera_yaml(tmp_path / "cal.yml")),
        charuco={"squares_x": 2, "squares_y": 5, "square_m": 0.07, "marker_m": 0.05, "marker_fallback": False},
    )  # fmt: skip
    stats = run_markers(cfg, str(folder), tmp_path / "runs")
    assert stats.frames == 4 and stats.frames_with_pose == 0
    assert stats.frames_rejected == 4 and stats.rejected_by_reason == {"collinear": 4}
    rows = list(csv.DictReader((stats.run_dir / "poses.csv").open()))
    assert [r["reason"] for r in rows] == ["collinear"] * 4

    # stopped after the second frame (Ctrl-C in the progress bar): both rows are on disk
    def stop_after_two(done: int, total: int, text: str) -> None:
        if done == 2:
            raise KeyboardInterrupt

    ok_cfg = cfg.model_copy(update={"charuco": cfg.charuco.model_copy(update={"marker_fallback": True})})  # fmt: skip
    # Ctrl-C stops a run over files half way: it goes on up (the command marks the folder
    # interrupted), what came so far on disk
    with pytest.raises(KeyboardInterrupt):
        run_markers(ok_cfg, str(folder), tmp_path / "stopped", progress=stop_after_two)
    (run,) = (tmp_path / "stopped").iterdir()
    assert not (run / "stats.json").exists()
    rows = list(csv.DictReader((run / "poses.csv").open()))
    assert [r["frame"] for r in rows] == ["0", "1"]
    assert all(abs(float(r["z_m"]) - 0.6) < 0.01 for r in rows)
