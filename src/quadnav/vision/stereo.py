"""Stereo rectification of a rig's first two cameras.

``T_C0_C1 = T_B_C0^-1 T_B_C1`` is the pose of the right camera in the left one; OpenCV's
``stereoRectify`` wants the map of left-camera points into the right camera, ``T_C1_C0``. The
lens model picks ``cv2.stereoRectify`` (radial-tangential) or ``cv2.fisheye.stereoRectify``
(equidistant). The undistort-rectify maps are computed once; :meth:`StereoRectifier.rectify`
remaps a pair. After it a point lies on the same image row in both pictures, and
``Q`` reprojects (x, y, disparity) to 3-D in the rectified left camera."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VisionError
from quadnav.geometry.camera import PinholeCamera
from quadnav.rig import CameraSpec, Rig

__all__ = ["StereoRectifier"]

FloatArray = NDArray[np.float64]


class StereoRectifier:
    """The rectification of ``rig``'s first two cameras: ``R0``/``R1`` (rotation of each
    rectified camera from its original), ``P0``/``P1`` (3x4 projections), ``Q`` (4x4), the
    maps (computed here, once) and the output ``size`` (the cameras'). ``alpha`` 0 keeps only
    valid pixels, 1 every source pixel (for the equidistant model it is the ``balance``)."""

    def __init__(self, rig: Rig, *, alpha: float = 0.0) -> None:
        if not rig.stereo:
            raise VisionError(f"rig {rig.name!r} has one camera: stereo needs two")
        left, right = rig.cameras[0], rig.cameras[1]
        a, b = left.camera, right.camera
        if a.model != b.model:
            raise VisionError(
                f"{left.name} and {right.name} have different lens models ({a.model}, {b.model})"
            )
        if (a.width, a.height) != (b.width, b.height):
            raise VisionError(f"{left.name} and {right.name} have different image sizes")
        if not 0.0 <= alpha <= 1.0:
            raise VisionError(f"stereo alpha must be in [0, 1], got {alpha}")
        T_C1_C0 = right.T_B_C.inverse() @ left.T_B_C
        t = T_C1_C0.p_A_B.reshape(3, 1)
        if np.linalg.norm(t) < 1e-6:
            raise VisionError(f"{left.name} and {right.name} are at the same place: no baseline")
        self.left, self.right = left, right
        self.size = (a.width, a.height)
        R = T_C1_C0.R_A_B.as_matrix()
        self.R0, self.R1, self.P0, self.P1, self.Q = _rectify(a, b, self.size, R, t, alpha)
        self.maps = (_map(a, self.R0, self.P0, self.size), _map(b, self.R1, self.P1, self.size))

    @classmethod
    def of_rig(cls, rig: Rig, *, alpha: float = 0.0) -> StereoRectifier:
        return cls(rig, alpha=alpha)

    @classmethod
    def of_cameras(
        cls, left: CameraSpec, right: CameraSpec, *, alpha: float = 0.0
    ) -> StereoRectifier:
        return cls(Rig(name="stereo", cameras=(left, right), imu=None), alpha=alpha)

    @property
    def K(self) -> FloatArray:
        """The rectified camera matrix (both cameras share it)."""
        return np.asarray(self.P0[:, :3], dtype=np.float64)

    @property
    def baseline_m(self) -> float:
        """The distance between the optical centres, from the rectified projection of the right
        camera (``P1[0, 3] = -fx * b``)."""
        return float(-self.P1[0, 3] / self.P1[0, 0])

    @property
    def camera(self) -> PinholeCamera:
        """The rectified, distortion-free camera (left; the right one is it shifted by the
        baseline)."""
        return PinholeCamera(self.K.copy(), np.zeros(0), self.size[0], self.size[1])

    def rectify(
        self, left: NDArray[np.uint8], right: NDArray[np.uint8]
    ) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """A rectified pair (bilinear remap)."""
        for img, spec in ((left, self.left), (right, self.right)):
            if img.shape[1::-1] != self.size:
                raise VisionError(
                    f"{spec.name} image is {img.shape[1]}x{img.shape[0]}, the calibration's {self.size[0]}x{self.size[1]}"
                )
        (l1, l2), (r1, r2) = self.maps
        out_l = cv2.remap(left, l1, l2, cv2.INTER_LINEAR)
        out_r = cv2.remap(right, r1, r2, cv2.INTER_LINEAR)
        return np.asarray(out_l, dtype=np.uint8), np.asarray(out_r, dtype=np.uint8)

    def rectify_points(self, which: int, px: FloatArray) -> FloatArray:
        """Rectified pixels (N, 2) of original ones of camera ``which`` (0 left, 1 right)."""
        spec = (self.left, self.right)[which]
        R, P = (self.R0, self.P0) if which == 0 else (self.R1, self.P1)
        return spec.camera.undistort_pixels(px, R=R, P=P)


def _rectify(
    a: PinholeCamera,
    b: PinholeCamera,
    size: tuple[int, int],
    R: FloatArray,
    t: FloatArray,
    alpha: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    if a.model == "equidistant":
        R0, R1, P0, P1, Q = cv2.fisheye.stereoRectify(
            a.K,
            a.dist,
            b.K,
            b.dist,
            size,
            R,
            t,
            flags=cv2.CALIB_ZERO_DISPARITY,
            newImageSize=size,
            balance=alpha,
            fov_scale=1.0,
        )
    else:
        R0, R1, P0, P1, Q, _, _ = cv2.stereoRectify(
            a.K, a.dist, b.K, b.dist, size, R, t, flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha
        )
    return tuple(np.asarray(m, dtype=np.float64) for m in (R0, R1, P0, P1, Q))  # type: ignore[return-value]


def _map(
    cam: PinholeCamera, R: FloatArray, P: FloatArray, size: tuple[int, int]
) -> tuple[NDArray[np.int16], NDArray[np.uint16]]:
    if cam.model == "equidistant":
        m1, m2 = cv2.fisheye.initUndistortRectifyMap(cam.K, cam.dist, R, P, size, cv2.CV_16SC2)
    else:
        m1, m2 = cv2.initUndistortRectifyMap(cam.K, cam.dist, R, P, size, cv2.CV_16SC2)
    return np.asarray(m1), np.asarray(m2)
