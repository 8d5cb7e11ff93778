"""Depth images of an RGB-D rig in an EuRoC ASL folder: ``mav0/depth0/data/<t_ns>.png``, 16-bit
millimetres (0: no reading, as a RealSense or Kinect driver publishes them), ``data.csv`` as a
camera's, and a ``sensor.yaml`` naming the camera the depth is registered to, its scale
(``depth_scale``: counts per metre) and its noise model."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import GeometryError, IoError, SampleError
from quadnav.io.datasets.files import float_text, read_image_list, read_yaml, yaml_numbers
from quadnav.rig import DepthSpec

__all__ = ["DEPTH_FOLDER", "DEPTH_SCALE", "DepthFrame", "depth_png", "depth_yaml", "read_depth"]

DEPTH_FOLDER = "depth0"
#: Counts per metre of the 16-bit depth PNGs (millimetres; the largest reading is 65.535 m).
DEPTH_SCALE = 1000.0
F32 = NDArray[np.float32]


def _load_depth_m(path: str, scale: float) -> F32:
    raw = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if raw is None or raw.dtype != np.uint16 or raw.ndim != 2:
        raise SampleError(f"depth image {path} cannot be read (not a 16-bit grey PNG)")
    depth = raw.astype(np.float32) / np.float32(scale)
    depth[raw == 0] = np.inf
    return depth


@dataclass(frozen=True, slots=True, kw_only=True)
class DepthFrame:
    """One depth image at ``t_ns`` registered to ``camera``: ``depth_m()`` loads it (float32
    metres along the optical axis, ``inf`` where there is no reading)."""

    t_ns: int
    camera: str
    path: Path
    scale: float = DEPTH_SCALE

    def depth_m(self) -> F32:
        return _load_depth_m(str(self.path), self.scale)


def depth_png(depth_m: F32 | NDArray[np.float64]) -> NDArray[np.uint16]:
    """Metres to 16-bit millimetres; no reading (``inf``, NaN, <= 0, beyond 65.535 m) is 0."""
    d = np.asarray(depth_m, dtype=np.float64) * DEPTH_SCALE
    ok = np.isfinite(d) & (d > 0.5) & (d < 65535.5)
    return np.where(ok, np.rint(np.where(ok, d, 0.0)), 0).astype(np.uint16)


def depth_yaml(spec: DepthSpec) -> str:
    return (
        "%YAML:1.0\nsensor_type: depth\n"
        f"camera: {spec.camera}\ndepth_scale: {float_text(DEPTH_SCALE)}\n"
        f"sigma0_m: {float_text(spec.sigma0_m)}\nsigma_per_m2: {float_text(spec.sigma_per_m2)}\n"
        f"min_range_m: {float_text(spec.min_range_m)}\nmax_range_m: {float_text(spec.max_range_m)}\n"
    )


def read_depth(mav0: Path) -> tuple[DepthSpec | None, tuple[DepthFrame, ...]]:
    """The depth sensor and its frames of ``mav0`` (none when there is no ``depth0/``)."""
    folder = mav0 / DEPTH_FOLDER
    if not folder.is_dir():
        return None, ()
    path = folder / "sensor.yaml"
    doc = read_yaml(path)
    values = {
        k: yaml_numbers(doc, k, path, 1)[0]
        for k in ("depth_scale", "sigma0_m", "sigma_per_m2", "min_range_m", "max_range_m")
    }
    try:
        spec = DepthSpec(
            camera=str(doc.get("camera", "cam0")),
            sigma0_m=values["sigma0_m"],
            sigma_per_m2=values["sigma_per_m2"],
            min_range_m=values["min_range_m"],
            max_range_m=values["max_range_m"],
        )
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None
    if values["depth_scale"] <= 0:
        raise IoError(f"{path}: depth_scale must be > 0, got {values['depth_scale']}")
    _, stamps, names = read_image_list(folder / "data.csv")
    make = functools.partial(DepthFrame, camera=spec.camera, scale=values["depth_scale"])
    return spec, tuple(
        make(t_ns=t, path=folder / "data" / n) for t, n in zip(stamps, names, strict=True)
    )
