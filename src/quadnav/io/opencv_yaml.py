"""OpenCV's YAML files (``%YAML:1.0``, ``!!opencv-matrix``): camera calibrations, detector
parameters, custom ArUco dictionaries and the thesis's ``vision_params.yml``.

Read through ``cv2.FileStorage``, which is what wrote them; every failure is one
:class:`~quadnav.errors.IoError` line naming the file (a parse error with its line).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, TypeAlias

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import GeometryError, IoError
from quadnav.geometry.camera import PinholeCamera
from quadnav.io.frames import quiet_libraries

__all__ = [
    "OpenCvValue",
    "opencv_error_text",
    "read_camera_yaml",
    "read_opencv_yaml",
    "write_camera_yaml",
]

#: An entry of an OpenCV YAML file: a number, text, a matrix (``!!opencv-matrix``), a mapping
#: or a sequence of entries, or None (an empty node).
OpenCvValue: TypeAlias = (
    "int | float | str | NDArray[np.float64] | dict[str, OpenCvValue] | list[OpenCvValue] | None"
)


def _node_value(node: Any) -> OpenCvValue:
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return str(node.string())
    if node.isMap():
        if {"rows", "cols", "data"} <= set(node.keys()):
            return np.asarray(node.mat(), dtype=np.float64)
        return {k: _node_value(node.getNode(k)) for k in node.keys()}  # noqa: SIM118 (a FileNode)
    if node.isSeq():
        return [_node_value(node.at(i)) for i in range(node.size())]
    return None


_PARSE_ERROR = re.compile(r"\((\d+)\): ([^']+)'")
_CV_ERROR = re.compile(r"error: \(-?\d+:[^)]*\) (.*?)(?: in function '[^']*')?\s*$", re.S)


def opencv_error_text(exc: BaseException) -> str:
    """The problem an OpenCV error states, without its source file and function:
    ``line 2: missing , between the elements`` or ``params.minDistanceToBorder >= 0``.

    On a parse error OpenCV's Python binding raises ``SystemError`` ("<class
    'cv2.FileStorage'> returned a result with an exception set") with the real
    ``cv2.error`` as its cause; that one is read."""
    err = exc if isinstance(exc, cv2.error) else (exc.__cause__ or exc.__context__)
    text = str(err).strip() if isinstance(err, cv2.error) else ""
    if m := _PARSE_ERROR.search(text):
        problem = m.group(2).strip().rstrip(".")
        return f"line {m.group(1)}: {problem[:1].lower()}{problem[1:]}"
    if m := _CV_ERROR.search(text):
        return m.group(1).strip()
    return "OpenCV cannot parse it"


def read_opencv_yaml(path: str | Path) -> dict[str, OpenCvValue]:
    """Every top-level entry of an OpenCV YAML file: numbers, strings, matrices (arrays)."""
    p = Path(path)
    if p.is_dir():
        raise IoError(f"{p}: is a folder, not an OpenCV YAML/XML file")
    if not p.is_file():
        raise IoError(f"{p}: no such file")
    try:
        with quiet_libraries():
            fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV's parser raises either on garbage
        why = "the file is empty" if p.stat().st_size == 0 else opencv_error_text(exc)
        raise IoError(f"{p}: not an OpenCV YAML/XML file ({why})") from None
    if not fs.isOpened():
        raise IoError(f"{p}: not an OpenCV YAML/XML file (OpenCV cannot open it)")
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
    if not isinstance(K, np.ndarray) or K.shape != (3, 3):
        shape = "x".join(map(str, K.shape)) if isinstance(K, np.ndarray) else repr(K)
        raise IoError(f"{path}: camera_matrix must be a 3x3 matrix, got {shape}")
    size = {}
    for key, centre in (("image_width", K[0, 2]), ("image_height", K[1, 2])):
        value = d.get(key, round(2 * centre) if np.isfinite(centre) else 0)
        if not isinstance(value, int | float) or not np.isfinite(value):
            raise IoError(f"{path}: {key} must be a number of pixels, got {value!r}")
        size[key] = int(value)
    width, height = size["image_width"], size["image_height"]
    dist = d["distortion_coefficients"]
    if not isinstance(dist, np.ndarray | list):
        raise IoError(f"{path}: distortion_coefficients must be a matrix, got {dist!r}")
    try:
        return PinholeCamera(K, np.asarray(dist), width, height)
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None


def write_camera_yaml(path: str | Path, camera: PinholeCamera, **extra: float | str) -> None:
    """Write a calibration in OpenCV's layout (readable by OpenCV and the thesis programs)."""
    p = Path(path)
    if not p.parent.is_dir():
        raise IoError(f"{p}: cannot be written, no folder {p.parent}")
    if p.is_dir():
        raise IoError(f"{p}: cannot be written, it is a folder")
    with quiet_libraries():
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise IoError(f"{p}: cannot be written")
    try:
        fs.write("image_width", camera.width)
        fs.write("image_height", camera.height)
        fs.write("camera_matrix", camera.K)
        fs.write("distortion_coefficients", camera.dist.reshape(1, -1))
        for k, v in extra.items():
            fs.write(k, v)
    finally:
        fs.release()
