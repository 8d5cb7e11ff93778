"""Stereo rectification: EuRoC's real pair (../shared/data/euroc_micro) and synthetic rigs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import VisionError
from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.rig import CameraSpec, Rig, euroc, thesis003_sim
from quadnav.vision.stereo import StereoRectifier
from tests.shared_data import SHARED, needs

EUROC_MICRO = SHARED / "euroc_micro"
_CRIT = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 0.001)


def row_offsets(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """|dy| of GFTT corners tracked left -> right by pyramidal KLT, kept when the track back
    right -> left returns within 0.05 px (forward-backward check) and the disparity is positive."""
    p0 = cv2.goodFeaturesToTrack(left, 300, 0.01, 12, blockSize=7)
    p0 = cv2.cornerSubPix(left, p0, (5, 5), (-1, -1), _CRIT)
    kw = {"winSize": (21, 21), "maxLevel": 3, "criteria": _CRIT}
    p1, s1, _ = cv2.calcOpticalFlowPyrLK(left, right, p0, None, **kw)
    pb, s2, _ = cv2.calcOpticalFlowPyrLK(right, left, p1, None, **kw)
    d = (p1 - p0).reshape(-1, 2)
    back = np.linalg.norm((pb - p0).reshape(-1, 2), axis=1)
    ok = (s1.ravel() == 1) & (s2.ravel() == 1) & (back < 0.05) & (d[:, 0] < 0)
    return np.abs(d[ok, 1])


@needs(EUROC_MICRO)
def test_euroc_micro_rectified_matches_lie_on_one_row() -> None:
    from quadnav.io.datasets import open_dataset

    ds = open_dataset(EUROC_MICRO)
    rect = StereoRectifier.of_rig(ds.rig)
    assert rect.baseline_m == pytest.approx(0.110, abs=0.001)
    left, right = ds.frames_of("cam0"), ds.frames_of("cam1")
    rectified, raw = [], []
    for k in range(0, 95, 10):
        a, b = left[k].image(), right[k].image()
        rectified.append(row_offsets(*rect.rectify(a, b)))
        raw.append(row_offsets(a, b))
    dy, dy_raw = np.concatenate(rectified), np.concatenate(raw)
    med, p95 = np.median(dy), np.percentile(dy, 95)
    print(
        f"rectified: n={dy.size} median |dy|={med:.3f} px p95={p95:.3f} px; "
        f"unrectified: n={dy_raw.size} median={np.median(dy_raw):.2f} px"
    )
    assert dy.size >= 300
    assert med < 0.1 and p95 < 0.5
    assert np.median(dy_raw) > 5.0  # the raw pair is not row-aligned: the test can fail


def _fisheye_rig() -> Rig:
    K = np.array([[190.0, 0.0, 254.0], [0.0, 191.0, 256.0], [0.0, 0.0, 1.0]])
    d0 = np.array([0.0034, 0.0007, -0.0020, 0.0002])
    d1 = np.array([0.0034, 0.0017, -0.0027, 0.0003])
    left = CameraSpec(
        name="cam0",
        camera=PinholeCamera(K, d0, 512, 512, model="equidistant"),
        T_B_C=Pose.identity(),
        rate_hz=20.0,
    )
    R = Rotation.from_euler("xyz", [1.5, -2.0, 0.8], degrees=True)
    right = CameraSpec(
        name="cam1",
        camera=PinholeCamera(K, d1, 512, 512, model="equidistant"),
        T_B_C=Pose(R, np.array([0.101, 0.002, -0.001])),
        rate_hz=20.0,
    )
    return Rig(name="fisheye", cameras=(left, right), imu=None)


@pytest.mark.parametrize("rig", [_fisheye_rig(), euroc()], ids=["equidistant", "radtan"])
def test_known_points_land_on_one_row(rig: Rig) -> None:
    rect = StereoRectifier.of_rig(rig)
    rng = np.random.default_rng(3)
    p_C0 = np.c_[rng.uniform(-1.5, 1.5, (200, 2)), rng.uniform(2.0, 6.0, 200)]
    T_C1_C0 = rig.cameras[1].T_B_C.inverse() @ rig.cameras[0].T_B_C
    px0 = rig.cameras[0].camera.project(p_C0)
    px1 = rig.cameras[1].camera.project(T_C1_C0 @ p_C0)
    inside = (np.abs(px0 - 256).max(axis=1) < 200) & (np.abs(px1 - 256).max(axis=1) < 200)
    r0, r1 = rect.rectify_points(0, px0[inside]), rect.rectify_points(1, px1[inside])
    assert np.abs(r0[:, 1] - r1[:, 1]).max() < 0.01
    assert np.abs(px0[inside, 1] - px1[inside, 1]).max() > 1.0
    # depth from disparity: z = fx * b / d in the rectified left camera
    z = rect.K[0, 0] * rect.baseline_m / (r0[:, 0] - r1[:, 0])
    z_true = (Pose(Rotation.from_matrix(rect.R0), np.zeros(3)) @ p_C0[inside])[:, 2]
    np.testing.assert_allclose(z, z_true, rtol=1e-3)
    assert rect.baseline_m == pytest.approx(rig.baseline_m, rel=1e-9)


def test_stereo_needs_two_cameras_apart() -> None:
    with pytest.raises(VisionError, match="one camera"):
        StereoRectifier.of_rig(thesis003_sim())
    rig = euroc()
    with pytest.raises(VisionError, match="image is 640x480"):
        StereoRectifier.of_rig(rig).rectify(
            np.zeros((480, 640), np.uint8), np.zeros((480, 752), np.uint8)
        )


def test_an_already_rectified_pair_stays_as_it_is(tmp_path: object) -> None:
    """KITTI's cameras are rectified (no distortion, parallel): the rectification is the
    identity and the baseline is P1's, 0.537 m."""
    K = np.array([[718.856, 0.0, 607.1928], [0.0, 718.856, 185.2157], [0.0, 0.0, 1.0]])
    lens = PinholeCamera(K, np.zeros(0), 1241, 376)
    b = 386.1448 / 718.856
    left = CameraSpec(name="cam0", camera=lens, T_B_C=Pose.identity(), rate_hz=10.0)
    right = CameraSpec(
        name="cam1", camera=lens, T_B_C=Pose(Rotation.identity(), np.array([b, 0, 0])), rate_hz=10.0
    )
    rect = StereoRectifier(Rig(name="kitti", cameras=(left, right), imu=None))
    np.testing.assert_allclose(rect.R0, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rect.K, K, atol=1e-9)
    assert rect.baseline_m == pytest.approx(b, rel=1e-12)
    img = np.random.default_rng(1).integers(0, 256, (376, 1241), dtype=np.uint8)
    out, _ = rect.rectify(img, img)
    assert np.abs(out[5:-5, 5:-5].astype(int) - img[5:-5, 5:-5]).max() <= 1
    np.testing.assert_allclose(rect.Q[2, 3], K[0, 0], rtol=1e-6)  # Q's focal length


