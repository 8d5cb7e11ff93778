"""Kalibr's calibration files (and OpenVINS' variants of them): ``camchain.yaml`` (per camera ``T_cam_imu``, ``intrinsics``,
``distortion_model``, ``distortion_coeffs``, ``resolution``, ``timeshift_cam_imu``; ``T_cn_cnm1``
between neighbours) and ``imu.yaml`` (noise densities, ``update_rate``; TUM-VI's
``imu_config.yaml`` has the same keys at the top level).

The rig's body frame is the IMU's: ``T_B_C = T_cam_imu^-1``. A camchain has no frame rate: the
reader takes it from the caller (the stamps of the images)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from quadnav.errors import GeometryError, IoError
from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.io.datasets.files import float_text, pose_of_4x4, read_yaml, yaml_numbers
from quadnav.rig import CameraSpec, ImuNoiseModel, ImuSpec, Rig
from quadnav.units import NS_PER_S

__all__ = [
    "DISTORTION_NAMES",
    "read_camchain",
    "read_kalibr_imu",
    "write_camchain",
    "write_kalibr_imu",
]

#: Distortion names of the formats (EuRoC, Kalibr, ROS CameraInfo) -> the camera model's.
DISTORTION_NAMES = {
    "radial-tangential": "radtan",
    "radtan": "radtan",
    "plumb_bob": "radtan",
    "rational_polynomial": "radtan",
    "none": "radtan",
    "equidistant": "equidistant",
    "equi": "equidistant",
    "fisheye": "equidistant",
}

IMU_KEYS = {
    "gyro_noise_density": "gyroscope_noise_density",
    "gyro_random_walk": "gyroscope_random_walk",
    "accel_noise_density": "accelerometer_noise_density",
    "accel_random_walk": "accelerometer_random_walk",
}


def camera_of(
    intr: list[float], dist: list[float], model_name: Any, res: list[float], path: Path
) -> PinholeCamera:
    """A lens from a calibration file's ``intrinsics`` (fu fv cu cv), distortion and resolution."""
    model = DISTORTION_NAMES.get(str(model_name).lower())
    if model is None:
        raise IoError(
            f"{path}: distortion model {model_name!r} is not one of {', '.join(DISTORTION_NAMES)}"
        )
    fu, fv, cu, cv = intr
    K = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    try:
        return PinholeCamera(K, np.array(dist), int(res[0]), int(res[1]), model=model)  # type: ignore[arg-type]
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None


def _matrix_rows(doc: dict[str, Any], key: str, path: Path) -> Pose:
    return pose_of_4x4(yaml_numbers(doc, key, path, 16), path, key)


def _camchain_camera(
    doc: dict[str, Any], name: str, prev: CameraSpec | None, rate_hz: float, path: Path
) -> CameraSpec:
    where = Path(f"{path} ({name})")
    if doc.get("camera_model", "pinhole") != "pinhole":
        raise IoError(f"{where}: camera_model {doc.get('camera_model')!r} is not pinhole")
    lens = camera_of(
        yaml_numbers(doc, "intrinsics", where, 4),
        yaml_numbers(doc, "distortion_coeffs", where) if "distortion_coeffs" in doc else [],
        doc.get("distortion_model", "radtan"),
        yaml_numbers(doc, "resolution", where, 2),
        where,
    )
    if "T_cam_imu" in doc:
        T_B_C = _matrix_rows(doc, "T_cam_imu", where).inverse()
    elif "T_imu_cam" in doc:  # OpenVINS' kalibr_imucam_chain.yaml
        T_B_C = _matrix_rows(doc, "T_imu_cam", where)
    elif prev is not None and "T_cn_cnm1" in doc:
        T_B_C = prev.T_B_C @ _matrix_rows(doc, "T_cn_cnm1", where).inverse()
    elif prev is None:
        T_B_C = Pose.identity()
    else:
        raise IoError(f"{where}: missing key 'T_cam_imu' (or 'T_cn_cnm1')")
    shift = yaml_numbers(doc, "timeshift_cam_imu", where, 1)[0] if "timeshift_cam_imu" in doc else 0
    return CameraSpec(
        name=name,
        camera=lens,
        T_B_C=T_B_C,
        rate_hz=rate_hz,
        time_offset_ns=round(shift * NS_PER_S),
    )


def read_camchain(path: Path, rates_hz: Mapping[str, float]) -> tuple[CameraSpec, ...]:
    """The cameras of a Kalibr camchain (``cam0``, ``cam1``... in order)."""
    doc = read_yaml(path)
    names = sorted(
        (k for k in doc if k.startswith("cam") and k[3:].isdigit()), key=lambda k: int(k[3:])
    )
    if not names:
        raise IoError(f"{path}: no cam0/cam1... entries (not a Kalibr camchain)")
    cams: list[CameraSpec] = []
    for name in names:
        if not isinstance(doc[name], dict):
            raise IoError(f"{path}: {name} must be a mapping of keys")
        rate = rates_hz.get(name, 20.0)
        try:
            cams.append(_camchain_camera(doc[name], name, cams[-1] if cams else None, rate, path))
        except GeometryError as exc:
            raise IoError(f"{path}: {name}: {exc}") from None
    return tuple(cams)


