"""Camera-IMU rigs: the named rigs carry the calibrations their sources publish."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.errors import GeometryError
from quadnav.experiments.marker_camera import thesis_mount
from quadnav.rig import RIGS, CameraSpec, DepthSpec, ImuNoiseModel, Rig, rig_named
from tests.shared_data import SHARED, needs

EUROC = SHARED / "euroc_micro" / "mav0"


def test_every_named_rig_builds_with_orthonormal_mounts() -> None:
    for name in RIGS:
        rig = rig_named(name)
        for cam in rig.cameras:
            R = cam.T_B_C.R_A_B.as_matrix()
            assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
            assert np.linalg.det(R) == pytest.approx(1.0)


def test_thesis003_camera_is_the_theses_vins_yaml() -> None:
    cam = rig_named("thesis003_sim").cameras[0]
    assert (cam.camera.width, cam.camera.height) == (640, 480)
    assert cam.camera.K[0, 0] == cam.camera.K[1, 1] == 381.3625
    assert (cam.camera.K[0, 2], cam.camera.K[1, 2]) == (320.5, 240.5)
    assert cam.rate_hz == 20.0
    imu = rig_named("thesis003_sim").imu
    assert imu is not None and imu.rate_hz == 200.0
    # forward looking on an FLU body: the optical axis is the body's x
    assert np.allclose(cam.T_B_C.R_A_B.apply([0.0, 0.0, 1.0]), [1.0, 0.0, 0.0])


def test_stereo_baselines_are_eurocs_and_the_zeds() -> None:
    assert rig_named("euroc").baseline_m == pytest.approx(0.110, abs=0.001)
    assert rig_named("zed").baseline_m == pytest.approx(0.120, abs=1e-9)
    assert rig_named("thesis003_sim").baseline_m == 0.0


def test_the_pi_camera_has_the_thesis_mount() -> None:
    T = rig_named("pi_camera").cameras[0].T_B_C
    assert np.allclose(T.R_A_B.as_matrix(), thesis_mount().R_A_B.as_matrix(), atol=1e-12)


@needs(EUROC)
def test_the_euroc_rig_is_its_sensor_yaml() -> None:
    import yaml

    rig = rig_named("euroc")
    for cam in rig.cameras:
        doc = yaml.safe_load(
            (EUROC / cam.name / "sensor.yaml").read_text().replace("%YAML:1.0", "")
        )
        T = np.array(doc["T_BS"]["data"]).reshape(4, 4)
        assert np.allclose(cam.T_B_C.matrix(), T, atol=1e-6)
        fu, fv, cu, cv = doc["intrinsics"]
        assert np.allclose(cam.camera.K[[0, 1, 0, 1], [0, 1, 2, 2]], [fu, fv, cu, cv])
        assert np.allclose(cam.camera.dist, doc["distortion_coefficients"])
    imu = yaml.safe_load((EUROC / "imu0" / "sensor.yaml").read_text().replace("%YAML:1.0", ""))
    assert rig.imu is not None
    assert rig.imu.noise.gyro_noise_density == imu["gyroscope_noise_density"]
    assert rig.imu.noise.accel_random_walk == imu["accelerometer_random_walk"]


def test_bad_rigs_are_refused_in_one_line() -> None:
    cam = rig_named("thesis003_sim").cameras[0]
    imu = rig_named("thesis003_sim").imu
    with pytest.raises(GeometryError, match="unknown rig 'kinect'"):
        rig_named("kinect")
    with pytest.raises(GeometryError, match="names a camera twice"):
        Rig(name="x", cameras=(cam, cam), imu=imu)
    with pytest.raises(GeometryError, match="depth registered to 'cam3'"):
        Rig(name="x", cameras=(cam,), imu=imu, depth=DepthSpec(camera="cam3"))
    with pytest.raises(GeometryError, match="rate_hz must be finite"):
        CameraSpec(name="c", camera=cam.camera, T_B_C=cam.T_B_C, rate_hz=float("nan"))
    with pytest.raises(GeometryError, match="exposure_s"):
        CameraSpec(name="c", camera=cam.camera, T_B_C=cam.T_B_C, rate_hz=20.0, exposure_s=0.1)
    with pytest.raises(GeometryError, match="gyro_noise_density"):
        ImuNoiseModel(
            gyro_noise_density=-1.0, gyro_random_walk=0, accel_noise_density=0, accel_random_walk=0
        )


def test_euroc_mono_is_eurocs_left_camera_and_imu() -> None:
    full, mono = rig_named("euroc"), rig_named("euroc_mono")
    assert mono.camera_names == ["cam0"] and not mono.stereo
    assert np.allclose(mono.cameras[0].T_B_C.matrix(), full.cameras[0].T_B_C.matrix())
    assert mono.imu is not None and full.imu is not None
    assert mono.imu.noise == full.imu.noise and mono.imu.rate_hz == full.imu.rate_hz
