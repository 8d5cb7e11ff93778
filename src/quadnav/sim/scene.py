"""3-D worlds made of textured planar convex polygons, in the world frame W (ENU, metres).

A :class:`Texture` is a grey image with its size on the ground (metres per texel) and its mip
pyramid (built once, shared by every polygon and every renderer that uses it). A
:class:`TexturedPolygon` maps texture coordinates ``(u, v)`` (metres along ``u_W`` and ``v_W``
from ``origin_W``) onto its plane; it is seen from the side its normal points to (points
counter-clockwise seen from there) and the texture repeats across it. :func:`box` makes the six
faces of a box, facing out (furniture) or in (a room).

The built-in worlds (:data:`WORLDS`) take a :class:`WorldPlan`: the box the camera flies in,
a seed, optionally the flight path (furniture keeps its clearance from it) and a
``texture_poor`` fraction of surfaces made flat and low-contrast.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from types import MappingProxyType

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav.errors import SimError
from quadnav.geometry.rotations import Pose
from quadnav.sim.camera import marker_object
from quadnav.sim.textures import PHOTOS, flat_texture, make_texture

__all__ = [
    "LIGHT_DIR_W",
    "WORLDS",
    "Scene",
    "Texture",
    "TexturedPolygon",
    "WorldPlan",
    "add_markers",
    "box",
    "clip_polygon",
    "polygon",
    "tessellate",
]

FloatArray = NDArray[np.float64]
U8 = NDArray[np.uint8]

#: The fixed light of the Lambertian shading (unit, towards the light): above, a little aside.
LIGHT_DIR_W = np.array([0.35, 0.5, 0.79]) / np.linalg.norm([0.35, 0.5, 0.79])


@dataclass(frozen=True, slots=True, eq=False)
class Texture:
    """A grey ``image`` (uint8, h x w) whose texels are ``m_per_texel`` metres on a surface;
    ``levels`` is its mip pyramid (level k halves level k - 1 by area averaging)."""

    image: U8
    m_per_texel: float
    name: str = ""
    levels: tuple[U8, ...] = field(init=False, repr=False)
    _shaded: dict[int, tuple[U8, ...]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        img = np.asarray(self.image)
        if img.ndim != 2 or img.dtype != np.uint8 or min(img.shape) < 1:
            raise SimError(f"texture {self.name!r}: the image must be a 2-D uint8 array")
        if not (math.isfinite(self.m_per_texel) and self.m_per_texel > 0):
            raise SimError(
                f"texture {self.name!r}: m_per_texel must be > 0, got {self.m_per_texel}"
            )
        levels = [img]
        while min(levels[-1].shape) >= 2:
            t = levels[-1]
            half = cv2.resize(t, (t.shape[1] // 2, t.shape[0] // 2), interpolation=cv2.INTER_AREA)
            levels.append(np.asarray(half, np.uint8))
        object.__setattr__(self, "levels", tuple(levels))
        object.__setattr__(self, "_shaded", {})

    def tile_m(self) -> tuple[float, float]:
        """The texture's period on a surface (metres along u, v)."""
        h, w = self.image.shape
        return w * self.m_per_texel, h * self.m_per_texel

    def padded_levels(self, shade: float) -> tuple[U8, ...]:
        """The pyramid times ``shade`` (cached per 1/64 step), each level padded with one
        texel of its own wrap-around, so one tile interpolates across its edges as tiled."""
        key = round(shade * 64)
        if key not in self._shaded:
            f = key / 64.0
            self._shaded[key] = tuple(
                np.pad(np.asarray(cv2.convertScaleAbs(lv, alpha=f), np.uint8), 1, mode="wrap")
                for lv in self.levels
            )
        return self._shaded[key]


def _newell_normal(p: FloatArray) -> FloatArray:
    """The polygon's area vector (twice its area times its unit normal), Newell's method."""
    q = np.roll(p, -1, axis=0)
    return np.array(
        [
            np.sum((p[:, 1] - q[:, 1]) * (p[:, 2] + q[:, 2])),
            np.sum((p[:, 2] - q[:, 2]) * (p[:, 0] + q[:, 0])),
            np.sum((p[:, 0] - q[:, 0]) * (p[:, 1] + q[:, 1])),
        ]
    )