def read_kalibr_imu(path: Path, rate_hz: float | None = None) -> ImuSpec:
    """An IMU from Kalibr's ``imu.yaml`` (under ``imu0``) or TUM-VI's ``imu_config.yaml``."""
    doc = read_yaml(path)
    if isinstance(doc.get("imu0"), dict):
        doc = doc["imu0"]
    noise = noise_from(doc, path)
    if "update_rate" in doc:
        rate_hz = yaml_numbers(doc, "update_rate", path, 1)[0]
    if rate_hz is None:
        raise IoError(f"{path}: missing key 'update_rate'")
    T_B_I = _matrix_rows(doc, "T_i_b", path).inverse() if "T_i_b" in doc else Pose.identity()
    try:
        return ImuSpec(rate_hz=rate_hz, noise=noise, T_B_I=T_B_I)
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None


def noise_from(doc: dict[str, Any], path: Path) -> ImuNoiseModel:
    """The noise densities of an EuRoC or Kalibr IMU file."""
    n = {ours: yaml_numbers(doc, theirs, path, 1)[0] for ours, theirs in IMU_KEYS.items()}
    try:
        return ImuNoiseModel(
            gyro_noise_density=n["gyro_noise_density"],
            gyro_random_walk=n["gyro_random_walk"],
            accel_noise_density=n["accel_noise_density"],
            accel_random_walk=n["accel_random_walk"],
        )
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None


def matrix_lines(T: Pose, indent: str) -> str:
    """A 4x4 as YAML rows of exact floats (indented past their key: OpenCV's reader needs it)."""
    M = T.matrix()
    return "".join(f"{indent}- [{', '.join(float_text(x) for x in row)}]\n" for row in M)


def numbers_text(values: Any) -> str:
    return "[" + ", ".join(float_text(float(x)) for x in np.asarray(values).ravel()) + "]"


def lens_fields(cam: PinholeCamera) -> tuple[str, str, str]:
    """(intrinsics, distortion coefficients, resolution) as YAML lists."""
    K = cam.K
    intr = numbers_text([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
    return intr, numbers_text(cam.dist), f"[{cam.width}, {cam.height}]"


def write_camchain(path: Path, rig: Rig, *, openvins: bool = False) -> None:
    """Kalibr's camchain of a rig (its IMU frame is the body's when it has no IMU), or with
    ``openvins`` OpenVINS' ``kalibr_imucam_chain.yaml``: ``%YAML:1.0`` first (OpenCV's
    FileStorage reads it) and ``T_imu_cam`` (the camera's pose in the IMU) for ``T_cam_imu``."""
    T_B_I = rig.imu.T_B_I if rig.imu is not None else Pose.identity()
    out = ["%YAML:1.0\n\n"] if openvins else []
    for k, spec in enumerate(rig.cameras):
        intr, dist, res = lens_fields(spec.camera)
        model = "equidistant" if spec.camera.model == "equidistant" else "radtan"
        T_I_C = T_B_I.inverse() @ spec.T_B_C
        if openvins:
            text = f"cam{k}:\n  T_imu_cam:\n" + matrix_lines(T_I_C, "    ")
        else:
            text = f"cam{k}:\n  T_cam_imu:\n" + matrix_lines(T_I_C.inverse(), "    ")
        if k > 0 and not openvins:
            T_cn_cnm1 = spec.T_B_C.inverse() @ rig.cameras[k - 1].T_B_C
            text += "  T_cn_cnm1:\n" + matrix_lines(T_cn_cnm1, "    ")
        overlaps = ", ".join(str(j) for j in range(len(rig.cameras)) if j != k)
        text += (
            f"  cam_overlaps: [{overlaps}]\n"
            f"  camera_model: pinhole\n  distortion_coeffs: {dist}\n"
            f"  distortion_model: {model}\n  intrinsics: {intr}\n  resolution: {res}\n"
            f"  rostopic: /cam{k}/image_raw\n"
            f"  timeshift_cam_imu: {float_text(spec.time_offset_ns / NS_PER_S)}\n"
        )
        out.append(text)
    path.write_text("".join(out), encoding="utf-8")


_IDENTITY_3 = "    - [1.0, 0.0, 0.0]\n    - [0.0, 1.0, 0.0]\n    - [0.0, 0.0, 1.0]\n"
_OPENVINS_IMU_MODEL = (
    '  model: "kalibr"\n'
    + "".join(f"  {k}:\n{_IDENTITY_3}" for k in ("Tw", "R_IMUtoGYRO", "Ta", "R_IMUtoACC"))
    + "  Tg:\n"
    + "    - [0.0, 0.0, 0.0]\n" * 3
)


def write_kalibr_imu(path: Path, rig: Rig, *, openvins: bool = False) -> None:
    """Kalibr's ``imu.yaml`` of the rig's IMU, or with ``openvins`` OpenVINS'
    ``kalibr_imu_chain.yaml`` (``%YAML:1.0`` first, an ideal IMU model: identity Tw, Ta)."""
    if rig.imu is None:
        raise IoError(f"rig {rig.name!r} has no IMU to write to {path}")
    n = rig.imu.noise
    text = "%YAML:1.0\n\n" if openvins else ""
    text += "imu0:\n  T_i_b:\n" + matrix_lines(rig.imu.T_B_I.inverse(), "    ")
    for ours, theirs in IMU_KEYS.items():
        text += f"  {theirs}: {float_text(getattr(n, ours))}\n"
    text += "  rostopic: /imu0\n  time_offset: 0.0\n"
    text += f"  update_rate: {float_text(rig.imu.rate_hz)}\n"
    text += _OPENVINS_IMU_MODEL if openvins else "  model: calibrated\n"
    path.write_text(text, encoding="utf-8")
