"""OpenCV's YAML files (``%YAML:1.0``, ``!!opencv-matrix``): camera calibrations, detector
parameters, custom ArUco dictionaries and the thesis's ``vision_params.yml``.

Read through ``cv2.FileStorage``, which is what wrote them; every failure is one
:class:`~quadnav.errors.IoError` line naming the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from quadnav.errors import GeometryError, IoError
from quadnav.geometry.camera import PinholeCamera

__all__ = ["read_camera_yaml", "read_opencv_yaml", "write_camera_yaml"]


def _node_value(node: Any) -> Any:
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    if node.isMap():
        if {"rows", "cols", "data"} <= set(node.keys()):
            return np.asarray(node.mat(), dtype=np.float64)
        return {k: _node_value(node.getNode(k)) for k in node.keys()}  # noqa: SIM118 (a FileNode)
    if node.isSeq():
        return [_node_value(node.at(i)) for i in range(node.size())]
    return None


def read_opencv_yaml(path: str | Path) -> dict[str, Any]:
    """Every top-level entry of an OpenCV YAML file: numbers, strings, matrices (arrays)."""
    p = Path(path)
    if not p.is_file():
        raise IoError(f"{p}: no such file")
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV's parser raises either on garbage
        lines = str(exc).strip().splitlines()
        raise IoError(
            f"{p}: not an OpenCV YAML file ({lines[-1] if lines else 'unreadable'})"
        ) from None
    if not fs.isOpened():
        raise IoError(f"{p}: cannot be read as an OpenCV YAML file")
    try:
        root = fs.root()
        return {k: _node_value(root.getNode(k)) for k in root.keys()}  # noqa: SIM118 (a FileNode)
    finally:
        fs.release()


def read_camera_yaml(path: str | Path) -> PinholeCamera:
    """A calibration as OpenCV writes it: ``camera_matrix``, ``distortion_coefficients``,
    ``image_width``, ``image_height``."""
    d = read_opencv_yaml(path)
    missing = [k for k in ("camera_matrix", "distortion_coefficients") if k not in d]
    if missing:
        raise IoError(f"{path}: not a camera calibration, missing {', '.join(missing)}")
    K = d["camera_matrix"]
    if not isinstance(K, np.ndarray):
        raise IoError(f"{path}: camera_matrix is not a matrix")
    width = int(d.get("image_width", round(2 * K[0, 2])))
    height = int(d.get("image_height", round(2 * K[1, 2])))
    try:
        return PinholeCamera(K, np.asarray(d["distortion_coefficients"]), width, height)
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None


def write_camera_yaml(path: str | Path, camera: PinholeCamera, **extra: float | str) -> None:
    """Write a calibration in OpenCV's layout (readable by OpenCV and the thesis programs)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise IoError(f"{path}: cannot be written")
    try:
        fs.write("image_width", camera.width)
        fs.write("image_height", camera.height)
        fs.write("camera_matrix", camera.K)
        fs.write("distortion_coefficients", camera.dist.reshape(1, -1))
        for k, v in extra.items():
            fs.write(k, v)
    finally:
        fs.release()
