"""A stereo or RGB-D frame of the SLAM (ORB-SLAM2's ``Frame``): its ORB keypoints, each one's
right coordinate and depth, which are close (ThDepth), and the rectified camera they are
measured in."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import SlamError
from quadnav.slam.config import SlamConfig
from quadnav.vision.orb import OrbExtractor, OrbFeatures
from quadnav.vision.stereo_match import (
    StereoKeypoints,
    close_points,
    rgbd_keypoints,
    stereo_keypoints,
)

__all__ = ["Frame", "StereoCamera", "rgbd_frame", "stereo_frame"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class StereoCamera:
    """A rectified stereo camera (or an RGB-D one, with its virtual baseline): ``fx``, ``fy``,
    ``cx``, ``cy`` (px) of the left camera and the ``baseline_m`` to the right one."""

    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float

    def __post_init__(self) -> None:
        vals = (self.fx, self.fy, self.cx, self.cy, self.baseline_m)
        if not all(np.isfinite(v) for v in vals) or min(self.fx, self.fy, self.baseline_m) <= 0:
            raise SlamError(f"a stereo camera needs finite fx, fy, baseline > 0, got {vals}")

    @property
    def bf(self) -> float:
        """``fx b``: disparity (px) times depth (m)."""
        return self.fx * self.baseline_m

    def mismatch(self, there: StereoCamera, rel_tol: float) -> str | None:
        """The first of fx, fy, cx, cy and the baseline further than ``rel_tol`` (relative)
        from ``there``'s, as ``fx 441.7 there, 436.2 here``; None when all are within."""
        for name in ("fx", "fy", "cx", "cy", "baseline_m"):
            a, b = getattr(self, name), getattr(there, name)
            if abs(a - b) > rel_tol * max(abs(b), 1e-3):
                return f"{name} {b:.6g} there, {a:.6g} here"
        return None

    @property
    def intrinsics(self) -> tuple[float, float, float, float, float]:
        """(fx, fy, cx, cy, fx b), as the optimisers take them."""
        return self.fx, self.fy, self.cx, self.cy, self.bf


@dataclass(frozen=True, slots=True, kw_only=True)
class Frame:
    """One frame: ``t_ns``, its keypoints and descriptors (``features``), their right
    coordinates and depths (``stereo``), which are close (``close``), and the ``camera``."""

    t_ns: int
    features: OrbFeatures
    stereo: StereoKeypoints
    close: NDArray[np.bool_]
    camera: StereoCamera

    def __len__(self) -> int:
        return len(self.features)

    def points_C(self, idx: NDArray[np.int64]) -> FloatArray:
        """The keypoints ``idx`` (with a depth) back-projected into the left camera (M, 3)."""
        c = self.camera
        z = self.stereo.depth_m[idx]
        uv = self.features.uv_px[idx]
        return np.column_stack([(uv[:, 0] - c.cx) * z / c.fx, (uv[:, 1] - c.cy) * z / c.fy, z])


def stereo_frame(
    t_ns: int, left: object, right: object, camera: StereoCamera, extractor: OrbExtractor,
    config: SlamConfig,
) -> Frame:  # fmt: skip
    """A frame from a rectified stereo pair."""
    fl, ll = extractor.extract(left)
    fr, lr = extractor.extract(right)
    keys = stereo_keypoints(fl, fr, ll, lr, fx=camera.fx, baseline_m=camera.baseline_m,
                            config=config.stereo)  # fmt: skip
    return _frame(t_ns, fl, keys, camera, config)


def rgbd_frame(
    t_ns: int, image: object, depth_m: NDArray[np.floating], camera: StereoCamera,
    extractor: OrbExtractor, config: SlamConfig,
) -> Frame:  # fmt: skip
    """A frame from an image and its registered depth (m)."""
    f, _ = extractor.extract(image)
    keys = rgbd_keypoints(f, depth_m, fx=camera.fx, baseline_m=camera.baseline_m)
    return _frame(t_ns, f, keys, camera, config)


def _frame(
    t_ns: int, f: OrbFeatures, keys: StereoKeypoints, camera: StereoCamera, config: SlamConfig
) -> Frame:
    close = close_points(keys, baseline_m=camera.baseline_m,
                         th_depth_baselines=config.th_depth_baselines)  # fmt: skip
    return Frame(t_ns=int(t_ns), features=f, stereo=keys, close=close, camera=camera)
