"""Stereo rectification of a rig's first two cameras.

``T_C0_C1 = T_B_C0^-1 T_B_C1`` is the pose of the right camera in the left one; OpenCV's
``stereoRectify`` wants the map of left-camera points into the right camera, ``T_C1_C0``. The
lens model picks ``cv2.stereoRectify`` (radial-tangential) or ``cv2.fisheye.stereoRectify``
(equidistant). The undistort-rectify maps are computed once; :meth:`StereoRectifier.rectify`
remaps a pair. After it a point lies on the same image row in both pictures, and
``Q`` reprojects (x, y, disparity) to 3-D in the rectified left camera.

A calibration found after the pair was rectified (a SLAM's self-calibrating adjustment: each
rectified image's own pinhole, the distortion the stated lens model left in it and the right
camera's turn) is folded into the maps by :meth:`StereoRectifier.corrected`, so that the
pair comes out as the ideal rectified pinhole pair of what was found."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VisionError
from quadnav.geometry.camera import PinholeCamera, project_radtan
from quadnav.rig import CameraSpec, Rig

__all__ = ["RectificationFix", "StereoRectifier"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, eq=False)
class RectificationFix:
    """What a rectified pair really is, found after it was rectified: each image's camera
    matrix (``K_left``, ``K_right``, 3x3), the distortion left in it (OpenCV's ``k1, k2, p1,
    p2``: ``dist_left``, ``dist_right``) and the right camera's turn from the left one
    (``R_left_right``: a ray in the right camera, in the left one's axes). The corrected pair is
    the ideal rectified pair of the left camera's pinhole."""

    K_left: FloatArray
    dist_left: FloatArray
    K_right: FloatArray
    dist_right: FloatArray
    R_left_right: FloatArray

    def __post_init__(self) -> None:
        arrays = (self.K_left, self.dist_left, self.K_right, self.dist_right, self.R_left_right)
        shapes = ((3, 3), (4,), (3, 3), (4,), (3, 3))
        for a, shape in zip(arrays, shapes, strict=True):
            if np.shape(a) != shape or not np.all(np.isfinite(a)):
                raise VisionError(f"a rectification fix needs finite {shape} arrays")
        R = np.asarray(self.R_left_right)
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise VisionError("a rectification fix's R_left_right is not a rotation")
        for K in (np.asarray(self.K_left), np.asarray(self.K_right)):
            if K[0, 0] <= 0 or K[1, 1] <= 0:
                raise VisionError("a rectification fix's focal lengths must be positive")

    @classmethod
    def of(
        cls, left: Sequence[float], right: Sequence[float], dist_left: Sequence[float],
        dist_right: Sequence[float], turn_rad: Sequence[float] | FloatArray,
    ) -> RectificationFix:  # fmt: skip
        """From each camera's ``(fx, fy, cx, cy)``, its ``k1, k2, p1, p2`` and the right
        camera's turn from the left one (a rotation vector, rad)."""
        from scipy.spatial.transform import Rotation

        def matrix(fx: float, fy: float, cx: float, cy: float) -> FloatArray:
            return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

        turn = np.asarray(turn_rad, np.float64)
        if len(left) != 4 or len(right) != 4 or turn.shape != (3,) or not np.isfinite(turn).all():
            raise VisionError("a rectification fix needs four numbers a camera and a 3-vector")
        return cls(
            K_left=matrix(*left), dist_left=np.asarray(dist_left, np.float64),
            K_right=matrix(*right), dist_right=np.asarray(dist_right, np.float64),
            R_left_right=Rotation.from_rotvec(turn).as_matrix(),
        )  # fmt: skip


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
        #: the fix folded into the maps (None: the stated calibration's rectification)
        self.fix: RectificationFix | None = None

    def corrected(self, fix: RectificationFix) -> StereoRectifier:
        """This rectification with ``fix`` folded into its maps: each output pixel is looked up
        where the fixed camera sees its ray in the stated rectified image. The rectified camera
        is the fixed left one's pinhole (both images), the baseline as stated."""
        if self.fix is not None:
            raise VisionError("this rectification is corrected already")
        out = object.__new__(StereoRectifier)
        out.__dict__.update(self.__dict__)
        K = np.asarray(fix.K_left, np.float64)
        b = self.baseline_m
        out.P0 = np.column_stack([K, np.zeros(3)])
        out.P1 = np.column_stack([K, [-K[0, 0] * b, 0.0, 0.0]])
        out.Q = _reprojection(K, b)
        out.maps = (
            _fold(self.maps[0], K, fix.K_left, fix.dist_left, np.eye(3), self.size),
            _fold(self.maps[1], K, fix.K_right, fix.dist_right, fix.R_left_right, self.size),
        )
        out.fix = fix
        return out

    def uncorrected(self, px: FloatArray) -> FloatArray:
        """The left image's pixels (N, 2) as the stated rectification has them (those of the
        corrected image looked up where its maps look them up); the same without a fix."""
        px = np.asarray(px, np.float64).reshape(-1, 2)
        if self.fix is None or len(px) == 0:
            return px
        K = np.asarray(self.P0[:, :3])
        rays = np.column_stack([(px[:, 0] - K[0, 2]) / K[0, 0], (px[:, 1] - K[1, 2]) / K[1, 1],
                                np.ones(len(px))])  # fmt: skip
        return project_radtan(self.fix.K_left, self.fix.dist_left, rays)

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
        """Rectified pixels (N, 2) of original ones of camera ``which`` (0 left, 1 right); not
        for a corrected rectification (its ``R1`` no longer describes the right camera)."""
        if self.fix is not None:
            raise VisionError("rectify_points: not for a corrected rectification")
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


def _reprojection(K: FloatArray, b: float) -> FloatArray:
    """``Q`` of a rectified pair of camera ``K`` and baseline ``b`` (OpenCV's, zero disparity at
    infinity): (x, y, disparity, 1) to 3-D in the left camera."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    return np.array([[1.0, 0.0, 0.0, -cx], [0.0, fx / fy, 0.0, -cy * fx / fy],
                     [0.0, 0.0, 0.0, fx], [0.0, 0.0, 1.0 / b, 0.0]])  # fmt: skip


def _fold(
    maps: tuple[NDArray[np.int16], NDArray[np.uint16]], K_new: FloatArray, K: FloatArray,
    dist: FloatArray, R: FloatArray, size: tuple[int, int],
) -> tuple[NDArray[np.int16], NDArray[np.uint16]]:  # fmt: skip
    """The maps of a rectification, each output pixel of the ideal camera ``K_new`` looked up
    where the camera ``K`` with distortion ``dist``, turned by ``R`` (its rays in the ideal
    camera's axes), sees the same ray in the image those maps make."""
    w, h = size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.column_stack([((u - K_new[0, 2]) / K_new[0, 0]).ravel(),
                            ((v - K_new[1, 2]) / K_new[1, 1]).ravel(), np.ones(w * h)])  # fmt: skip
    src = project_radtan(np.asarray(K), np.asarray(dist), rays @ np.asarray(R))  # (R^T r)
    sx = src[:, 0].reshape(h, w).astype(np.float32)
    sy = src[:, 1].reshape(h, w).astype(np.float32)
    fx, fy = cv2.convertMaps(maps[0], maps[1], cv2.CV_32FC1)
    nx = cv2.remap(fx, sx, sy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1)
    ny = cv2.remap(fy, sx, sy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1)
    outside = (sx < 0) | (sx > w - 1) | (sy < 0) | (sy > h - 1)  # (not blended with the fill)
    nx[outside], ny[outside] = -1.0, -1.0
    m1, m2 = cv2.convertMaps(nx, ny, cv2.CV_16SC2)
    return np.asarray(m1), np.asarray(m2)


def _map(
    cam: PinholeCamera, R: FloatArray, P: FloatArray, size: tuple[int, int]
) -> tuple[NDArray[np.int16], NDArray[np.uint16]]:
    if cam.model == "equidistant":
        m1, m2 = cv2.fisheye.initUndistortRectifyMap(cam.K, cam.dist, R, P, size, cv2.CV_16SC2)
    else:
        m1, m2 = cv2.initUndistortRectifyMap(cam.K, cam.dist, R, P, size, cv2.CV_16SC2)
    return np.asarray(m1), np.asarray(m2)
