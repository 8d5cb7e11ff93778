"""A pinhole camera with a lens distortion model: OpenCV's radial-tangential one (``k1 k2 p1 p2
[k3 [k4 k5 k6 ...]]``, Kalibr's ``radtan``) or the equidistant (Kannala-Brandt, OpenCV's fisheye,
Kalibr's ``equidistant``: ``k1 k2 k3 k4``).

Pure maths on arrays; reading and writing OpenCV YAML files is in :mod:`quadnav.io.opencv_yaml`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import GeometryError

__all__ = ["DISTORTION_MODELS", "DistortionModel", "PinholeCamera", "thesis_camera"]

FloatArray = NDArray[np.float64]
DistortionModel = Literal["radtan", "equidistant"]
DISTORTION_MODELS: tuple[DistortionModel, ...] = ("radtan", "equidistant")
#: when undistorting points stops: converged to 1e-10, or after 30 iterations
UNDISTORT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-10)


@dataclass(frozen=True, slots=True)
class PinholeCamera:
    """Intrinsics ``K`` (3x3), distortion coefficients (OpenCV order) and image size (px);
    ``model`` says how to read the coefficients (``radtan``: OpenCV's default model, 0, 4, 5, 8,
    12 or 14 of them; ``equidistant``: OpenCV's fisheye model, exactly 4)."""

    K: FloatArray
    dist: FloatArray
    width: int
    height: int
    model: DistortionModel = "radtan"

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        d = np.asarray(self.dist, dtype=np.float64).ravel()
        if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise GeometryError(
                f"camera matrix must be 3x3 with positive focal lengths, got {K.tolist()}"
            )
        if self.model not in DISTORTION_MODELS:
            raise GeometryError(
                f"distortion model must be one of {', '.join(DISTORTION_MODELS)}, got {self.model!r}"
            )
        if not np.isfinite(d).all():
            raise GeometryError(f"distortion coefficients must be finite, got {d.tolist()}")
        if self.model == "equidistant" and d.size == 0:
            d = np.zeros(4)
        if self.model == "equidistant" and d.size != 4:
            raise GeometryError(f"the equidistant model takes 4 coefficients, got {d.size}")
        if self.model == "radtan" and d.size not in (0, 4, 5, 8, 12, 14):
            raise GeometryError(
                f"distortion must have 0, 4, 5, 8, 12 or 14 finite coefficients, got {d.size}"
            )
        if self.width <= 0 or self.height <= 0:
            raise GeometryError(f"image size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", d)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    def project(self, p_C: FloatArray) -> FloatArray:
        """Pixels (N, 2) of points (N, 3) in the camera frame (z forward, x right, y down)."""
        p = np.asarray(p_C, dtype=np.float64).reshape(-1, 1, 3)
        if self.model == "equidistant":
            px, _ = cv2.fisheye.projectPoints(p, np.zeros(3), np.zeros(3), self.K, self.dist)
            return np.asarray(px.reshape(-1, 2), dtype=np.float64)
        return project_radtan(self.K, self.dist, p)

    @property
    def distorted(self) -> bool:
        """Whether any distortion coefficient is non-zero."""
        return bool(np.any(self.dist))

    def undistort_pixels(
        self, px: FloatArray, R: FloatArray | None = None, P: FloatArray | None = None
    ) -> FloatArray:
        """Ideal (distortion-free) pixels of distorted ones, in the same camera matrix (or, with
        a rectification ``R`` and new camera matrix ``P``, in those).

        Iterated to convergence: OpenCV's default for the radial-tangential model stops after 5
        iterations, which leaves 0.1 px RMS and 0.3 px at the corners of EuRoC's lens
        (k1 = -0.28), a bias the same in every frame."""
        p = np.asarray(px, dtype=np.float64).reshape(-1, 1, 2)
        P = self.K if P is None else P
        if self.model == "equidistant":
            out = cv2.fisheye.undistortPoints(p, self.K, self.dist, R=R, P=P, criteria=UNDISTORT)
        else:
            out = cv2.undistortPoints(p, self.K, self.dist, None, R, P, criteria=UNDISTORT)
        return np.asarray(out.reshape(-1, 2), dtype=np.float64)

    def scaled(self, width: int, height: int) -> PinholeCamera:
        """The same lens at another resolution (focal lengths and centre scale with it)."""
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0] *= sx
        K[1] *= sy
        return PinholeCamera(K, self.dist.copy(), width, height, self.model)


def project_radtan(K: FloatArray, dist: FloatArray, p_C: FloatArray) -> FloatArray:
    """Pixels (N, 2) of points (N, 3, in front) in a camera of matrix ``K`` (3x3) and OpenCV's
    radial-tangential coefficients ``dist`` (``k1, k2, p1, p2``...; none: a pinhole)."""
    p = np.asarray(p_C, dtype=np.float64).reshape(-1, 1, 3)
    px, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), K, dist)
    return np.asarray(px.reshape(-1, 2), dtype=np.float64)


def thesis_camera() -> PinholeCamera:
    """Thesis 000's Raspberry Pi Camera v2 at 640x480 (its ``cal.yml``)."""
    return PinholeCamera(
        np.array(
            [[498.57027128, 0.0, 317.13790849], [0.0, 499.04454028, 253.31937807], [0.0, 0.0, 1.0]]
        ),
        np.array([0.16052725, -0.25643743, 0.00342303, 0.00516838, -0.15214634]),
        640,
        480,
    )