@dataclass(frozen=True, slots=True, eq=False)
class TexturedPolygon:
    """A planar convex polygon ``points_W`` (n, 3), counter-clockwise seen from its visible
    side; texture coordinates ``(u, v)`` in metres along ``u_W``, ``v_W`` (orthonormal, in
    the plane) from ``origin_W``; texel (i, j) covers u in [i, i + 1] m_per_texel (columns
    along u, rows along v). ``shade`` multiplies the texture (Lambertian lighting)."""

    points_W: FloatArray
    texture: Texture
    origin_W: FloatArray
    u_W: FloatArray
    v_W: FloatArray
    shade: float = 1.0
    name: str = ""
    normal_W: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        label = self.name or "polygon"
        p = np.asarray(self.points_W, np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 3:
            raise SimError(f"{label}: a polygon needs at least 3 points (n, 3), got {p.shape}")
        if not np.isfinite(p).all():
            raise SimError(f"{label}: polygon points are not finite")
        a = _newell_normal(p)
        size = float(np.ptp(p, axis=0).max())
        if np.linalg.norm(a) <= 1e-9 * max(size, 1e-9) ** 2 or size <= 0:
            raise SimError(f"{label}: the polygon has zero area")
        n = a / np.linalg.norm(a)
        if np.abs((p - p[0]) @ n).max() > 1e-6 * max(size, 1.0):
            raise SimError(f"{label}: the polygon's points are not in one plane")
        e = np.roll(p, -1, axis=0) - p
        turns = np.cross(e, np.roll(e, -1, axis=0)) @ n
        if (turns < -1e-12 * size**2).any():
            raise SimError(f"{label}: the polygon is not convex (or its points are out of order)")
        u, v = np.asarray(self.u_W, np.float64), np.asarray(self.v_W, np.float64)
        if abs(u @ n) > 1e-6 or abs(v @ n) > 1e-6 or abs(u @ v) > 1e-6:
            raise SimError(f"{label}: texture axes u_W, v_W must lie in the polygon's plane")
        if not (math.isfinite(self.shade) and 0 < self.shade <= 1):
            raise SimError(f"{label}: shade must be in (0, 1], got {self.shade}")
        object.__setattr__(self, "points_W", p)
        object.__setattr__(self, "origin_W", np.asarray(self.origin_W, np.float64))
        object.__setattr__(self, "u_W", u / np.linalg.norm(u))
        object.__setattr__(self, "v_W", v / np.linalg.norm(v))
        object.__setattr__(self, "normal_W", n)


def lambert_shade(normal_W: FloatArray, ambient: float = 0.55) -> float:
    """A fixed light's Lambertian factor for a face: ``ambient`` plus the rest times |n . l|
    (both sides of a face are lit, as by the light and its bounces)."""
    return ambient + (1.0 - ambient) * abs(float(np.dot(normal_W, LIGHT_DIR_W)))


def polygon(
    points_W: ArrayLike,
    texture: Texture,
    *,
    u_dir_W: ArrayLike | None = None,
    offset_m: tuple[float, float] = (0.0, 0.0),
    shade: float | None = None,
    name: str = "",
) -> TexturedPolygon:
    """A polygon whose texture runs along ``u_dir_W`` (default: its first edge; projected into
    the plane) with ``v = u x n`` (down the image when seen from the front), shifted by
    ``offset_m``; ``shade`` defaults to :func:`lambert_shade` of its normal."""
    p = np.asarray(points_W, np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 3:
        raise SimError(
            f"{name or 'polygon'}: a polygon needs at least 3 points (n, 3), got {p.shape}"
        )
    a = _newell_normal(p)
    if not np.isfinite(a).all() or np.linalg.norm(a) == 0:
        raise SimError(f"{name or 'polygon'}: the polygon has zero area")
    n = a / np.linalg.norm(a)
    d = p[1] - p[0] if u_dir_W is None else np.asarray(u_dir_W, np.float64)
    u = d - (d @ n) * n
    if np.linalg.norm(u) < 1e-12:
        raise SimError(f"{name or 'polygon'}: u_dir_W is normal to the polygon")
    u /= np.linalg.norm(u)
    v = np.cross(u, n)
    origin = p[0] - offset_m[0] * u - offset_m[1] * v
    s = lambert_shade(n) if shade is None else shade
    return TexturedPolygon(p, texture, origin, u, v, s, name)


def clip_polygon(points: FloatArray, normal: FloatArray, offset: float) -> FloatArray:
    """Sutherland-Hodgman: the part of the convex polygon ``points`` (n, 3) where
    ``normal . x >= offset`` (possibly empty: shape (0, 3))."""
    s = points @ normal - offset
    out: list[FloatArray] = []
    n = len(points)
    for i in range(n):
        j = (i + 1) % n
        if s[i] >= 0:
            out.append(points[i])
        if (s[i] >= 0) != (s[j] >= 0):
            t = s[i] / (s[i] - s[j])
            out.append(points[i] + t * (points[j] - points[i]))
    return np.array(out).reshape(-1, 3)


def tessellate(poly: TexturedPolygon, cell_m: float) -> list[TexturedPolygon]:
    """``poly`` cut along its texture's tiles, and each tile into cells of at most ``cell_m``
    (same texture mapping, so the texture stays continuous). A cell within one tile renders
    fast (no wrap-around) and gets its own mip level."""
    p, o = poly.points_W, poly.origin_W
    out = []
    tiles = poly.texture.tile_m()
    cuts = []
    for axis, tile in zip((poly.u_W, poly.v_W), tiles, strict=True):
        period = tile / max(1, math.ceil(tile / cell_m - 1e-9))
        c = (p - o) @ axis
        k0, k1 = math.floor(c.min() / period + 1e-9), math.ceil(c.max() / period - 1e-9)
        cuts.append([max(k * period, c.min()) for k in range(k0, k1)] + [c.max()])
    eu, ev = cuts
    if len(eu) == len(ev) == 2:
        return [poly]
    for i in range(len(eu) - 1):
        a = clip_polygon(p, poly.u_W, eu[i] + o @ poly.u_W)
        a = clip_polygon(a, -poly.u_W, -(eu[i + 1] + o @ poly.u_W))
        for j in range(len(ev) - 1):
            c = clip_polygon(a, poly.v_W, ev[j] + o @ poly.v_W)
            c = clip_polygon(c, -poly.v_W, -(ev[j + 1] + o @ poly.v_W))
            if len(c) >= 3 and np.linalg.norm(_newell_normal(c)) > 1e-10:
                out.append(replace(poly, points_W=c, name=f"{poly.name}[{i},{j}]"))
    return out


def box(
    lo_W: ArrayLike,
    hi_W: ArrayLike,
    textures: Texture | Sequence[Texture],
    *,
    inward: bool = False,
    rng: np.random.Generator | None = None,
    name: str = "box",
) -> list[TexturedPolygon]:
    """The six faces of the axis-aligned box [lo_W, hi_W], facing out (or ``inward``), in the
    order -x, +x, -y, +y, -z (bottom), +z (top); one texture for all or one per face. Side faces
    keep their texture upright; ``rng`` shifts each face's texture at random."""
    lo, hi = np.asarray(lo_W, np.float64), np.asarray(hi_W, np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or not (hi > lo).all():
        raise SimError(f"{name}: a box needs lo_W < hi_W on every axis, got {lo} and {hi}")
    tex = [textures] * 6 if isinstance(textures, Texture) else list(textures)
    if len(tex) != 6:
        raise SimError(f"{name}: give one texture or six, got {len(tex)}")
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    # counter-clockwise seen from outside
    faces = [
        [[x0, y1, z0], [x0, y0, z0], [x0, y0, z1], [x0, y1, z1]],
        [[x1, y0, z0], [x1, y1, z0], [x1, y1, z1], [x1, y0, z1]],
        [[x0, y0, z0], [x1, y0, z0], [x1, y0, z1], [x0, y0, z1]],
        [[x1, y1, z0], [x0, y1, z0], [x0, y1, z1], [x1, y1, z1]],
        [[x0, y0, z0], [x0, y1, z0], [x1, y1, z0], [x1, y0, z0]],
        [[x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]],
    ]
    out = []
    for k, f in enumerate(faces):
        pts = np.array(f[::-1] if inward else f, np.float64)
        n_out = np.cross(pts[1] - pts[0], pts[2] - pts[1])
        u_dir = np.array([1.0, 0.0, 0.0]) if k >= 4 else np.cross([0.0, 0.0, 1.0], n_out)
        off = (0.0, 0.0) if rng is None else tuple(rng.uniform(0.0, 3.0, 2))
        # side faces: first point at the top so that v (down) starts there
        origin_pts = pts if k >= 4 else pts[np.argsort(-pts[:, 2], kind="stable")]
        poly = polygon(pts, tex[k], u_dir_W=u_dir, offset_m=off, name=f"{name} face {k}")
        top = origin_pts[0] - off[0] * poly.u_W - off[1] * poly.v_W
        out.append(replace(poly, origin_W=top))
    return out


@dataclass(frozen=True, slots=True, eq=False)
class Scene:
    """A world: its polygons, a name and the grey of what no polygon covers (the sky)."""

    polygons: tuple[TexturedPolygon, ...]
    name: str = ""
    background_grey: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "polygons", tuple(self.polygons))
        if not 0 <= self.background_grey <= 255:
            raise SimError(f"scene background_grey must be 0..255, got {self.background_grey}")


def add_markers(
    scene: Scene,
    markers: Sequence[tuple[int, float, Pose]],
    *,
    dictionary: cv2.aruco.Dictionary | None = None,
    lift_m: float = 0.001,
) -> Scene:
    """``scene`` with printed ArUco markers ``(id, side length m, T_W_M)`` (marker frame:
    centred, x right, y up, z out of the face, as :func:`~quadnav.sim.camera.marker_object`
    draws them with their white margin), ``lift_m`` in front of the surface they lie on."""
    d = dictionary or cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250)
    out = list(scene.polygons)
    for marker_id, length_m, T_W_M in markers:
        obj = marker_object(d, marker_id, length_m, T_W_M)
        s = float(obj.A[0, 0])
        if not (np.isclose(obj.A[1, 1], -s) and obj.A[0, 1] == 0 and obj.A[1, 0] == 0):
            raise SimError(f"marker {marker_id}: unexpected texture mapping")
        lift = np.array([0.0, 0.0, lift_m])
        corners = T_W_M @ (obj.corners_O()[::-1] + lift)  # counter-clockwise seen from +z
        x0, y0 = obj.A[0, 2] - 0.5 * s, obj.A[1, 2] + 0.5 * s
        R = T_W_M.R_A_B.as_matrix()
        tex = Texture(obj.texture, s, f"marker {marker_id}")
        out.append(
            TexturedPolygon(
                corners, tex, T_W_M @ np.array([x0, y0, lift_m]), R[:, 0], -R[:, 1], 1.0, obj.name
            )
        )
    return Scene(tuple(out), scene.name, scene.background_grey)


@dataclass(frozen=True, slots=True, kw_only=True)
class WorldPlan:
    """What a world is built around: the axis-aligned box the camera flies in
    (``flight_min_m``, ``flight_max_m``, ENU metres), a ``seed``, optionally the flight path's
    points ``path_W`` (N, 3; obstacles keep ``clearance_m`` from it, and may then stand inside
    the flight box), ``texture_poor`` (the fraction of surfaces made flat and low-contrast) and
    the ``margin_m`` between the flight box and the walls."""

    flight_min_m: tuple[float, float, float]
    flight_max_m: tuple[float, float, float]
    seed: int = 0
    path_W: FloatArray | None = None
    texture_poor: float = 0.0
    clearance_m: float = 0.5
    margin_m: float = 1.5

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.flight_min_m, float), np.asarray(self.flight_max_m, float)
        if (
            lo.shape != (3,)
            or hi.shape != (3,)
            or not (np.isfinite(lo).all() and np.isfinite(hi).all())
        ):
            raise SimError(
                "world plan: flight_min_m and flight_max_m must be 3 finite numbers each"
            )
        if not (hi >= lo).all():
            raise SimError(
                f"world plan: flight_max_m {hi.tolist()} is below flight_min_m {lo.tolist()}"
            )
        if not 0.0 <= self.texture_poor <= 1.0:
            raise SimError(f"world plan: texture_poor must be in 0..1, got {self.texture_poor}")
        if not (self.clearance_m >= 0 and self.margin_m > 0):
            raise SimError("world plan: clearance_m must be >= 0 and margin_m > 0")
        if self.path_W is not None:
            path = np.asarray(self.path_W, np.float64).reshape(-1, 3)
            if not np.isfinite(path).all() or len(path) == 0:
                raise SimError("world plan: path_W must be finite points (N, 3)")
            object.__setattr__(self, "path_W", path)

    def dense_path(self, step_m: float = 0.05) -> FloatArray | None:
        """The path with points at most ``step_m`` apart (segments interpolated)."""
        if self.path_W is None:
            return None
        p = self.path_W
        pieces = [p[:1]]
        for a, b in itertools.pairwise(p):
            k = max(1, math.ceil(float(np.linalg.norm(b - a)) / step_m))
            pieces.append(a + np.linspace(0.0, 1.0, k + 1)[1:, None] * (b - a))
        return np.concatenate(pieces)


