"""The world a simulated vehicle flies in: box obstacles and a planar laser scanner."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.random import Generator
from numpy.typing import NDArray

from quadnav.errors import SimError
from quadnav.messages import RangeScan

__all__ = ["Box", "LaserScanner", "World"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class Box:
    """An axis-aligned box obstacle (a house, a wall) between two corners, in metres (ENU)."""

    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]
    name: str = "box"

    def __post_init__(self) -> None:
        if any(not a < b for a, b in zip(self.min_m, self.max_m, strict=True)):
            raise SimError(f"box {self.name!r}: every min_m coordinate must be below max_m")

    def distance_m(self, p: FloatArray) -> FloatArray:
        """Euclidean distance from points (..., 3) to the box (0 inside)."""
        lo, hi = np.asarray(self.min_m), np.asarray(self.max_m)
        d = np.maximum(np.maximum(lo - p, p - hi), 0.0)
        return np.asarray(np.linalg.norm(d, axis=-1), dtype=np.float64)


@dataclass(frozen=True, slots=True, kw_only=True)
class World:
    boxes: tuple[Box, ...] = field(default_factory=tuple)

    def min_distance_m(self, p: FloatArray) -> FloatArray:
        """Distance from points (..., 3) to the nearest obstacle (inf without obstacles)."""
        p = np.asarray(p, dtype=np.float64)
        if not self.boxes:
            return np.full(p.shape[:-1], np.inf)
        return np.asarray(np.min([b.distance_m(p) for b in self.boxes], axis=0), dtype=np.float64)


@dataclass(frozen=True, slots=True, kw_only=True)
class LaserScanner:
    """A 2-D scanner in the body's horizontal plane (like a Hokuyo on hector_quadrotor).

    Rays are cast from the body origin at its height, turned by the body's yaw, against the
    boxes whose height span contains the scanner; ranges get Gaussian noise.
    """

    n_rays: int = 360
    angle_min_rad: float = -math.pi
    angle_max_rad: float = math.pi
    range_max_m: float = 10.0
    noise_sigma_m: float = 0.01

    def __post_init__(self) -> None:
        if self.n_rays < 1 or not self.range_max_m > 0 or self.noise_sigma_m < 0:
            raise SimError("LaserScanner needs n_rays >= 1, range_max_m > 0 and noise_sigma_m >= 0")
        if not self.angle_max_rad > self.angle_min_rad:
            raise SimError("LaserScanner needs angle_max_rad > angle_min_rad")

    @property
    def increment_rad(self) -> float:
        span = self.angle_max_rad - self.angle_min_rad
        full = abs(span - 2 * math.pi) < 1e-9
        return span / (self.n_rays if full else max(self.n_rays - 1, 1))

    def scan(
        self, world: World, p_W_B: FloatArray, yaw_rad: float, t_ns: int, rng: Generator
    ) -> RangeScan:
        inc = self.increment_rad
        ang = self.angle_min_rad + inc * np.arange(self.n_rays)
        d = np.column_stack([np.cos(ang + yaw_rad), np.sin(ang + yaw_rad)])  # (R, 2)
        o = np.asarray(p_W_B[:2], dtype=np.float64)
        ranges = np.full(self.n_rays, np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            for box in world.boxes:
                if not box.min_m[2] <= p_W_B[2] <= box.max_m[2]:
                    continue
                lo = (np.asarray(box.min_m[:2]) - o) / d  # slab entry/exit per axis
                hi = (np.asarray(box.max_m[:2]) - o) / d
                t_near = np.nanmax(np.minimum(lo, hi), axis=1)
                t_far = np.nanmin(np.maximum(lo, hi), axis=1)
                hit = (t_far >= np.maximum(t_near, 0.0)) & (t_near <= self.range_max_m)
                ranges = np.where(hit, np.minimum(ranges, np.maximum(t_near, 0.0)), ranges)
        hit = np.isfinite(ranges)
        if self.noise_sigma_m > 0:
            ranges[hit] = np.maximum(
                ranges[hit] + self.noise_sigma_m * rng.standard_normal(int(hit.sum())), 0.0
            )
        return RangeScan(
            t_ns=t_ns,
            angle_min_rad=self.angle_min_rad,
            angle_increment_rad=inc,
            range_max_m=self.range_max_m,
            ranges_m=ranges,
        )
