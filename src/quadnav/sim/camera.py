"""A synthetic camera: renders planar textured objects (markers, boards) lying in the world into
the image of a pinhole camera at any pose, with lens distortion, motion blur, exposure and
noise over a background texture.

One homography warp per object (``cv2.warpPerspective``) into an ideal pinhole image, then one
remap through the lens distortion; fast enough to close the loop at 30 Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import SimError
from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose

__all__ = [
    "PlanarObject",
    "RenderSettings",
    "SyntheticCamera",
    "board_object",
    "diamond_object",
    "marker_object",
]

FloatArray = NDArray[np.float64]
U8 = NDArray[np.uint8]


@dataclass(frozen=True, slots=True)
class PlanarObject:
    """A flat texture in the world: ``texture`` (gray, uint8), ``A`` (3x3) mapping texture
    pixels ``(u, v, 1)`` to points ``(x, y, 1)`` on the plane z = 0 of the object frame, and the
    object's pose in the world ``T_W_O``."""

    texture: U8
    A: FloatArray
    T_W_O: Pose
    name: str = ""

    def corners_O(self) -> FloatArray:
        """The texture's outline (4, 3) in the object frame."""
        h, w = self.texture.shape
        uv = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], dtype=np.float64)
        xy = (self.A @ uv.T).T
        xy = xy[:, :2] / xy[:, 2:3]
        return np.column_stack([xy, np.zeros(4)])


def marker_object(
    dictionary: cv2.aruco.Dictionary,
    marker_id: int,
    length_m: float,
    T_W_M: Pose,
    *,
    px_per_bit: int = 20,
    margin_bits: float = 1.0,
) -> PlanarObject:
    """A printed marker (centred on its frame, x right, y up, z out of the face) with a white
    quiet zone of ``margin_bits`` cells around it, as on paper."""
    bits = dictionary.markerSize + 2
    side = bits * px_per_bit
    img = cv2.aruco.generateImageMarker(dictionary, int(marker_id), side)
    m = round(margin_bits * px_per_bit)
    tex = np.asarray(cv2.copyMakeBorder(img, m, m, m, m, cv2.BORDER_CONSTANT, value=255), np.uint8)
    s = length_m / side  # metres per texture pixel
    half = 0.5 * length_m + m * s
    # Pixel centres sit at integer coordinates: texture pixel u covers [u - 0.5, u + 0.5].
    A = np.array([[s, 0.0, 0.5 * s - half], [0.0, -s, half - 0.5 * s], [0.0, 0.0, 1.0]])
    return PlanarObject(tex, A, T_W_M, f"marker {marker_id}")


def _pattern_object(
    board: cv2.aruco.Board,
    size_m: tuple[float, float],
    T_W_O: Pose,
    origin_m: tuple[float, float],
    px_per_m: float,
    margin_m: float,
    name: str,
) -> PlanarObject:
    """The image OpenCV prints of ``board`` (``size_m`` without the white margin), in a frame
    with x right, y up the printed image, z out of its face and the origin ``origin_m`` from
    the pattern's bottom-left corner."""
    w_m, h_m = size_m
    m_px = round(margin_m * px_per_m)
    w_px, h_px = round(w_m * px_per_m), round(h_m * px_per_m)
    img = board.generateImage((w_px + 2 * m_px, h_px + 2 * m_px), marginSize=m_px)
    s = 1.0 / px_per_m
    # Pixel centres sit at integer coordinates: texture pixel u covers [u - 0.5, u + 0.5].
    x0, y0 = (0.5 - m_px) * s - origin_m[0], h_m - (0.5 - m_px) * s - origin_m[1]
    A = np.array([[s, 0.0, x0], [0.0, -s, y0], [0.0, 0.0, 1.0]])
    return PlanarObject(np.asarray(img, np.uint8), A, T_W_O, name)


def board_object(
    board: cv2.aruco.Board,
    size_m: tuple[float, float],
    T_W_O: Pose,
    *,
    px_per_m: float = 1500.0,
    margin_m: float = 0.02,
) -> PlanarObject:
    """An OpenCV board (ChArUco or grid) of ``size_m`` in its face frame (origin at the
    bottom-left corner of the pattern, x right, y up, z out of the printed face, as
    :class:`~quadnav.vision.markers.CharucoTarget` poses it), with a white margin of
    ``margin_m``."""
    return _pattern_object(board, size_m, T_W_O, (0.0, 0.0), px_per_m, margin_m, "board")


