"""Marker pose on synthetic renders with the thesis camera (640x480, cal.yml intrinsics and
distortion): accuracy, covariance consistency, the frame chain."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.experiments.markers import look_at, synthetic_marker_study
from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.sim.camera import RenderSettings, SyntheticCamera, board_object, marker_object
from quadnav.vision.markers import CharucoSpec, CharucoTarget, get_dictionary
from quadnav.vision.pipeline import MapBoard, MapMarker, MarkerMap, MarkerPipeline
from quadnav.vision.pose import marker_corners_3d, mount_pose, solve_pnp, vehicle_pose

# thesis_rig/cal.yml, inlined so these tests run without the shared data
THESIS_CAMERA = PinholeCamera(
    np.array(
        [[498.57027128, 0.0, 317.13790849], [0.0, 499.04454028, 253.31937807], [0.0, 0.0, 1.0]]
    ),
    np.array([0.16052725, -0.25643743, 0.00342303, 0.00516838, -0.15214634]),
    640,
    480,
)


@pytest.mark.parametrize("seed", [0, 1])
def test_single_marker_pose_accuracy_and_consistency(seed: int) -> None:
    """0.2335 m marker, 0.5 to 3 m, up to 40 degrees off-axis, image noise sigma 3 grey levels."""
    s = synthetic_marker_study(THESIS_CAMERA, n_views=100, seed=seed)
    ok = s.detected
    assert ok.mean() >= 0.97
    assert np.median(s.position_error_m[ok] / s.distance_m[ok]) <= 0.01
    assert np.median(s.orientation_error_deg[ok]) <= 1.0
    assert 3.0 <= np.mean(s.nees[ok]) <= 12.0  # consistent: within a factor 2 of 6


def test_covariance_grows_with_distance_and_obliquity() -> None:
    d = get_dictionary("DICT_4X4_250")
    scene = SyntheticCamera(
        THESIS_CAMERA,
        [marker_object(d, 3, 0.2335, Pose.identity())],
        RenderSettings(noise_sigma=1.0),
    )
    pipe = MarkerPipeline(THESIS_CAMERA, MarkerMap.single_marker(3, 0.2335, 4 * 0 + "DICT_4X4_250".__len__() * 0 or "DICT_4X4_250"), Pose.identity())  # fmt: skip
    sig = {}
    for name, eye in (
        ("close", [0.0, 0.0, 0.8]),
        ("far", [0.0, 0.0, 2.5]),
        ("oblique", [1.2, 0.0, 1.4]),
    ):
        fp = pipe.process(scene.render(look_at(np.array(eye), np.zeros(3))))
        assert fp.pose is not None, name
        sig[name] = math.sqrt(np.trace(fp.pose.cov_position))
    assert sig["far"] > 3 * sig["close"]
    assert sig["oblique"] > sig["close"]


def test_frame_chain_with_the_thesis_mount() -> None:
    """Thesis 000 eqs 3.1-3.6 as T_W_B = T_W_M T_C_M^-1 T_B_C^-1, with the camera turned 180
    degrees about the vertical from the body and looking down (roll 180, yaw 180 in FLU)."""
    T_B_C = mount_pose((180.0, 0.0, 180.0), (0.05, 0.0, -0.03))
    R_B_C = T_B_C.R_A_B.as_matrix()
    np.testing.assert_allclose(R_B_C @ [0, 0, 1], [0, 0, -1], atol=1e-12)  # optical axis down
    np.testing.assert_allclose(R_B_C @ [1, 0, 0], [-1, 0, 0], atol=1e-12)  # image x to the tail
    T_W_M = Pose(Rotation.from_euler("z", 0.4), np.array([2.0, -1.0, 0.0]))
    T_W_B = Pose(Rotation.from_euler("ZYX", [1.0, 0.05, -0.08]), np.array([2.3, -0.6, 1.2]))
    T_C_M = (T_W_B @ T_B_C).inverse() @ T_W_M
    px = THESIS_CAMERA.project(T_C_M @ marker_corners_3d(0.2335))
    pnp = solve_pnp(marker_corners_3d(0.2335), px, THESIS_CAMERA, square=True)
    vp = vehicle_pose(pnp, T_W_M, T_B_C)
    np.testing.assert_allclose(vp.T_W_B.p_A_B, T_W_B.p_A_B, atol=1e-6)
    assert (vp.T_W_B.R_A_B.inv() * T_W_B.R_A_B).magnitude() < 1e-6


def test_marker_map_and_board_give_one_pose_from_everything_in_view() -> None:
    d = get_dictionary("DICT_4X4_250")
    poses = {
        i: Pose(Rotation.from_euler("z", 0.3 * i), np.array([0.6 * (i % 2), 0.6 * (i // 2), 0.0]))
        for i in range(4)
    }
    spec = CharucoSpec(5, 4, 0.08, 0.06, "DICT_4X4_250")
    target = CharucoTarget(spec)
    T_W_O = Pose(Rotation.from_euler("z", 3, degrees=True), np.array([1.5, -0.32, 0.0]))
    objects = [marker_object(d, 10 + i, 0.2, p) for i, p in poses.items()]
    objects.append(board_object(target.board, (0.4, 0.32), T_W_O))
    scene = SyntheticCamera(THESIS_CAMERA, objects, RenderSettings(noise_sigma=1.0))
    mmap = MarkerMap("DICT_4X4_250", {10 + i: MapMarker(10 + i, 0.2, p) for i, p in poses.items()})
    pipe = MarkerPipeline(THESIS_CAMERA, mmap, Pose.identity())
    T_W_C = look_at(np.array([0.4, 0.3, 2.0]), np.array([0.3, 0.3, 0.0]))
    fp = pipe.process(scene.render(T_W_C))
    assert fp.pose is not None and fp.n_points == 16
    assert np.linalg.norm(fp.pose.T_W_B.p_A_B - T_W_C.p_A_B) < 0.02
    # the board alone at x = 1.5 m (its face frame: z out of the print, origin bottom-left)
    bmap = MarkerMap("DICT_4X4_250", boards=[MapBoard(spec, T_W_O)])
    pipe_b = MarkerPipeline(THESIS_CAMERA, bmap, Pose.identity())
    T_W_C2 = look_at(np.array([1.25, -0.3, 0.8]), np.array([1.7, -0.16, 0.0]))  # 30 deg oblique
    fp2 = pipe_b.process(scene.render(T_W_C2))
    assert fp2.pose is not None and fp2.n_points >= 8
    assert np.linalg.norm(fp2.pose.T_W_B.p_A_B - T_W_C2.p_A_B) < 0.01
