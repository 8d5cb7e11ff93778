"""Grey textures for the 3-D worlds: real photographs shipped with scikit-image (loaded offline)
and procedural ones (fractal noise, checkers, bricks, wood-like stripes).

Every texture is a square, power-of-two greyscale ``uint8`` image, so its mip levels tile
exactly; procedural ones are periodic (they tile without seams) and seeded. All are cached and
returned read-only: two worlds (or two cameras) share one array.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import SimError

__all__ = [
    "PHOTOS",
    "PROCEDURAL",
    "flat_texture",
    "make_texture",
    "photo",
]

U8 = NDArray[np.uint8]
FloatArray = NDArray[np.float64]

#: scikit-image's shipped photographs that load without a network (checked on 0.26).
PHOTOS = (
    "brick",
    "grass",
    "gravel",
    "coffee",
    "camera",
    "moon",
    "rocket",
    "astronaut",
    "text",
    "coins",
    "page",
    "cell",
    "chelsea",
    "hubble_deep_field",
)


def _frozen(img: NDArray[np.generic]) -> U8:
    out = np.ascontiguousarray(np.clip(img, 0, 255), dtype=np.uint8)
    out.flags.writeable = False
    return out


def _check_size(size_px: int) -> None:
    if size_px < 8 or size_px & (size_px - 1):
        raise SimError(f"texture size_px must be a power of two >= 8, got {size_px}")


@lru_cache(maxsize=64)
def photo(name: str, size_px: int = 512) -> U8:
    """The scikit-image photograph ``name`` in grey, resized to ``size_px`` squared, with its
    contrast stretched (2nd to 98th percentile over 20 to 235)."""
    if name not in PHOTOS:
        raise SimError(f"unknown photo texture {name!r}; choose one of {', '.join(PHOTOS)}")
    _check_size(size_px)
    import skimage.data

    img = np.asarray(getattr(skimage.data, name)())
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img[..., :3]), cv2.COLOR_RGB2GRAY)
    h, w = img.shape
    s = min(h, w)  # the central square, then to size
    img = img[(h - s) // 2 : (h - s) // 2 + s, (w - s) // 2 : (w - s) // 2 + s]
    interp = cv2.INTER_AREA if s > size_px else cv2.INTER_CUBIC
    g = cv2.resize(img, (size_px, size_px), interpolation=interp).astype(np.float64)
    lo, hi = np.percentile(g, [2.0, 98.0])
    return _frozen(20.0 + 215.0 * (g - lo) / max(hi - lo, 1.0))


def _fractal(rng: np.random.Generator, n: int, beta: float, min_period_px: float) -> FloatArray:
    """Periodic noise (n, n) of zero mean and unit deviation with a 1/f^beta spectrum, no
    detail finer than ``min_period_px``."""
    f = np.fft.fftfreq(n)
    fr = np.hypot(f[:, None], f[None, :])
    fr[0, 0] = 1.0
    amp = fr ** (-beta / 2.0) * (fr <= 1.0 / min_period_px)
    amp[0, 0] = 0.0
    spec = np.fft.fft2(rng.standard_normal((n, n))) * amp
    out = np.real(np.fft.ifft2(spec))
    return np.asarray((out - out.mean()) / max(float(out.std()), 1e-12), np.float64)


def _noise(rng: np.random.Generator, n: int) -> FloatArray:
    """Speckled fractal noise: blotches at all scales and texel-sized grain (concrete, carpet)."""
    return 128.0 + 38.0 * _fractal(rng, n, 2.0, 2.0) + 14.0 * _fractal(rng, n, 0.0, 1.5)


def _checkers(rng: np.random.Generator, n: int) -> FloatArray:
    """Checkers of random size (4 to 16 per side) with a random grey per square and grain."""
    k = int(rng.choice([4, 8, 16]))
    levels = rng.uniform(30.0, 225.0, (k, k))
    idx = np.arange(n) * k // n
    return levels[idx[:, None], idx[None, :]] + 8.0 * _fractal(rng, n, 1.0, 2.0)


def _bricks(rng: np.random.Generator, n: int) -> FloatArray:
    """Courses of bricks (offset every other row), a grey per brick, light mortar, grain."""
    rows = int(rng.choice([8, 16]))
    per_row = rows // 2
    bh, bw = n // rows, n // per_row
    y, x = np.mgrid[0:n, 0:n]
    course = y // bh
    shifted = (x + (course % 2) * (bw // 2)) % n
    brick = course * per_row + shifted // bw
    grey = rng.uniform(70.0, 170.0, rows * per_row)[brick]
    mortar = ((y % bh) < max(bh // 8, 1)) | ((shifted % bw) < max(bh // 8, 1))
    return np.where(mortar, 200.0, grey) + 12.0 * _fractal(rng, n, 1.5, 2.0)


def _wood(rng: np.random.Generator, n: int) -> FloatArray:
    """Wood-like grain: stripes along x whose phase wanders with low-frequency noise, knots."""
    y, x = np.mgrid[0:n, 0:n] / n
    turb = _fractal(rng, n, 3.0, 8.0)
    k = int(rng.integers(10, 24))
    rings = np.sin(2 * np.pi * (k * y + 0.35 * turb + x))  # whole periods: it tiles
    return np.asarray(125.0 + 22.0 * rings + 18.0 * _fractal(rng, n, 2.0, 2.0), np.float64)


#: Procedural texture kinds by name (each a seeded, periodic generator).
PROCEDURAL: dict[str, Callable[[np.random.Generator, int], FloatArray]] = {
    "noise": _noise,
    "checkers": _checkers,
    "bricks": _bricks,
    "wood": _wood,
}


#: Depth of the large-scale albedo variation (stains, wear, uneven light) laid over every
#: texture: without it a tracker's coarse pyramid levels see flat tiles, and fast turns were
#: harder to track than in a real EuRoC image (examples/track_realism.py: 0.60 against 0.77 of
#: the features kept per frame at 120 deg/s in the room; 0.75 with it).
ALBEDO_DEPTH = 0.3


def _albedo(img: FloatArray, seed: int, size_px: int) -> FloatArray:
    """``img`` times a smooth periodic field of mean 1 (no detail finer than 1/8 of the tile)."""
    rng = np.random.default_rng((seed, 0xA1BED0))
    return np.asarray(img * (1.0 + ALBEDO_DEPTH * _fractal(rng, size_px, 3.0, size_px / 8)))


@lru_cache(maxsize=256)
def make_texture(kind: str, seed: int = 0, size_px: int = 512) -> U8:
    """A photo (one of :data:`PHOTOS`) or a procedural texture (one of :data:`PROCEDURAL`),
    with a seeded large-scale albedo variation over it (:data:`ALBEDO_DEPTH`)."""
    if kind in PHOTOS:
        base = photo(kind, size_px).astype(np.float64)
    elif kind in PROCEDURAL:
        _check_size(size_px)
        base = PROCEDURAL[kind](np.random.default_rng(seed), size_px)
    else:
        raise SimError(
            f"unknown texture {kind!r}; choose a photo ({', '.join(PHOTOS)}) "
            f"or one of {', '.join(PROCEDURAL)}"
        )
    return _frozen(_albedo(base, seed, size_px))


@lru_cache(maxsize=64)
def flat_texture(seed: int = 0, size_px: int = 64, *, contrast: float = 3.0) -> U8:
    """A texture-poor surface: a random flat grey with faint smooth shading (``contrast`` grey
    levels of deviation), like a painted wall; seeded and periodic."""
    _check_size(size_px)
    rng = np.random.default_rng(seed)
    base = rng.uniform(90.0, 200.0)
    return _frozen(base + contrast * _fractal(rng, size_px, 3.0, 4.0))