def diamond_object(
    dictionary: cv2.aruco.Dictionary,
    ids: tuple[int, int, int, int],
    square_m: float,
    marker_m: float,
    T_W_D: Pose,
    *,
    px_per_m: float = 1500.0,
    margin_m: float = 0.02,
) -> PlanarObject:
    """A ChArUco diamond (a 3x3 ChArUco board of the markers ``ids``) centred on its frame
    (x right, y up, z out of the face), with a white margin of ``margin_m``."""
    board = cv2.aruco.CharucoBoard(
        (3, 3), square_m, marker_m, dictionary, np.asarray(ids, np.int32)
    )
    side = 3 * square_m
    o = 0.5 * side
    return _pattern_object(board, (side, side), T_W_D, (o, o), px_per_m, margin_m, f"diamond {ids}")


@dataclass(frozen=True, slots=True, kw_only=True)
class RenderSettings:
    """Image effects: ``noise_sigma`` (grey levels), ``exposure_gain`` (1 = nominal),
    ``blur_exposure_s`` (the shutter time that smears motion), ``background_level`` and
    ``background_contrast`` of the floor texture, the ``seed`` of its pattern."""

    noise_sigma: float = 2.0
    exposure_gain: float = 1.0
    blur_exposure_s: float = 0.0
    background_level: float = 150.0
    background_contrast: float = 40.0
    seed: int = 0