@lru_cache(maxsize=512)
def _texture(kind: str, seed: int, m_per_texel: float, size_px: int = 512) -> Texture:
    """One shared :class:`Texture` (and mip pyramid) per kind, seed, scale and size."""
    img = flat_texture(seed) if kind == "flat" else make_texture(kind, seed, size_px)
    return Texture(img, m_per_texel, f"{kind}:{seed}")


class _Surfaces:
    """Seeded texture choices for a world; ``texture_poor`` of them flat."""

    def __init__(self, plan: WorldPlan) -> None:
        self.rng = np.random.default_rng(plan.seed)
        self.poor = plan.texture_poor

    def pick(self, kinds: Sequence[str], m_per_texel: float, *, big: bool = False) -> Texture:
        """A texture of ``m_per_texel``; ``big``: tiles twice as large (1024 texels when
        procedural, photos at half the resolution), for fewer cells on large surfaces."""
        kind = kinds[int(self.rng.integers(len(kinds)))]
        seed = int(self.rng.integers(8))
        if self.rng.random() < self.poor:
            return _texture("flat", seed, m_per_texel * (16 if big else 8))
        if big and kind in PHOTOS:
            return _texture(kind, seed, 2 * m_per_texel)
        return _texture(kind, seed, m_per_texel, 1024 if big else 512)


