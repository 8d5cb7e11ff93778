"""A z-buffered renderer of :class:`~quadnav.sim.scene.Scene` s for a :class:`PinholeCamera`.

Per polygon: cull (facing away, behind, outside the view), clip against the near plane in 3-D
(Sutherland-Hodgman), project; warp its texture from the mip level whose texels are about one
pixel (``cv2.warpPerspective``, the texture repeating) into the polygon's pixel bounding box
only; its inverse depth 1/z is affine in pixel coordinates, so the box's depth is one affine
expression; keep the pixels inside the polygon (``cv2.fillConvexPoly``) and nearer than the
z-buffer. Lens distortion: the ideal pinhole image (widened to cover what the lens sees) is
remapped once through a map computed from ``camera.undistort_pixels``.

Effects (:class:`RenderEffects`): exposure gain, vignetting, shot and read noise, from the
caller's generator; motion blur averages renders at poses over the exposure.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import SimError
from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.sim.scene import Scene, TexturedPolygon, clip_polygon

__all__ = ["RenderEffects", "RenderedFrame", "Renderer", "depth_noise", "look_at"]

FloatArray = NDArray[np.float64]
F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]

LENS_LOD_BIAS = 0.95  # through a lens: the remap resamples once more, half a level softer
_SHIFT = 4  # sub-pixel bits of the polygon outlines (cv2.fillConvexPoly)


@dataclass(frozen=True, slots=True)
class RenderedFrame:
    """A rendered grey ``image`` (uint8, h x w) and ``depth_m`` (float32, h x w): z along the
    optical axis, ``inf`` where nothing is hit."""

    image: U8
    depth_m: F32


@dataclass(frozen=True, slots=True, kw_only=True)
class RenderEffects:
    """Sensor effects on a rendered image: ``exposure_gain`` (1 = nominal; the image saturates
    at 255), ``vignetting`` (the fraction of light lost in the corners, falling off as r^2),
    ``shot_noise_dn`` (photon noise: variance = shot_noise_dn times the grey level) and
    ``read_noise_sigma`` (additive Gaussian, grey levels)."""

    exposure_gain: float = 1.0
    read_noise_sigma: float = 0.0
    shot_noise_dn: float = 0.0
    vignetting: float = 0.0

    def __post_init__(self) -> None:
        for name in ("exposure_gain", "read_noise_sigma", "shot_noise_dn", "vignetting"):
            x = getattr(self, name)
            if not (math.isfinite(x) and x >= 0):
                raise SimError(f"render effects: {name} must be finite and >= 0, got {x}")
        if self.vignetting >= 1:
            raise SimError(f"render effects: vignetting must be below 1, got {self.vignetting}")

    def apply(self, image: U8 | F32, rng: np.random.Generator) -> U8:
        """The image as the sensor returns it (uint8), all noise drawn from ``rng`` (one
        Gaussian per pixel: read and shot noise add in variance)."""
        out = np.asarray(image, np.float32) * np.float32(self.exposure_gain)
        if self.vignetting > 0:
            out *= _falloff(out.shape[0], out.shape[1], self.vignetting)
        np.minimum(out, 255.0, out=out)  # the pixel saturates before it is read out
        if self.shot_noise_dn > 0 or self.read_noise_sigma > 0:
            var = np.float32(self.shot_noise_dn) * out + np.float32(self.read_noise_sigma**2)
            out += np.sqrt(var) * rng.standard_normal(out.shape, dtype=np.float32)
        out += 0.5
        np.clip(out, 0.0, 255.0, out=out)
        return out.astype(np.uint8)  # truncating x + 0.5: rounding


@lru_cache(maxsize=16)
def _falloff(h: int, w: int, vignetting: float) -> F32:
    """1 - vignetting (r / r_corner)^2 over an h x w image (read-only, cached)."""
    y, x = np.ogrid[0:h, 0:w]
    r2 = ((x - 0.5 * (w - 1)) ** 2 + (y - 0.5 * (h - 1)) ** 2) / (
        0.25 * ((w - 1) ** 2 + (h - 1) ** 2)
    )
    out = np.asarray(1.0 - vignetting * r2, np.float32)
    out.flags.writeable = False
    return out


def depth_noise(
    depth_m: F32 | FloatArray,
    rng: np.random.Generator,
    *,
    sigma0_m: float,
    sigma_per_m2: float,
    min_range_m: float = 0.0,
    max_range_m: float = math.inf,
) -> F32:
    """An RGB-D sensor's depth (Kinect-like): Gaussian noise of sigma = ``sigma0_m`` +
    ``sigma_per_m2`` z^2; ``inf`` (no return) outside [``min_range_m``, ``max_range_m``] and
    where nothing was hit."""
    if not (sigma0_m >= 0 and sigma_per_m2 >= 0 and 0 <= min_range_m < max_range_m):
        raise SimError(
            "depth noise: sigma0_m and sigma_per_m2 must be >= 0 and min_range_m < max_range_m"
        )
    z = np.asarray(depth_m, np.float32)
    valid = np.isfinite(z) & (z >= min_range_m) & (z <= max_range_m)
    zv = np.where(valid, z, 0.0).astype(np.float32)
    sigma = np.float32(sigma0_m) + np.float32(sigma_per_m2) * zv * zv
    noisy = zv + sigma * rng.standard_normal(z.shape, dtype=np.float32)
    return np.where(valid, np.maximum(noisy, 0.0), np.inf).astype(np.float32)


@dataclass(frozen=True, slots=True)
class _Packed:
    """The scene's polygons as arrays, to cull and set up all of them at once per frame."""

    verts_W: FloatArray  # (N, V, 3), short polygons padded with their last point
    count: NDArray[np.int64]  # (N,)
    normal_W: FloatArray  # (N, 3)
    offset: FloatArray  # (N,) normal . p0
    axes_W: FloatArray  # (N, 3, 3) columns u_W, v_W and the texture origin (of its tile)
    wraps: NDArray[np.bool_]  # (N,) the polygon spans several tiles of its texture
    area_texels: FloatArray  # (N,) the polygon's area in level-0 texels
    n_levels: NDArray[np.int64]  # (N,)
    scale: FloatArray  # (N, L, 2) metres per texel along u, v of each mip level


