"""``benchmarks/slam_peer.py``, ``orb_peer.py`` and ``orb_rgbd.py``'s pure parts: our final
trajectory made as ORB-SLAM3 saves its own (each frame through its keyframe's final pose), the
depth images as ORB-SLAM3 reads them through the settings we write for it, its EuRoC-layout
trajectories turned into the body's, its log's counts and which datasets each system runs on (bad
input: ``tests/test_benchmark_inputs.py``). No test runs ORB-SLAM3 or the SLAM."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.geometry.trajectory import Trajectory
from quadnav.io.datasets.depth import DepthFrame, depth_png, depth_yaml
from quadnav.rig import DepthSpec, rgbd
from tests.script_module import load_script

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "slam_peer.py"


@pytest.fixture(scope="module")
def peer() -> ModuleType:
    return load_script(SCRIPT)


@pytest.fixture(scope="module")
def orb() -> ModuleType:
    return load_script(ROOT / "benchmarks" / "orb_peer.py")


@pytest.fixture(scope="module")
def runner() -> ModuleType:
    return load_script(ROOT / "benchmarks" / "orb_rgbd.py")


def _poses(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, 0.5, (n, 3))).as_matrix()
    T[:, :3, 3] = np.cumsum(rng.normal(0, 0.1, (n, 3)), axis=0)
    return T


def test_each_frame_follows_the_final_pose_of_the_newest_keyframe_before_it(
    peer: ModuleType,
) -> None:
    """Keyframes at frames 0, 10 and 20; the final map moved keyframe 20 (a loop closed) and
    left keyframe 0 alone; keyframe 10 was culled (not in the final map). Frames 0-19 are
    unchanged; frames from 20 on move rigidly with keyframe 20, relative poses kept."""
    t = np.arange(30, dtype=np.int64) * 50_000_000
    T = _poses(30, 0)
    est = Trajectory.from_matrices(t, T)
    fix = _poses(1, 1)[0]
    kf = np.stack([T[0], fix @ T[20]])
    final = peer.through_final_keyframes(est, est, Trajectory.from_matrices(t[[0, 20]], kf))
    F = final.matrices()
    np.testing.assert_allclose(F[:20], T[:20], atol=1e-9)
    np.testing.assert_allclose(F[20:], fix @ T[20:], atol=1e-9)
    # a keyframe the tracked poses lack carries nothing; frames before every keyframe take the first
    late = Trajectory.from_matrices(t[[5, 12]], np.stack([fix @ T[5], T[12]]))
    tracked = est.select(np.setdiff1d(np.arange(30), [12]))
    F = peer.through_final_keyframes(est, tracked, late).matrices()
    np.testing.assert_allclose(F, fix @ T, atol=1e-9)
    with pytest.raises(ValueError, match="no keyframe of the final map"):
        peer.through_final_keyframes(est, tracked, late.select(np.array([1])))


def test_depth_images_reach_orb_slam3_in_the_metres_quadnav_reads(
    runner: ModuleType, tmp_path: Path
) -> None:
    """A depth image written as ``quadnav dataset make`` writes it, read back as ORB-SLAM3 reads
    it (the PNG as float counts, divided by the ``RGBD.DepthMapFactor`` of the settings we give
    it, parsed by OpenCV's FileStorage as ORB-SLAM3 does): within half a millimetre of the truth
    and of quadnav's own reading; no reading (out of range, NaN) is 0, which ORB-SLAM3 skips."""
    rng = np.random.default_rng(3)
    depth = rng.uniform(0.2, 8.0, (48, 64)).astype(np.float32)
    depth[0, :5] = [np.inf, np.nan, 0.0, -1.0, 70.0]
    path = tmp_path / "d.png"
    assert cv2.imwrite(str(path), depth_png(depth))
    yaml = runner.read_yaml
    (tmp_path / "depth.yaml").write_text(depth_yaml(DepthSpec()), encoding="utf-8")
    cam_yaml = tmp_path / "cam.yaml"
    cam_yaml.write_text(_cam0_yaml(), encoding="utf-8")
    text = runner.settings_text(yaml(cam_yaml), yaml(tmp_path / "depth.yaml"), nfeat=1200,
                                thdepth=40.0, baseline_m=0.05)  # fmt: skip
    fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    factor = fs.getNode("RGBD.DepthMapFactor").real()
    seen = runner.orb_depth_m(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), factor)
    ours = DepthFrame(t_ns=0, camera="cam0", path=path).depth_m()
    valid = np.isfinite(depth) & (depth > 0) & (depth < 65)
    assert (seen[~valid] == 0).all() and np.isinf(ours[~valid]).all()
    assert np.abs(seen[valid] - depth[valid]).max() <= 0.0005 + 1e-6
    np.testing.assert_allclose(seen[valid], ours[valid], atol=1e-6)
    # the rest of what ORB-SLAM3 requires of an RGB-D camera, as the dataset states it
    assert fs.getNode("Camera1.fx").real() == pytest.approx(381.3625)
    assert fs.getNode("Stereo.b").real() * fs.getNode("Stereo.ThDepth").real() == pytest.approx(2.0)
    assert fs.getNode("Camera.width").real() == 640 and fs.getNode("Viewer.ViewpointF").real() > 0
    # loop closing on unless asked off (ORB-SLAM3 v1.0 reads loopClosing: 0)
    assert fs.getNode("loopClosing").empty()
    off = runner.settings_text(yaml(cam_yaml), yaml(tmp_path / "depth.yaml"), nfeat=1200,
                               thdepth=40.0, baseline_m=0.05, loop=False)  # fmt: skip
    no_loop = cv2.FileStorage(off, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    assert no_loop.getNode("loopClosing").real() == 0 and not no_loop.getNode("loopClosing").empty()


def _cam0_yaml() -> str:
    cam = rgbd().cameras[0]
    T = cam.T_B_C.matrix().ravel()
    return (
        "%YAML:1.0\ncamera_model: pinhole\nT_BS:\n  cols: 4\n  rows: 4\n"
        f"  data: [{', '.join(map(str, T))}]\nrate_hz: 20.0\nresolution: [640, 480]\n"
        "intrinsics: [381.3625, 381.3625, 320.5, 240.5]\n"
        "distortion_model: radial-tangential\ndistortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n"
    )


def test_settings_refuse_a_lens_orb_slam3_would_misread(runner: ModuleType) -> None:
    cam = {"camera_model": "omni", "distortion_model": "radial-tangential"}
    with pytest.raises(ValueError, match="cam0: omni/radial-tangential is not pinhole"):
        runner.settings_text(cam, {"depth_scale": 1000.0}, nfeat=1200, thdepth=40, baseline_m=0.05)
    with pytest.raises(ValueError, match="16-bit"):
        runner.depth_for_orb(np.zeros((4, 4), np.float32))


def test_orb_camera_trajectories_become_the_body_s(orb: ModuleType, tmp_path: Path) -> None:
    """ORB-SLAM3 saves a camera's poses (``t_ns x y z qx qy qz qw``) without an IMU; turned by
    the body in the camera they are the body's; a repeated stamp is dropped."""
    T_W_B = _poses(5, 4)
    T_B_C = _poses(1, 5)[0]
    T_W_C = T_W_B @ T_B_C
    t_ns = np.array([1, 2, 3, 3, 4], np.int64) * 1_000_000_000 + 1_403_715_525_107_140_000
    rows = [
        [t, *T[:3, 3], *Rotation.from_matrix(T[:3, :3]).as_quat()]
        for t, T in zip(t_ns, T_W_C, strict=True)
    ]
    path = tmp_path / "kf.txt"
    path.write_text("\n".join(f"{int(r[0])} " + " ".join(f"{v:.12f}" for v in r[1:]) for r in rows))
    traj = orb.read_orb_euroc(path, np.linalg.inv(T_B_C))
    # (ORB-SLAM3 writes nanoseconds as a double: within 256 ns at 1.4e18)
    np.testing.assert_allclose(traj.t_ns - t_ns[[0, 1, 2, 4]], 0, atol=256)
    np.testing.assert_allclose(traj.matrices(), T_W_B[[0, 1, 2, 4]], atol=1e-9)


def test_orb_slam3_log_counts(orb: ModuleType) -> None:
    log = (
        "Creation of new map with id: 0\nCreation of new map with last KF id: 0\n*Loop detected\n"
        "SYSTEM-> Reseting active map in monocular case\nCreation of new map with id: 1\n"
        "*Loop detected\n*Merge detected\n"
    )
    assert orb.log_counts(log) == {"resets": 1.0, "new_maps": 1.0, "loops": 2.0, "merges": 1.0}
    assert orb.log_counts("Vocabulary loaded!\n")["new_maps"] == 0.0


def test_each_system_runs_on_its_kind_of_dataset(peer: ModuleType, tmp_path: Path) -> None:
    for name, folders in {
        "st": ("cam0", "cam1"),
        "rgbd": ("cam0", "depth0"),
        "mono": ("cam0",),
    }.items():
        for f in folders:
            (tmp_path / name / "mav0" / f).mkdir(parents=True)
            (tmp_path / name / "mav0" / f / "data.csv").write_text("#t,f\n")
        (tmp_path / name / "groundtruth.tum").write_text("")
    assert peer.dataset_kind(tmp_path / "st") == "stereo"
    assert peer.dataset_kind(tmp_path / "rgbd") == "rgbd"
    assert peer.dataset_kind(tmp_path / "mono") is None
    assert peer.group_name("v102_rgbd_s12") == "v102_rgbd" and peer.group_name("mh01") == "mh01"
    assert peer.parse_systems("orb_rgbd,quadnav_rgbd,orb_rgbd") == ["orb_rgbd", "quadnav_rgbd"]
