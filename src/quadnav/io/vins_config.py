"""VINS-Mono's configuration YAML (OpenCV FileStorage, ``%YAML:1.0``), as thesis 003 ran it.

It gives the camera (``model_type`` PINHOLE with ``distortion_parameters`` k1 k2 p1 p2 and
``projection_parameters`` fx fy cx cy, or KANNALA_BRANDT with k2..k5 and mu mv u0 v0), the
camera-to-IMU extrinsic (``extrinsicRotation`` and ``extrinsicTranslation``: ``imu^R_cam`` and
``imu^p_cam``, that is ``T_B_C`` with the IMU as the body), the IMU's noise (``acc_n``, ``gyr_n``,
``acc_w``, ``gyr_w``, read as the continuous densities Kalibr and EuRoC give), ``g_norm``, the
front end's ``max_cnt``, ``min_dist``, ``F_threshold``, ``equalize``, and the camera-IMU time
offset (``estimate_td``, ``td``: ``t_imu = t_cam + td``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.errors import GeometryError, IoError
from quadnav.geometry.camera import DistortionModel, PinholeCamera
from quadnav.geometry.multiview import nearest_rotation
from quadnav.geometry.rotations import Pose
from quadnav.io.datasets.files import read_yaml, yaml_numbers
from quadnav.rig import CameraSpec, ImuNoiseModel, ImuSpec, Rig
from quadnav.units import GRAVITY_M_S2, s_to_ns
from quadnav.vision.tracking import TrackerConfig

__all__ = ["VinsConfig", "read_vins_config"]

MODELS = ("PINHOLE", "KANNALA_BRANDT")


@dataclass(frozen=True, slots=True, kw_only=True)
class VinsConfig:
    """What a VINS-Mono configuration says: the rig (one camera, the IMU as the body), the front
    end's settings, gravity's magnitude, and whether the extrinsic and the time offset are to be
    estimated online; ``topics`` are the ROS topics it names (``imu_topic``, ``image_topic``)."""

    rig: Rig
    tracker: TrackerConfig
    g_norm_m_s2: float
    estimate_extrinsic: int
    estimate_td: bool
    topics: dict[str, str]


def _number(doc: dict[str, Any], key: str, path: Path) -> float:
    return yaml_numbers(doc, key, path, 1)[0]


def _section(doc: dict[str, Any], key: str, names: tuple[str, ...], path: Path) -> list[float]:
    sec = doc.get(key)
    if not isinstance(sec, dict):
        raise IoError(f"{path}: missing section {key!r} (with {', '.join(names)})")
    return [_number(sec, n, path) for n in names]


def _camera(doc: dict[str, Any], path: Path) -> PinholeCamera:
    model = str(doc.get("model_type", "PINHOLE")).upper()
    if model not in MODELS:
        raise IoError(
            f"{path}: model_type {model!r} is not one quadnav reads ({', '.join(MODELS)})"
        )
    w, h = int(_number(doc, "image_width", path)), int(_number(doc, "image_height", path))
    if model == "PINHOLE":
        dist = _section(doc, "distortion_parameters", ("k1", "k2", "p1", "p2"), path)
        fx, fy, cx, cy = _section(doc, "projection_parameters", ("fx", "fy", "cx", "cy"), path)
        kind: DistortionModel = "radtan"
    else:  # camodocal's Kannala-Brandt: theta_d = theta + k2 theta^3 + k3 theta^5 + ...
        dist = _section(doc, "projection_parameters", ("k2", "k3", "k4", "k5"), path)
        fx, fy, cx, cy = _section(doc, "projection_parameters", ("mu", "mv", "u0", "v0"), path)
        kind = "equidistant"
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    try:
        return PinholeCamera(K, np.array(dist), w, h, kind)
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None


def _extrinsic(doc: dict[str, Any], path: Path) -> Pose:
    R = np.array(yaml_numbers(doc, "extrinsicRotation", path, 9)).reshape(3, 3)
    p = np.array(yaml_numbers(doc, "extrinsicTranslation", path, 3))
    S = np.linalg.svd(R, compute_uv=False)
    if abs(float(np.linalg.det(R)) - 1.0) > 1e-3 or np.max(np.abs(S - 1.0)) > 1e-3:
        raise IoError(f"{path}: extrinsicRotation is not a rotation (det {np.linalg.det(R):.4f})")
    return Pose(Rotation.from_matrix(nearest_rotation(R)), p)


def _noise(doc: dict[str, Any], path: Path) -> ImuNoiseModel:
    try:
        return ImuNoiseModel(
            accel_noise_density=_number(doc, "acc_n", path),
            gyro_noise_density=_number(doc, "gyr_n", path),
            accel_random_walk=_number(doc, "acc_w", path),
            gyro_random_walk=_number(doc, "gyr_w", path),
        )
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None


def _tracker(doc: dict[str, Any], path: Path) -> TrackerConfig:
    fields: dict[str, object] = {}
    if "max_cnt" in doc:
        fields["max_features"] = int(_number(doc, "max_cnt", path))
    if "min_dist" in doc:
        fields["min_distance_px"] = _number(doc, "min_dist", path)
    if "F_threshold" in doc:
        fields["ransac_threshold_px"] = _number(doc, "F_threshold", path)
    if "equalize" in doc:
        fields["equalize"] = bool(_number(doc, "equalize", path))
    try:
        return TrackerConfig.model_validate(fields)
    except ValueError as exc:
        raise IoError(f"{path}: the front end's settings: {str(exc).splitlines()[-1]}") from None


def read_vins_config(
    path: Path | str, *, imu_rate_hz: float = 200.0, camera_rate_hz: float = 20.0
) -> VinsConfig:
    """A VINS-Mono configuration file; the IMU and camera rates, which it does not give, are
    the arguments (EuRoC's by default)."""
    path = Path(path)
    doc = read_yaml(path)
    g = _number(doc, "g_norm", path) if "g_norm" in doc else GRAVITY_M_S2
    if not 9.0 < g < 10.5:
        raise IoError(f"{path}: g_norm {g} m/s^2 is not Earth's gravity")
    td = _number(doc, "td", path) if "td" in doc else 0.0
    if not math.isfinite(td) or abs(td) > 1.0:
        raise IoError(f"{path}: td {td} s is not a camera-IMU time offset (|td| <= 1 s)")
    cam = CameraSpec(
        name="cam0",
        camera=_camera(doc, path),
        T_B_C=_extrinsic(doc, path),
        rate_hz=camera_rate_hz,
        time_offset_ns=s_to_ns(td),
    )
    rig = Rig(
        name=path.stem,
        cameras=(cam,),
        imu=ImuSpec(rate_hz=imu_rate_hz, noise=_noise(doc, path)),
    )
    topics: dict[str, str] = {k: str(doc[k]) for k in ("imu_topic", "image_topic") if k in doc}
    return VinsConfig(
        rig=rig,
        tracker=_tracker(doc, path),
        g_norm_m_s2=g,
        estimate_extrinsic=int(_number(doc, "estimate_extrinsic", path))
        if "estimate_extrinsic" in doc
        else 0,
        estimate_td=bool(_number(doc, "estimate_td", path)) if "estimate_td" in doc else False,
        topics=topics,
    )