def _area_vectors(p: FloatArray) -> FloatArray:
    """Twice the area vectors of polygons (..., V, 3) (padding by repeats adds nothing)."""
    q = np.concatenate([p[..., 1:, :], p[..., :1, :]], axis=-2)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    a, b, c = q[..., 0], q[..., 1], q[..., 2]
    return np.stack([(y * c - z * b).sum(-1), (z * a - x * c).sum(-1), (x * b - y * a).sum(-1)], -1)


def _pixel_area(uv: FloatArray) -> FloatArray:
    """The areas of polygons (..., V, 2) in pixels (shoelace)."""
    x, y = uv[..., 0], uv[..., 1]
    xn = np.concatenate([x[..., 1:], x[..., :1]], axis=-1)
    yn = np.concatenate([y[..., 1:], y[..., :1]], axis=-1)
    return np.asarray(0.5 * np.abs((x * yn - xn * y).sum(-1)), np.float64)


def _pack(polys: Sequence[TexturedPolygon]) -> _Packed:
    vmax = max(len(p.points_W) for p in polys)
    verts = np.empty((len(polys), vmax, 3))
    axes = np.empty((len(polys), 3, 3))
    wraps = np.zeros(len(polys), bool)
    for i, p in enumerate(polys):
        n = len(p.points_W)
        verts[i, :n] = p.points_W
        verts[i, n:] = p.points_W[-1]
        origin, wraps[i] = _tile_origin(p)
        axes[i] = np.column_stack([p.u_W, p.v_W, origin])
    normals = np.array([p.normal_W for p in polys])
    m = np.array([p.texture.m_per_texel for p in polys])
    area = 0.5 * np.linalg.norm(_area_vectors(verts), axis=1) / m**2
    return _Packed(
        verts,
        np.array([len(p.points_W) for p in polys], np.int64),
        normals,
        np.einsum("ij,ij->i", normals, verts[:, 0]),
        axes,
        wraps,
        area,
        np.array([len(p.texture.levels) for p in polys], np.int64),
        _scales(polys),
    )


