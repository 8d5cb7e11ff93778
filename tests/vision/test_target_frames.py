"""One frame convention for every target kind (marker, ChArUco board, diamond, map): z out of
the printed face, so the thesis's downward camera over a target on the floor puts the vehicle
above it, upright. Renders with known poses, seeded."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.experiments.markers_run import load_markers_config, run_markers
from quadnav.geometry.rotations import Pose
from quadnav.sim.camera import (
    PlanarObject,
    RenderSettings,
    SyntheticCamera,
    board_object,
    diamond_object,
    marker_object,
)
from quadnav.vision.config import MarkersConfig, from_thesis_vision_params
from quadnav.vision.markers import CharucoSpec, CharucoTarget, get_dictionary
from quadnav.vision.pipeline import MarkerMap, MarkerPipeline
from quadnav.vision.pose import marker_corners_3d
from tests.vision.test_degenerate_views import write_camera_yaml
from tests.vision.test_pose_synthetic import THESIS_CAMERA

D = get_dictionary("DICT_4X4_250")
BOARD = {"squares_x": 5, "squares_y": 7, "square_m": 0.06, "marker_m": 0.04}
DIAMOND_IDS = (3, 9, 12, 20)
MAP_DIAMOND = (50, 51, 52, 53)


def _board(spec: CharucoSpec, T_W_O: Pose) -> PlanarObject:
    size = (spec.squares_x * spec.square_m, spec.squares_y * spec.square_m)
    return board_object(CharucoTarget(spec).board, size, T_W_O)


def _scene(kind: str) -> tuple[MarkersConfig, list[PlanarObject], np.ndarray]:
    """A config, the objects it describes and a point of the floor to fly over."""
    if kind == "marker":
        cfg = MarkersConfig(target="marker", marker_id=7, marker_length_m=0.2)
        return cfg, [marker_object(D, 7, 0.2, Pose.identity())], np.zeros(2)
    if kind == "charuco":
        cfg = MarkersConfig(target="charuco", charuco=BOARD)
        return cfg, [_board(cfg.charuco_spec(cfg.charuco), Pose.identity())], np.array([0.15, 0.21])
    if kind == "diamond":
        cfg = MarkersConfig(target="diamond", diamond={"square_m": 0.12, "marker_m": 0.075, "ids": DIAMOND_IDS})  # fmt: skip
        return cfg, [diamond_object(D, DIAMOND_IDS, 0.12, 0.075, Pose.identity())], np.zeros(2)
    # one dictionary, distinct ids: the board has markers 0-16, the marker is 40, the
    # diamond 50-53
    placed = {"position_m": (0.15, -0.1, 0.0), "rpy_deg": (0.0, 0.0, 35.0)}
    cfg = MarkersConfig(
        target="map",
        map_markers=[{"id": 40, "length_m": 0.15, "position_m": (-0.3, 0.25, 0.0), "rpy_deg": (0.0, 0.0, -20.0)}],
        map_boards=[{"charuco": BOARD, **placed}],
        map_diamonds=[{"diamond": {"square_m": 0.1, "marker_m": 0.06, "ids": MAP_DIAMOND}, "position_m": (-0.35, -0.25, 0.0)}],
    )  # fmt: skip
    mm = cfg.marker_map()
    objects = [
        marker_object(D, 40, 0.15, mm.markers[40].T_W_M),
        _board(mm.boards[0].spec, mm.boards[0].T_W_O),
        diamond_object(D, MAP_DIAMOND, 0.1, 0.06, mm.diamonds[0].T_W_D),
    ]
    return cfg, objects, np.zeros(2)


@pytest.mark.parametrize("kind", ["marker", "charuco", "diamond", "map"])
def test_the_thesis_mount_over_every_target_kind_is_above_it_and_upright(kind: str) -> None:
    cfg, objects, over = _scene(kind)
    T_B_C = cfg.T_B_C()  # the thesis's camera: looking down, turned 180 degrees
    scene = SyntheticCamera(THESIS_CAMERA, objects, RenderSettings(noise_sigma=1.5, seed=3))
    pipe = MarkerPipeline(THESIS_CAMERA, cfg.marker_map(), T_B_C)
    rng = np.random.default_rng(12)
    pos_err, rot_err, tilt, n = [], [], [], 20
    for _ in range(n):
        height = rng.uniform(0.8, 1.3)
        p = np.append(over + rng.uniform(-0.05, 0.05, 2), height)
        rpy = [rng.uniform(-math.pi, math.pi), rng.normal(0, 0.05), rng.normal(0, 0.05)]
        T_W_B = Pose(Rotation.from_euler("ZYX", rpy), p)
        fp = pipe.process(scene.render(T_W_B @ T_B_C))
        if fp.pose is None:
            continue
        est = fp.pose.T_W_B
        assert est.p_A_B[2] > 0.3, kind  # above the target, not below it
        tilt.append(np.abs(est.R_A_B.as_euler("ZYX", degrees=True)[[2, 1]]))
        pos_err.append(np.linalg.norm(est.p_A_B - p))
        rot_err.append(math.degrees((est.R_A_B.inv() * T_W_B.R_A_B).magnitude()))
    assert len(pos_err) >= 0.9 * n
    # upright (roll and pitch of the truth are ~3 degrees), not upside down (180); a small
    # target far away may take the other pose of the planar ambiguity (~10 degrees off)
    assert np.median(tilt) < 5 and np.max(tilt) < 25, kind
    # a few mm from 0.8-1.3 m; the 0.12 m diamond is the least precise of them
    assert np.median(pos_err) < 0.02
    assert np.median(rot_err) < 1.5


def test_board_markers_are_laid_out_as_single_markers() -> None:
    """Each marker of a board has the corners of a single marker of its side around its
    centre: x right, y up, z out of the face (OpenCV 4.6+ lays boards out with y down)."""
    target = CharucoTarget(CharucoSpec(5, 7, 0.06, 0.04, "DICT_4X4_250"))
    ids = np.asarray(target.board.getIds()).ravel()
    corners = target.marker_corners(ids)
    centres = corners.mean(axis=1, keepdims=True)
    np.testing.assert_allclose(corners - centres, np.broadcast_to(marker_corners_3d(0.04), corners.shape), atol=1e-6)  # fmt: skip
    # the origin is the bottom-left corner of the pattern: everything at x, y >= 0
    assert corners[..., :2].min() > 0 and target.chessboard_corners[:, :2].min() > 0
    # marker 0 is printed at the top-left: the highest row of the face frame
    assert corners[0, :, 1].min() > 0.5 * 7 * 0.06


def test_a_diamond_is_posed_with_its_square_not_the_thesis_marker_length() -> None:
    """The thesis's ``diamond: true`` (with ``charuco: false``) makes the diamond the world,
    with its squareLength / markerLength; single markers of marker_length would be 8x off."""
    thesis = {"diamond": 1, "charuco": 0, "marker_length": 0.96, "squareLength": 0.12,
              "markerLength": 0.075, "dict_type": 2}  # fmt: skip
    keys, ignored = from_thesis_vision_params(thesis)
    assert "diamond" not in ignored and keys["target"] == "diamond"
    cfg = MarkersConfig(**keys)
    assert (cfg.diamond.square_m, cfg.diamond.marker_m) == (0.12, 0.075)
    # two diamonds in view: with ids, the world is the one asked for
    other = Pose(Rotation.identity(), np.array([0.45, 0.0, 0.0]))
    objects = [diamond_object(D, DIAMOND_IDS, 0.12, 0.075, Pose.identity()),
               diamond_object(D, (30, 31, 32, 33), 0.12, 0.075, other)]  # fmt: skip
    scene = SyntheticCamera(THESIS_CAMERA, objects, RenderSettings(noise_sigma=1.0))
    T_B_C = cfg.T_B_C()
    T_W_B = Pose(Rotation.from_euler("z", 0.7), np.array([0.22, 0.02, 0.9]))
    image = scene.render(T_W_B @ T_B_C)
    for ids, origin in (
        (None, np.zeros(3)),
        (DIAMOND_IDS, np.zeros(3)),
        ((30, 31, 32, 33), other.p_A_B),
    ):
        c = MarkersConfig(**{**keys, "diamond": {**keys["diamond"], "ids": ids}})
        fp = MarkerPipeline(THESIS_CAMERA, c.marker_map(), T_B_C).process(image)
        assert fp.pose is not None and fp.n_points == 4
        np.testing.assert_allclose(fp.pose.T_W_B.p_A_B, T_W_B.p_A_B - origin, atol=0.02)  # fmt: skip
    # a map of markers only does not see diamonds as a target
    assert MarkerMap.single_marker(3, 0.075, 2).diamonds == []


def test_the_thesis_diamond_key_through_the_command(tmp_path: Path) -> None:
    """A thesis ``vision_params.yml`` with ``diamond: true``: the run poses the diamond at
    its squareLength (no note that the key is unused)."""
    params = tmp_path / "vision_params.yml"
    params.write_text(
        "%YAML:1.0\ndict_type: 2\nmarker_length: 0.96\ndiamond: true\ncharuco: false\n"
        "squareLength: 0.12\nmarkerLength: 0.075\n"
    )
    cfg0, ignored = load_markers_config(params, [])
    assert "diamond" not in ignored and cfg0.target == "diamond"
    scene = SyntheticCamera(THESIS_CAMERA, [diamond_object(D, DIAMOND_IDS, 0.12, 0.075, Pose.identity())],
                            RenderSettings(noise_sigma=1.0))  # fmt: skip
    folder = tmp_path / "frames"
    folder.mkdir()
    heights = [0.7, 0.75, 0.8]
    for k, h in enumerate(heights):
        T_W_B = Pose(Rotation.from_euler("z", 0.3 * k), np.array([0.02, -0.03, h]))
        cv2.imwrite(str(folder / f"{k:03d}.png"), scene.render(T_W_B @ cfg0.T_B_C()))
    cfg, _ = load_markers_config(params, [f"camera_file={write_camera_yaml(tmp_path / 'cal.yml')}", "video=false"])  # fmt: skip
    stats = run_markers(cfg, str(folder), tmp_path / "runs")
    rows = list(csv.DictReader((stats.run_dir / "poses.csv").open()))
    np.testing.assert_allclose([float(r["z_m"]) for r in rows], heights, atol=0.02)