def _aabb_distance(points: FloatArray, lo: FloatArray, hi: FloatArray) -> float:
    """The least distance from ``points`` (N, 3) to the box [lo, hi]."""
    d = np.maximum(np.maximum(lo - points, points - hi), 0.0)
    return float(np.sqrt((d**2).sum(axis=1)).min())


@dataclass
class _Placer:
    """Places obstacle boxes standing on a floor: inside ``area`` (x0, y0, x1, y1), apart from
    each other, clear of the flight path (or, without one, of the flight box)."""

    plan: WorldPlan
    area: tuple[float, float, float, float]
    floor_z: float
    rng: np.random.Generator
    placed: list[tuple[FloatArray, FloatArray]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.path = self.plan.dense_path()

    def clear(self, lo: FloatArray, hi: FloatArray) -> bool:
        c = self.plan.clearance_m
        if self.path is not None:
            ok = _aabb_distance(self.path, lo, hi) >= c + 1e-6
        else:
            f_lo = np.asarray(self.plan.flight_min_m) - c
            f_hi = np.asarray(self.plan.flight_max_m) + c
            ok = bool((hi <= f_lo).any() or (lo >= f_hi).any())
        return ok and all((hi + 0.1 <= a).any() or (lo - 0.1 >= b).any() for a, b in self.placed)

    def place(self, size: FloatArray, tries: int = 60) -> tuple[FloatArray, FloatArray] | None:
        x0, y0, x1, y1 = self.area
        for _ in range(tries):
            sx, sy = size[:2] if self.rng.random() < 0.5 else size[1::-1]
            if x1 - x0 <= sx or y1 - y0 <= sy:
                return None
            x, y = self.rng.uniform(x0, x1 - sx), self.rng.uniform(y0, y1 - sy)
            lo = np.array([x, y, self.floor_z])
            hi = np.array([x + sx, y + sy, self.floor_z + size[2]])
            if self.clear(lo, hi):
                self.placed.append((lo, hi))
                return lo, hi
        return None


def _enclosure(
    plan: WorldPlan,
    S: _Surfaces,
    margin_m: float,
    height_m: float,
    cell_m: float,
    scale: float,
    big: bool = False,
) -> tuple[list[TexturedPolygon], FloatArray, FloatArray]:
    """Walls, floor and ceiling around the flight box (facing in), cut along their textures'
    tiles and the floor (seen from near to far at once) into cells of at most ``cell_m``."""
    f_lo, f_hi = np.asarray(plan.flight_min_m), np.asarray(plan.flight_max_m)
    lo = np.array([f_lo[0] - margin_m, f_lo[1] - margin_m, min(0.0, f_lo[2] - 0.1)])
    hi = np.array([f_hi[0] + margin_m, f_hi[1] + margin_m, max(lo[2] + height_m, f_hi[2] + 1.0)])
    walls = ["bricks", "noise", "brick", "wood", "checkers", "coins", "cell", "page"]
    tex = [S.pick(walls, scale, big=big) for _ in range(4)]
    floor = ["gravel", "noise", "grass", "bricks"]
    tex += [S.pick(floor, scale, big=big), S.pick(["noise", "moon"], scale, big=big)]
    faces = box(lo, hi, tex, inward=True, rng=S.rng, name="enclosure")
    return _cells(faces[:4]) + _cells(faces[4:5], cell_m) + _cells(faces[5:]), lo, hi


def _posters(
    walls: Sequence[TexturedPolygon], S: _Surfaces, per_wall: int, size_m: tuple[float, float]
) -> list[TexturedPolygon]:
    """Photos hung on the (tessellated) side walls, 2 mm in front of them, upright."""
    photos = ["astronaut", "coffee", "chelsea", "rocket", "camera", "text", "hubble_deep_field"]
    sides = [w for w in walls if abs(w.normal_W[2]) < 0.5]
    out = []
    for k in S.rng.choice(len(sides), size=min(per_wall * 4, len(sides)), replace=False):
        w = sides[int(k)]
        side = S.rng.uniform(*size_m)
        a = b = 0.5 * side
        c = w.points_W.mean(axis=0) + 0.002 * w.normal_W
        u, v = w.u_W, w.v_W
        pts = np.array([c - a * u - b * v, c - a * u + b * v, c + a * u + b * v, c + a * u - b * v])
        tex = _texture(photos[int(S.rng.integers(len(photos)))], 0, 2 * a / 512)
        out.append(polygon(pts, tex, u_dir_W=u, shade=w.shade, name="poster"))
    for i, p in enumerate(out):
        out[i] = replace(p, origin_W=p.points_W[0])
    return out


def _obstacles(
    placer: _Placer,
    S: _Surfaces,
    kind: str,
    n: int,
    size_lo: tuple[float, float, float],
    size_hi: tuple[float, float, float],
    kinds: Sequence[str],
    scale: float,
) -> list[TexturedPolygon]:
    """Up to ``n`` boxes of random size standing where the placer finds room."""
    out: list[TexturedPolygon] = []
    for i in range(n):
        got = placer.place(placer.rng.uniform(size_lo, size_hi))
        if got is not None:
            tex = S.pick(kinds, scale)  # one material all round
            out += _cells(box(*got, tex, rng=S.rng, name=f"obstacle:{kind} {i}"))
    return out


def _cells(polys: Sequence[TexturedPolygon], cell_m: float = 1e3) -> list[TexturedPolygon]:
    """Every polygon cut along its texture's tiles (and into cells of at most ``cell_m``)."""
    return [c for p in polys for c in tessellate(p, cell_m)]


def _area(lo: FloatArray, hi: FloatArray, inset: float) -> tuple[float, float, float, float]:
    return (lo[0] + inset, lo[1] + inset, hi[0] - inset, hi[1] - inset)


def build_room(plan: WorldPlan) -> Scene:
    """Like EuRoC's Vicon room: a textured room around the flight box with posters on the walls,
    cabinets, desks and crates (clear of the path)."""
    S = _Surfaces(plan)
    enc, lo, hi = _enclosure(plan, S, max(plan.margin_m, 1.5), 3.2, 2.0, 0.004)
    polys = enc + _posters(enc, S, 2, (0.6, 1.1))
    placer = _Placer(plan, _area(lo, hi, 0.05), float(lo[2]), S.rng)
    furniture = ["wood", "noise", "checkers", "bricks", "coffee", "coins", "page"]
    polys += _obstacles(placer, S, "cabinet", 4, (0.4, 0.8, 1.0), (0.6, 1.6, 2.0), furniture, 0.003)
    polys += _obstacles(placer, S, "desk", 3, (0.6, 1.0, 0.7), (0.9, 1.8, 0.8), furniture, 0.003)
    polys += _obstacles(placer, S, "crate", 6, (0.3, 0.3, 0.3), (0.7, 0.7, 0.8), furniture, 0.002)
    return Scene(tuple(polys), "room")


def build_hall(plan: WorldPlan) -> Scene:
    """Like EuRoC's machine hall: large and tall, pillars on a grid, shelves along the walls
    and machines as boxes."""
    S = _Surfaces(plan)
    enc, lo, hi = _enclosure(plan, S, max(plan.margin_m, 3.0), 9.0, 4.0, 0.008, big=True)
    polys = enc + _posters(enc, S, 1, (1.5, 3.0))
    placer = _Placer(plan, _area(lo, hi, 0.05), float(lo[2]), S.rng)
    metal = ["noise", "checkers", "coins", "cell", "gravel", "page", "bricks"]
    for i, x in enumerate(np.arange(lo[0] + 2.5, hi[0] - 1.0, 6.0)):
        for j, y in enumerate(np.arange(lo[1] + 2.5, hi[1] - 1.0, 6.0)):
            p_lo, p_hi = np.array([x, y, lo[2]]), np.array([x + 0.5, y + 0.5, hi[2]])
            if placer.clear(p_lo, p_hi):
                placer.placed.append((p_lo, p_hi))
                polys += _cells(
                    box(
                        p_lo, p_hi, S.pick(metal, 0.008), rng=S.rng, name=f"obstacle:pillar {i},{j}"
                    )
                )
    polys += _obstacles(placer, S, "shelf", 6, (0.6, 2.0, 2.0), (0.9, 4.0, 3.5), metal, 0.006)
    polys += _obstacles(placer, S, "machine", 8, (0.8, 0.8, 0.8), (2.5, 3.0, 2.5), metal, 0.006)
    polys += _obstacles(placer, S, "crate", 8, (0.4, 0.4, 0.4), (1.0, 1.0, 1.0), metal, 0.003)
    return Scene(tuple(polys), "hall")


def build_yard(plan: WorldPlan) -> Scene:
    """Outdoors: ground out to 40 m around the flight box, buildings and trees (as boxes) around
    it, and a bright flat sky (where nothing is hit)."""
    S = _Surfaces(plan)
    f_lo, f_hi = np.asarray(plan.flight_min_m), np.asarray(plan.flight_max_m)
    gz = min(0.0, f_lo[2] - 0.1)
    near_lo, near_hi = f_lo[:2] - 12.0, f_hi[:2] + 12.0
    far_lo, far_hi = f_lo[:2] - 40.0, f_hi[:2] + 40.0
    ground = S.pick(["grass", "gravel", "noise"], 0.008)
    far = Texture(ground.image, 0.032, ground.name)  # coarser far away: fewer, larger tiles
    polys: list[TexturedPolygon] = []
    pieces: list[tuple[float, float, float, float, Texture]] = [
        (*near_lo, *near_hi, ground),
        (*far_lo, far_hi[0], near_lo[1], far),
        (far_lo[0], near_hi[1], *far_hi, far),
        (far_lo[0], near_lo[1], near_lo[0], near_hi[1], far),
        (near_hi[0], near_lo[1], far_hi[0], near_hi[1], far),
    ]
    for x0, y0, x1, y1, tex in pieces:
        quad = [[x0, y0, gz], [x1, y0, gz], [x1, y1, gz], [x0, y1, gz]]
        polys += _cells([polygon(quad, tex, u_dir_W=[1, 0, 0], name="ground")])
    m = plan.margin_m + 6.0
    area = (f_lo[0] - m - 14.0, f_lo[1] - m - 14.0, f_hi[0] + m + 14.0, f_hi[1] + m + 14.0)
    placer = _Placer(plan, area, gz, S.rng)
    # buildings only outside the flight box plus the margin, trees anywhere clear of the path
    keep = (np.array([f_lo[0] - m, f_lo[1] - m, gz]), np.array([f_hi[0] + m, f_hi[1] + m, gz + 50]))
    placer.placed.append(keep)
    facade = ["brick", "bricks", "noise", "text", "page", "checkers"]
    polys += _obstacles(
        placer, S, "building", 10, (6.0, 8.0, 4.0), (12.0, 20.0, 14.0), facade, 0.01
    )
    placer.placed.pop(0)
    placer.area = (f_lo[0] - m, f_lo[1] - m, f_hi[0] + m, f_hi[1] + m)
    for i in range(12):
        r, h = S.rng.uniform(0.8, 1.5), S.rng.uniform(1.5, 3.0)
        got = placer.place(np.array([2 * r, 2 * r, 2.0 + h]))  # the tree's whole extent
        if got is None:
            continue
        c = 0.5 * (got[0] + got[1])
        t_lo, t_hi = (
            np.array([c[0] - 0.15, c[1] - 0.15, gz]),
            np.array([c[0] + 0.15, c[1] + 0.15, gz + 2.0]),
        )
        trunk = box(
            t_lo, t_hi, S.pick(["wood", "bricks"], 0.003), rng=S.rng, name=f"obstacle:trunk {i}"
        )
        crown_lo = np.array([c[0] - r, c[1] - r, gz + 2.0])
        crown = box(
            crown_lo,
            got[1],
            S.pick(["grass", "gravel"], 0.004),
            rng=S.rng,
            name=f"obstacle:crown {i}",
        )
        polys += _cells(trunk + crown)
    return Scene(tuple(polys), "yard", background_grey=235)


def build_marker_floor(plan: WorldPlan) -> Scene:
    """Thesis 000's marker field: DICT_4X4_250 markers of 0.2335 m every 0.6 m on the floor
    under the flight box (ids 0... row by row from the south-west corner), in a plain room."""
    S = _Surfaces(plan)
    enc, lo, _ = _enclosure(plan, S, max(plan.margin_m, 1.5), 3.2, 2.0, 0.004)
    f_lo, f_hi = np.asarray(plan.flight_min_m), np.asarray(plan.flight_max_m)
    xs = np.arange(f_lo[0] - 0.6, f_hi[0] + 0.6 + 1e-9, 0.6)
    ys = np.arange(f_lo[1] - 0.6, f_hi[1] + 0.6 + 1e-9, 0.6)
    R = Pose.identity().R_A_B
    markers = [
        (k, 0.2335, Pose(R, np.array([x, y, lo[2]])))
        for k, (y, x) in enumerate((y, x) for y in ys for x in xs)
    ]
    return add_markers(Scene(tuple(enc), "marker_floor"), markers)


def build_aliased(plan: WorldPlan) -> Scene:
    """Perceptual aliasing: a room whose every surface, two crates included (outside the
    flight box), has the same brick texture, so that different places look alike to a place
    recogniser (a loop closer must not close a loop on looks alone)."""
    tex = Texture(make_texture("bricks", 3, 512), 0.004, "bricks:3")
    f_lo, f_hi = np.asarray(plan.flight_min_m), np.asarray(plan.flight_max_m)
    lo, hi = f_lo - np.array([1.5, 1.5, 0.5]), f_hi + np.array([1.5, 1.5, 1.0])
    rng = np.random.default_rng(plan.seed)
    faces = box(lo, hi, tex, inward=True, rng=rng, name="enclosure")
    for i, (x, y) in enumerate([(lo[0] + 0.2, lo[1] + 0.2), (hi[0] - 1.0, hi[1] - 1.0)]):
        c = np.array([x, y, lo[2]])
        faces += box(c, c + np.array([0.8, 0.8, 0.9]), tex, rng=rng, name=f"crate {i}")
    return Scene(tuple(c for p in faces for c in tessellate(p, 2.0)), "aliased")


#: The built-in worlds by name: each builds a :class:`Scene` from a :class:`WorldPlan`.
WORLDS: Mapping[str, Callable[[WorldPlan], Scene]] = MappingProxyType(
    {
        "room": build_room,
        "hall": build_hall,
        "yard": build_yard,
        "marker_floor": build_marker_floor,
        "aliased": build_aliased,
    }
)