def _scales(polys: Sequence[TexturedPolygon]) -> FloatArray:
    """Metres per texel (u, v) of every mip level of every polygon's texture (N, L, 2)."""
    n_levels = max(len(p.texture.levels) for p in polys)
    out = np.ones((len(polys), n_levels, 2))
    for i, p in enumerate(polys):
        h0, w0 = p.texture.image.shape
        for k, lv in enumerate(p.texture.levels):
            out[i, k] = (
                w0 / lv.shape[1] * p.texture.m_per_texel,
                h0 / lv.shape[0] * p.texture.m_per_texel,
            )
    return out


def _tile_origin(poly: TexturedPolygon) -> tuple[FloatArray, bool]:
    """The origin of the one texture tile that holds ``poly`` (and False), or the texture's
    origin and True if the polygon spans several tiles."""
    origin = poly.origin_W.copy()
    for axis, tile in zip((poly.u_W, poly.v_W), poly.texture.tile_m(), strict=True):
        c = (poly.points_W - poly.origin_W) @ axis / tile
        k = math.floor(float(c.mean()))
        if c.min() < k - 1e-6 or c.max() > k + 1 + 1e-6:
            return poly.origin_W, True
        origin += k * tile * axis
    return origin, False


@dataclass(frozen=True, slots=True)
class _Item:
    """One polygon to draw this frame: its index, its pixel box [x0, x1) x [y0, y1) in the ideal
    image, outline in that box (n, 2; fixed point), inverse depth plane ``a`` (1/z = a . (u, v,
    1), float32) and the homography ``G`` from its mip ``level``'s texels to the box."""

    index: int
    box: tuple[int, int, int, int]
    outline: NDArray[np.int32]
    a: F32
    G: FloatArray
    level: int
    inv_z_max: float  # the polygon's nearest point's 1/z


