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