def test_a_fix_found_later_makes_the_pair_the_ideal_one() -> None:
    """A parallel pinhole pair as stated, the real one otherwise: each camera 1.3 % longer in
    focal length and 2 px off in cx, with a little distortion of its own (k1 0.01 and 0.012,
    a tangential term), the right one turned 0.1 deg about its axis and 0.05 deg about its
    vertical. Folded into the maps as a :class:`RectificationFix`, every point lands
    where the ideal rectified pair of the real left camera puts it (within 0.05 px; the stated
    maps miss the right image's by over 0.5 px, and the real rows differ by over 0.6 px), and
    ``uncorrected`` gives back where the stated maps have it."""
    from quadnav.geometry.camera import project_radtan
    from quadnav.vision.stereo import RectificationFix

    K = np.array([[458.0, 0.0, 376.0], [0.0, 458.0, 240.0], [0.0, 0.0, 1.0]])
    lens = PinholeCamera(K, np.zeros(0), 752, 480)
    b = 0.11
    left = CameraSpec(name="cam0", camera=lens, T_B_C=Pose.identity(), rate_hz=20.0)
    right = CameraSpec(
        name="cam1", camera=lens, T_B_C=Pose(Rotation.identity(), np.array([b, 0, 0])), rate_hz=20.0
    )
    rect = StereoRectifier(Rig(name="pair", cameras=(left, right), imu=None))
    K_true = K @ np.diag([1.013, 1.013, 1.0]) + np.array([[0, 0, 2.0], [0, 0, 0], [0, 0, 0]])
    K_true_r = K_true + np.array([[0, 0, 0.3], [0, 0, 0], [0, 0, 0]])
    R_true = Rotation.from_rotvec(np.radians([0.0, 0.05, 0.1])).as_matrix()
    dist_l, dist_r = np.array([0.01, 0.0, 0.0005, 0.0]), np.array([0.012, 0.0, 0.0, 0.0004])
    fix = RectificationFix(K_left=K_true, dist_left=dist_l, K_right=K_true_r,
                           dist_right=dist_r, R_left_right=R_true)  # fmt: skip
    fixed = rect.corrected(fix)
    rng = np.random.default_rng(0)
    p = np.c_[rng.uniform(-1.5, 1.5, (300, 2)), rng.uniform(2.0, 6.0, 300)]
    raw_l = project_radtan(K_true, dist_l, p)  # (the stated maps are the identity here)
    p_r = (p - [b, 0.0, 0.0]) @ R_true  # (R^T (p - t): the point in the real right camera)
    raw_r = project_radtan(K_true_r, dist_r, p_r)
    ideal_l = ((p / p[:, 2:]) @ K_true.T)[:, :2]  # (the fixed pair's camera is the real left one's)
    q = p - [b, 0.0, 0.0]
    ideal_r = ((q / q[:, 2:]) @ K_true.T)[:, :2]

    def looked_up(maps: tuple[np.ndarray, np.ndarray], px: np.ndarray) -> np.ndarray:
        mx, my = cv2.convertMaps(maps[0], maps[1], cv2.CV_32FC1)
        x, y = px[:, 0].astype(np.float32)[None], px[:, 1].astype(np.float32)[None]
        return np.c_[
            cv2.remap(mx, x, y, cv2.INTER_LINEAR)[0], cv2.remap(my, x, y, cv2.INTER_LINEAR)[0]
        ]

    inside = np.all((ideal_l > 20) & (ideal_l < (732, 460)) & (ideal_r > 20) & (ideal_r < (732, 460)), axis=1)  # fmt: skip
    assert inside.sum() > 150
    err_l = np.linalg.norm(looked_up(fixed.maps[0], ideal_l[inside]) - raw_l[inside], axis=1)
    err_r = np.linalg.norm(looked_up(fixed.maps[1], ideal_r[inside]) - raw_r[inside], axis=1)
    assert err_l.max() < 0.05 and err_r.max() < 0.05, (err_l.max(), err_r.max())
    stated_r = np.linalg.norm(looked_up(rect.maps[1], ideal_r[inside]) - raw_r[inside], axis=1)
    assert stated_r.max() > 0.5 and np.ptp(raw_r[inside, 1] - raw_l[inside, 1]) > 0.6
    np.testing.assert_allclose(fixed.uncorrected(ideal_l[inside]), raw_l[inside], atol=1e-6)
    np.testing.assert_allclose(fixed.K, K_true, atol=1e-12)
    assert fixed.baseline_m == pytest.approx(b, rel=1e-9) and fixed.fix is fix
    with pytest.raises(VisionError, match="corrected already"):
        fixed.corrected(fix)
    with pytest.raises(VisionError, match="not for a corrected rectification"):
        fixed.rectify_points(0, raw_l[:3])
    with pytest.raises(VisionError, match="focal lengths must be positive"):
        RectificationFix(K_left=K_true, dist_left=dist_l, K_right=0 * K_true_r,
                         dist_right=dist_r, R_left_right=R_true)  # fmt: skip