@dataclass
class SyntheticCamera:
    """Render :class:`PlanarObject` s into the image of ``camera`` at pose ``T_W_C``."""

    camera: PinholeCamera
    objects: list[PlanarObject]
    settings: RenderSettings = field(default_factory=RenderSettings)

    def __post_init__(self) -> None:
        w, h = self.camera.width, self.camera.height
        # For each distorted output pixel, where it comes from in the ideal pinhole image.
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        ideal = self.camera.undistort_pixels(np.column_stack([u.ravel(), v.ravel()]))
        self._map_x = ideal[:, 0].reshape(h, w).astype(np.float32)
        self._map_y = ideal[:, 1].reshape(h, w).astype(np.float32)
        self._distorted = bool(np.any(self.camera.dist))
        rng = np.random.default_rng(self.settings.seed)
        # A smooth random floor texture (noise blurred at two scales).
        coarse = cv2.resize(
            rng.standard_normal((h // 16 + 1, w // 16 + 1)), (w, h), interpolation=cv2.INTER_CUBIC
        )
        fine = cv2.GaussianBlur(rng.standard_normal((h, w)), (0, 0), 1.5)
        bg = self.settings.background_level + self.settings.background_contrast * (
            0.7 * coarse + 0.6 * fine
        )
        self._background = np.clip(bg, 0, 255).astype(np.uint8)
        cv2.setRNGSeed(self.settings.seed + 1)
        self._pyramids: list[list[U8]] = []
        self._R_WO = np.array([o.T_W_O.R_A_B.as_matrix() for o in self.objects]).reshape(-1, 3, 3)
        self._p_WO = np.array([o.T_W_O.p_A_B for o in self.objects]).reshape(-1, 3)
        self._corners_W = np.array([o.T_W_O @ o.corners_O() for o in self.objects]).reshape(
            -1, 4, 3
        )
        for obj in self.objects:
            levels = [obj.texture]
            while min(levels[-1].shape) >= 16:
                t = levels[-1]
                levels.append(
                    np.asarray(
                        cv2.resize(
                            t, (t.shape[1] // 2, t.shape[0] // 2), interpolation=cv2.INTER_AREA
                        ),
                        np.uint8,
                    )
                )
            self._pyramids.append(levels)

    def render(self, T_W_C: Pose, *, velocity_px_s: tuple[float, float] = (0.0, 0.0)) -> U8:
        """A grey image (h, w) of the scene from ``T_W_C`` (camera frame: x right, y down, z
        forward). ``velocity_px_s``: the image motion during the exposure, for the blur."""
        w, h = self.camera.width, self.camera.height
        ideal = self._background.copy()
        T_C_W = T_W_C.inverse()
        K = self.camera.K
        R_CW = T_C_W.R_A_B.as_matrix()
        p_CW = T_C_W.p_A_B
        # All objects' outlines in the camera at once: (n, 4, 3), then their pixels.
        corners_C = self._corners_W @ R_CW.T + p_CW
        depth_ok = np.all(corners_C[:, :, 2] > 0.05, axis=1)
        uvw = corners_C @ K.T
        uv = uvw[:, :, :2] / np.where(depth_ok[:, None, None], uvw[:, :, 2:3], 1.0)
        lo = np.floor(uv.min(axis=1)).astype(int) - 1
        hi = np.ceil(uv.max(axis=1)).astype(int) + 2
        visible = depth_ok & (hi[:, 0] > 0) & (hi[:, 1] > 0) & (lo[:, 0] < w) & (lo[:, 1] < h)
        for k in np.flatnonzero(visible):
            obj = self.objects[k]
            R = R_CW @ self._R_WO[k]
            t = R_CW @ self._p_WO[k] + p_CW
            H = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ obj.A
            # A camera pixel integrates over its footprint: warp from the pyramid level whose
            # texels are about one image pixel (no aliasing when the object is far).
            q = uv[k]
            area = 0.5 * abs(
                (q[0, 0] - q[2, 0]) * (q[1, 1] - q[3, 1])
                - (q[1, 0] - q[3, 0]) * (q[0, 1] - q[2, 1])
            )
            texels_per_px = math.sqrt(obj.texture.size / max(area, 1.0))
            level = min(
                max(math.floor(math.log2(max(texels_per_px, 1.0))), 0), len(self._pyramids[k]) - 1
            )
            tex = self._pyramids[k][level]
            scale = obj.texture.shape[1] / tex.shape[1]
            # texel centres of the coarser level: u = scale (u' + 0.5) - 0.5; and the warp
            # writes only into the object's bounding box (a field of markers stays cheap)
            x0, y0 = max(int(lo[k, 0]), 0), max(int(lo[k, 1]), 0)
            x1, y1 = min(int(hi[k, 0]), w), min(int(hi[k, 1]), h)
            S = np.array(
                [[scale, 0.0, 0.5 * scale - 0.5], [0.0, scale, 0.5 * scale - 0.5], [0.0, 0.0, 1.0]]
            )
            shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
            roi = np.ascontiguousarray(ideal[y0:y1, x0:x1])
            cv2.warpPerspective(
                tex,
                shift @ H @ S,
                (x1 - x0, y1 - y0),
                dst=roi,
                flags=cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_TRANSPARENT,
            )
            ideal[y0:y1, x0:x1] = roi
        return self._effects(ideal, velocity_px_s)

    def _effects(self, ideal: U8, velocity_px_s: tuple[float, float]) -> U8:
        """Lens distortion, motion blur over the exposure, exposure gain and sensor noise."""
        img: NDArray[np.uint8] = ideal
        if self._distorted:
            img = np.asarray(
                cv2.remap(
                    ideal,
                    self._map_x,
                    self._map_y,
                    cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE,
                ),
                np.uint8,
            )
        s = self.settings
        vx, vy = velocity_px_s
        length = math.hypot(vx, vy) * s.blur_exposure_s
        if length >= 1.0:
            n = math.ceil(length) | 1
            kernel = np.zeros((n, n), np.float32)
            c = n // 2
            ang = math.atan2(vy, vx)
            p1 = (round(c - c * math.cos(ang)), round(c - c * math.sin(ang)))
            p2 = (round(c + c * math.cos(ang)), round(c + c * math.sin(ang)))
            cv2.line(kernel, p1, p2, 1.0, 1)
            img = np.asarray(cv2.filter2D(img, -1, kernel / kernel.sum()), np.uint8)
        out = img.astype(np.float32)
        if s.exposure_gain != 1.0:
            out *= s.exposure_gain
        if s.noise_sigma > 0:
            noise = np.empty(out.shape, np.float32)
            cv2.randn(noise, np.zeros(1), np.full(1, s.noise_sigma))
            out += noise
        return np.asarray(np.clip(out, 0, 255), dtype=np.uint8)

    def check_pose(self, T_W_C: Pose) -> None:
        if not np.isfinite(T_W_C.p_A_B).all():
            raise SimError("camera pose is not finite")