def look_at(eye_W: FloatArray, target_W: FloatArray, up_W: FloatArray | None = None) -> Pose:
    """``T_W_C`` of a camera at ``eye_W`` looking at ``target_W`` (image up towards ``up_W``,
    default world z; x if the view is vertical)."""
    eye, target = np.asarray(eye_W, np.float64), np.asarray(target_W, np.float64)
    z = target - eye
    if not (np.isfinite(z).all() and np.linalg.norm(z) > 0):
        raise SimError("look_at: eye_W and target_W must be finite and apart")
    z /= np.linalg.norm(z)
    up = np.array([0.0, 0.0, 1.0]) if up_W is None else np.asarray(up_W, np.float64)
    if np.linalg.norm(np.cross(z, up)) < 1e-6:
        up = np.array([1.0, 0.0, 0.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    return Pose(Rotation.from_matrix(np.column_stack([x, np.cross(z, x), z])), eye)


class Renderer:
    """Renders ``scene`` as ``camera`` sees it; two renderers may share one scene (its
    textures and mip pyramids are not copied). ``near_m``: the near clipping plane;
    ``mipmaps=False`` samples the full-resolution texture only (aliased: for comparison);
    ``max_ideal_pixels``: through a lens, the most pixels of the ideal pinhole image rendered
    before the remap, in sensor images. A strong barrel lens sees a wide view: EuRoC's makes the
    full ideal image 1.9 sensor images; 1.2 shrinks it (at most to 0.8 of the focal length) for
    about 1.5 times the speed, corners then within 0.1-0.15 px instead of 0.1."""

    def __init__(
        self,
        scene: Scene,
        camera: PinholeCamera,
        *,
        near_m: float = 0.02,
        mipmaps: bool = True,
        max_ideal_pixels: float = 10.0,
    ) -> None:
        if not 0.3 <= max_ideal_pixels <= 10.0:
            raise SimError(
                f"renderer max_ideal_pixels must be in [0.3, 10], got {max_ideal_pixels}"
            )
        self.max_ideal_pixels = max_ideal_pixels
        if not scene.polygons:
            raise SimError(f"scene {scene.name!r} is empty: it has no polygons to render")
        if not near_m > 0:
            raise SimError(f"renderer near_m must be > 0, got {near_m}")
        self.scene = scene
        self.camera = camera
        self.near_m = near_m
        self.mipmaps = mipmaps
        self._polys = scene.polygons
        self._packed = _pack(scene.polygons)
        for p in scene.polygons:  # build the shaded pyramids now (shared through the textures)
            p.texture.padded_levels(p.shade)
        self._setup_lens()
        u = np.arange(self._w, dtype=np.float32)
        v = np.arange(self._h, dtype=np.float32)
        self._U = np.ascontiguousarray(np.broadcast_to(u[None, :], (self._h, self._w)))
        self._V = np.ascontiguousarray(np.broadcast_to(v[:, None], (self._h, self._w)))

    def _setup_lens(self) -> None:
        """The ideal pinhole image (its size, K) and the remap of the lens distortion."""
        cam = self.camera
        w, h = cam.width, cam.height
        self._maps: tuple[F32, F32] | None = None
        K = cam.K.copy()
        self._lens_scale: FloatArray | None = None
        # the finest level whose texels span at least 1.4 pixels: a bilinear ramp narrower than
        # that aliases (edges wobble by a tenth of a pixel), where a camera's optics blur
        self._lod_bias = 0.45
        if not np.any(cam.dist):
            self._K, self._w, self._h = K, w, h
            return
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        ideal = cam.undistort_pixels(np.column_stack([u.ravel(), v.ravel()])).reshape(h, w, 2)
        ok = np.asarray(np.isfinite(ideal).all(axis=2), bool)
        lo = np.where(ok[..., None], ideal, np.inf).reshape(-1, 2).min(axis=0)
        hi = np.where(ok[..., None], ideal, -np.inf).reshape(-1, 2).max(axis=0)
        # widen the ideal image to what the lens sees (at most its own size on each side), and
        # shrink it to about the sensor's pixel count: a barrel lens squeezes the wide edges, so
        # the full-size ideal image of EuRoC's lens has 1.9 times the sensor's pixels
        s = self._ideal_scale(lo, hi, w, h)
        lo, hi = s * lo, s * hi
        pl = int(np.clip(math.ceil(-lo[0]) + 2, 0, w))
        pt = int(np.clip(math.ceil(-lo[1]) + 2, 0, h))
        pr = int(np.clip(math.ceil(hi[0] - (s * w - 1)) + 2, 0, w))
        pb = int(np.clip(math.ceil(hi[1] - (s * h - 1)) + 2, 0, h))
        K[:2] *= s
        K[0, 2] += pl
        K[1, 2] += pt
        self._K = K
        self._w = math.ceil(s * w) + pl + pr
        self._h = math.ceil(s * h) + pt + pb
        mx = np.where(ok, s * ideal[..., 0] + pl, -1.0).astype(np.float32)
        my = np.where(ok, s * ideal[..., 1] + pt, -1.0).astype(np.float32)
        self._maps = (mx, my)  # float maps: fixed-point ones round to 1/32 px
        # the depth takes the nearest ideal pixel (no blend across edges): rounded integer maps
        self._depth_map = cv2.convertMaps(mx, my, cv2.CV_16SC2, nninterpolation=True)[0]
        self._lens_scale = self._output_area(cam)
        # the remap resamples once more: half a level softer, or its bilinear taps alias edges
        self._lod_bias = LENS_LOD_BIAS

    @property
    def ideal_pixels(self) -> int:
        """Pixels of the ideal pinhole image rendered before the lens remap."""
        return self._w * self._h

    def _ideal_scale(self, lo: FloatArray, hi: FloatArray, w: int, h: int) -> float:
        """The scale of the ideal image: 1, or less where the lens's full view would have more
        than ``max_ideal_pixels`` times the sensor's pixels (never below 0.8)."""
        full = (min(hi[0], 2 * w) - max(lo[0], -w) + 5) * (min(hi[1], 2 * h) - max(lo[1], -h) + 5)
        return float(np.clip(math.sqrt(self.max_ideal_pixels * w * h / full), 0.8, 1.0))

    def _output_area(self, cam: PinholeCamera, step: int = 16) -> FloatArray:
        """Output pixels per ideal pixel (by area) on a grid every ``step`` ideal pixels: the
        mip level is chosen for the output image, where the lens shrinks or swells things."""
        gx, gy = np.meshgrid(np.arange(0, self._w + step, step), np.arange(0, self._h + step, step))
        q = np.column_stack([gx.ravel(), gy.ravel()]).astype(np.float64)
        Kinv = np.linalg.inv(self._K)

        def project(p: FloatArray) -> FloatArray:
            return cam.project(np.column_stack([p, np.ones(len(p))]) @ Kinv.T)

        o = project(q)
        jx, jy = project(q + [0.5, 0.0]) - o, project(q + [0.0, 0.5]) - o
        area = np.abs(jx[:, 0] * jy[:, 1] - jx[:, 1] * jy[:, 0]) / 0.25
        return np.asarray(np.where(np.isfinite(area), area, 1.0).reshape(gx.shape), np.float64)

    def render(self, T_W_C: Pose, *, blur_poses: Sequence[Pose] = ()) -> RenderedFrame:
        """The image and depth from ``T_W_C`` (camera: x right, y down, z forward). With
        ``blur_poses`` (the camera's poses over the exposure) the image is their renders'
        average (motion blur) and the depth is ``T_W_C``'s."""
        img, inv_z = self._render_ideal(T_W_C)
        with np.errstate(divide="ignore"):
            depth = np.asarray(1.0 / inv_z, np.float32)
        image = self._to_lens(img) if not blur_poses else img
        if self._maps is not None:
            depth = np.asarray(
                cv2.remap(  # type: ignore[call-overload, unused-ignore]  # map2 may be None (integer map1)
                    depth,
                    self._depth_map,
                    None,
                    cv2.INTER_NEAREST,
                    borderMode=cv2.BORDER_CONSTANT,
                    borderValue=float("inf"),
                ),
                np.float32,
            )
        if blur_poses:
            acc = np.zeros((self.camera.height, self.camera.width), np.float32)
            for T in blur_poses:
                acc += self._to_lens(self._render_ideal(T)[0])
            image = np.asarray(np.rint(acc / len(blur_poses)), np.uint8)
        return RenderedFrame(image, depth)

    def _to_lens(self, ideal: U8) -> U8:
        if self._maps is None:
            return ideal
        bg = float(self.scene.background_grey)
        return np.asarray(cv2.remap(ideal, *self._maps, cv2.INTER_LINEAR, borderValue=bg), np.uint8)

    def _visible(self, T_C_W: Pose, c_W: FloatArray) -> list[_Item]:
        """The polygons that may be seen this frame, nearest first."""
        P, K, near = self._packed, self._K, self.near_m
        R, t = T_C_W.R_A_B.as_matrix(), T_C_W.p_A_B
        idx = np.flatnonzero(P.normal_W @ c_W - P.offset > 1e-9)  # facing the camera
        vC = P.verts_W[idx] @ R.T + t
        z = vC[..., 2]
        # in front of the near plane and not wholly outside one side of the view
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        x, y = vC[..., 0], vC[..., 1]
        keep = z.max(axis=1) > near
        for side in (fx * x + (cx + 1) * z, (self._w - cx) * z - fx * x):
            keep &= side.max(axis=1) >= 0
        for side in (fy * y + (cy + 1) * z, (self._h - cy) * z - fy * y):
            keep &= side.max(axis=1) >= 0
        idx, vC, z = idx[keep], vC[keep], z[keep]
        front = z.min(axis=1) > near
        f, c = np.array([K[0, 0], K[1, 1]]), K[:2, 2]
        uv = vC[..., :2] / np.where(z > near, z, 1.0)[..., None] * f + c
        area_px = _pixel_area(uv)
        area_tx = P.area_texels[idx].copy()
        pieces: dict[int, FloatArray] = {}
        for kk in np.flatnonzero(~front):  # clip against the near plane
            k, i = int(kk), int(idx[kk])
            q = clip_polygon(vC[k, : P.count[i]], np.array([0.0, 0.0, 1.0]), near)
            if len(q) < 3:
                continue
            pieces[k] = q[:, :2] / q[:, 2:3] * f + c
            area_px[k] = _pixel_area(pieces[k])
            m = self._polys[i].texture.m_per_texel
            area_tx[k] = 0.5 * np.linalg.norm(_area_vectors(q)) / m**2
        lo, hi = uv.min(axis=1), uv.max(axis=1)
        for k, q in pieces.items():
            lo[k], hi[k] = q.min(axis=0), q.max(axis=0)
        x0 = np.clip(np.floor(lo[:, 0]), 0, self._w).astype(np.int64)
        y0 = np.clip(np.floor(lo[:, 1]), 0, self._h).astype(np.int64)
        x1 = np.clip(np.ceil(hi[:, 0]) + 1, 0, self._w).astype(np.int64)
        y1 = np.clip(np.ceil(hi[:, 1]) + 1, 0, self._h).astype(np.int64)
        drawn = (front | np.isin(np.arange(len(idx)), list(pieces))) & (x1 > x0) & (y1 > y0)
        zmin = z.min(axis=1)
        sel = np.flatnonzero(drawn)
        sel = sel[np.argsort(zmin[sel])]  # nearest first
        idx, uv, vC, area_px, area_tx = idx[sel], uv[sel], vC[sel], area_px[sel], area_tx[sel]
        x0, y0, x1, y1, zmin = x0[sel], y0[sel], x1[sel], y1[sel], zmin[sel]
        if self._lens_scale is not None:  # texels per output pixel, not per ideal one
            g = self._lens_scale
            cen = np.clip(np.rint(uv.mean(axis=1) / 16), 0, [g.shape[1] - 1, g.shape[0] - 1])
            area_px = area_px * g[cen[:, 1].astype(int), cen[:, 0].astype(int)]
        with np.errstate(divide="ignore"):
            lv = np.ceil(
                0.5 * np.log2(np.maximum(area_tx / np.maximum(area_px, 1e-9), 1.0)) + self._lod_bias
            )
        level = np.minimum(lv.astype(np.int64), P.n_levels[idx] - 1) * self.mipmaps
        n_C = P.normal_W[idx] @ R.T
        d_C = np.einsum("ij,ij->i", n_C, vC[:, 0])
        plane = (n_C @ np.linalg.inv(K) / d_C[:, None]).astype(np.float32)
        G = self._homographies(idx, R, t, level, x0, y0)
        corner = np.stack([x0, y0], axis=1)[:, None, :]
        outlines = np.rint((uv - corner) * (1 << _SHIFT)).astype(np.int32)
        inv_near = (1.0 / np.maximum(zmin, near)).tolist()  # clipped: the near plane
        boxes = np.stack([x0, y0, x1, y1], axis=1).tolist()
        clipped = {int(np.flatnonzero(sel == k)[0]): q for k, q in pieces.items() if k in sel}
        items = []
        for j, (i, n, lev) in enumerate(
            zip(idx.tolist(), P.count[idx].tolist(), level.tolist(), strict=True)
        ):
            if j in clipped:
                outline = np.rint((clipped[j] - corner[j]) * (1 << _SHIFT)).astype(np.int32)
            else:
                outline = outlines[j, :n]
            items.append(_Item(i, tuple(boxes[j]), outline, plane[j], G[j], lev, inv_near[j]))
        return items

    def _homographies(
        self,
        idx: NDArray[np.int64],
        R: FloatArray,
        t: FloatArray,
        level: NDArray[np.int64],
        x0: NDArray[np.int64],
        y0: NDArray[np.int64],
    ) -> FloatArray:
        """Per polygon, the map from texels of its mip level (padded by one texel when it lies
        in one tile) to pixels of its box: K [R u, R v, R o + t] S."""
        P = self._packed
        M = np.einsum("ij,njk->nik", R, P.axes_W[idx])
        M[:, :, 2] += t
        H = np.einsum("ij,njk->nik", self._K, M)
        st = P.scale[idx, level]
        pad = np.where(P.wraps[idx], 0.0, 1.0)
        # texel (i, j) centre at u = (i + 0.5 - pad) s, v = (j + 0.5 - pad) t from the origin
        G = np.empty_like(H)
        G[:, :, 0] = H[:, :, 0] * st[:, 0, None]
        G[:, :, 1] = H[:, :, 1] * st[:, 1, None]
        G[:, :, 2] = (0.5 - pad)[:, None] * (G[:, :, 0] + G[:, :, 1]) + H[:, :, 2]
        G[:, 0] -= x0[:, None] * G[:, 2]
        G[:, 1] -= y0[:, None] * G[:, 2]
        return np.asarray(G, np.float64)

    def _render_ideal(self, T_W_C: Pose) -> tuple[U8, F32]:
        """The ideal pinhole image and its inverse depth (0 where nothing is hit)."""
        R = T_W_C.R_A_B.as_matrix()
        if not (np.isfinite(T_W_C.p_A_B).all() and np.isfinite(R).all()):
            raise SimError("camera pose T_W_C is not finite")
        img = np.full((self._h, self._w), self.scene.background_grey, np.uint8)
        inv_z = np.zeros((self._h, self._w), np.float32)
        for item in self._visible(T_W_C.inverse(), T_W_C.p_A_B):
            self._draw(item, img, inv_z)
        return img, inv_z

    def _draw(self, item: _Item, img: U8, inv_z: F32) -> None:
        """One polygon into the z-buffered image (its box only)."""
        x0, y0, x1, y1 = item.box
        a = item.a
        roi_z = inv_z[y0:y1, x0:x1]
        z_lo, z_hi, _, _ = cv2.minMaxLoc(roi_z)
        if z_lo > item.inv_z_max:  # all of its box is nearer already
            return
        U, V = self._U[y0:y1, x0:x1], self._V[y0:y1, x0:x1]
        plane = cv2.addWeighted(U, float(a[0]), V, float(a[1]), float(a[2]), dtype=cv2.CV_32F)
        mask: U8 = np.zeros(roi_z.shape, np.uint8)
        cv2.fillConvexPoly(mask, item.outline, 255, cv2.LINE_8, _SHIFT)
        G = item.G
        if z_hi > 0:  # something drawn here already: the depth test
            cv2.bitwise_and(mask, cv2.compare(plane, roi_z, cv2.CMP_GT), dst=mask)
            bx, by, bw, bh = cv2.boundingRect(mask)
            if bw == 0:
                return
            if bw * bh < 0.8 * mask.size:  # partly hidden: warp only what shows
                G = G.copy()
                G[0] -= bx * G[2]
                G[1] -= by * G[2]
                mask, plane = mask[by : by + bh, bx : bx + bw], plane[by : by + bh, bx : bx + bw]
                roi_z = roi_z[by : by + bh, bx : bx + bw]
                x0, y0 = x0 + bx, y0 + by
        poly = self._polys[item.index]
        tex = poly.texture.padded_levels(poly.shade)[item.level]
        if self._packed.wraps[item.index]:  # spans tiles: the texture wraps around (slower)
            tex, border = tex[1:-1, 1:-1], cv2.BORDER_WRAP
        else:  # one tile: its padding interpolates across the edges, the rest is cut off
            border = cv2.BORDER_CONSTANT
        h, w = int(mask.shape[0]), int(mask.shape[1])
        warped = cv2.warpPerspective(tex, G, (w, h), flags=cv2.INTER_LINEAR, borderMode=border)
        cv2.copyTo(warped, mask, img[y0 : y0 + h, x0 : x0 + w])
        cv2.copyTo(plane, mask, roi_z)
