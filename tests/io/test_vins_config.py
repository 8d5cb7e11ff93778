"""VINS-Mono's configuration YAML: the rig and front end it describes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quadnav.errors import IoError
from quadnav.io.vins_config import read_vins_config
from quadnav.rig import rig_named

# As VINS-Mono's EuRoC file lays it out (OpenCV FileStorage), with EuRoC cam0's own calibration.
EUROC_LIKE = """%YAML:1.0
imu_topic: "/imu0"
image_topic: "/cam0/image_raw"
model_type: PINHOLE
camera_name: camera
image_width: 752
image_height: 480
distortion_parameters:
   k1: -0.28340811
   k2: 0.07395907
   p1: 0.00019359
   p2: 1.76187114e-05
projection_parameters:
   fx: 458.654
   fy: 457.296
   cx: 367.215
   cy: 248.375
estimate_extrinsic: 0
extrinsicRotation: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [0.0148655429818, -0.999880929698, 0.00414029679422,
           0.999557249008, 0.0149672133247, 0.025715529948,
           -0.0257744366974, 0.00375618835797, 0.999660727178]
extrinsicTranslation: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [-0.0216401454975,-0.064676986768, 0.00981073058949]
max_cnt: 150
min_dist: 30
freq: 10
F_threshold: 1.0
equalize: 1
acc_n: 0.08
gyr_n: 0.004
acc_w: 0.00004
gyr_w: 2.0e-6
g_norm: 9.81007
estimate_td: 1
td: 0.004
"""

# Thesis 003's camera block (its code 5.3), with a camera looking along the IMU's x.
THESIS003 = """%YAML:1.0
imu_topic: "/raw_imu"
image_topic: "/camera/rgb/image_raw"
model_type: PINHOLE
camera_name: camera
image_width: 640
image_height: 480
distortion_parameters:
  k1: 0
  k2: 0
  p1: 0
  p2: 0
projection_parameters:
  fx: 381.3625
  fy: 381.3625
  cx: 320.5
  cy: 240.5
extrinsicRotation: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [0, 0, 1, -1, 0, 0, 0, -1, 0]
extrinsicTranslation: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [0.1, 0, 0]
acc_n: 0.1
gyr_n: 0.01
acc_w: 0.001
gyr_w: 0.0001
"""


def _write(tmp: Path, text: str, name: str = "config.yaml") -> Path:
    p = tmp / name
    p.write_text(text)
    return p


def test_vins_eurocs_file_gives_eurocs_cam0_and_the_front_end(tmp_path: Path) -> None:
    cfg = read_vins_config(_write(tmp_path, EUROC_LIKE))
    cam, ref = cfg.rig.cameras[0], rig_named("euroc").cameras[0]
    assert np.allclose(cam.camera.K, ref.camera.K) and np.allclose(cam.camera.dist, ref.camera.dist)
    assert np.allclose(cam.T_B_C.matrix(), ref.T_B_C.matrix(), atol=1e-9)
    assert cam.time_offset_ns == 4_000_000 and cfg.estimate_td
    assert cfg.tracker.max_features == 150 and cfg.tracker.min_distance_px == 30.0
    assert cfg.tracker.ransac_threshold_px == 1.0 and cfg.tracker.equalize
    assert cfg.rig.imu is not None and cfg.rig.imu.noise.accel_noise_density == 0.08
    assert cfg.rig.imu.noise.gyro_random_walk == 2.0e-6
    assert cfg.g_norm_m_s2 == 9.81007 and cfg.topics["image_topic"] == "/cam0/image_raw"


def test_thesis_003s_camera_is_the_built_in_rigs(tmp_path: Path) -> None:
    cfg = read_vins_config(_write(tmp_path, THESIS003))
    cam, ref = cfg.rig.cameras[0], rig_named("thesis003_sim").cameras[0]
    assert np.allclose(cam.camera.K, ref.camera.K) and not cam.camera.distorted
    assert np.allclose(cam.T_B_C.matrix(), ref.T_B_C.matrix())
    assert (cam.camera.width, cam.camera.height) == (640, 480)
    assert not cfg.estimate_td and cam.time_offset_ns == 0


def test_a_kannala_brandt_camera_is_the_equidistant_model(tmp_path: Path) -> None:
    text = THESIS003.replace("model_type: PINHOLE", "model_type: KANNALA_BRANDT").replace(
        "projection_parameters:\n  fx: 381.3625\n  fy: 381.3625\n  cx: 320.5\n  cy: 240.5",
        "projection_parameters:\n  k2: 0.01\n  k3: -0.002\n  k4: 0.0\n  k5: 0.0\n"
        "  mu: 190.0\n  mv: 190.5\n  u0: 254.9\n  v0: 256.9",
    )
    cam = read_vins_config(_write(tmp_path, text)).rig.cameras[0].camera
    assert cam.model == "equidistant"
    assert np.allclose(cam.dist, [0.01, -0.002, 0.0, 0.0]) and cam.K[0, 0] == 190.0


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("model_type: PINHOLE", "model_type: MEI"), "model_type 'MEI' is not one quadnav reads"),
        (("  fx: 381.3625\n", ""), "missing key 'fx'"),
        (("data: [0, 0, 1, -1, 0, 0, 0, -1, 0]", "data: [0, 0, 2, -1, 0, 0, 0, -1, 0]"), "not a rotation"),
        (("acc_n: 0.1", "acc_n: -0.1"), "accel_noise_density"),
        (("acc_n: 0.1", "acc_n: 0.1\ng_norm: 3.7"), "g_norm 3.7"),
        (("acc_n: 0.1", "acc_n: 0.1\nmax_cnt: 5"), "front end"),
    ],
)  # fmt: skip
def test_bad_vins_configs_are_one_line_errors(
    tmp_path: Path, edit: tuple[str, str], message: str
) -> None:
    with pytest.raises(IoError, match=message) as info:
        read_vins_config(_write(tmp_path, THESIS003.replace(*edit)))
    assert "\n" not in str(info.value)
