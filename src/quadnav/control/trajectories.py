"""Reference trajectories: position, velocity, acceleration (and jerk) and yaw at any time.

All are vectorised over time: ``reference(t_s)`` takes an array of seconds and returns
(N, 3) arrays, so a whole run's reference is one call.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav.errors import ControlError

__all__ = ["Circle", "Hover", "Reference", "Sigmoid", "TrajectoryGenerator", "Waypoints"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class Reference:
    """Desired position, velocity, acceleration, jerk and snap (N, 3) in the world frame, and yaw (N,)."""

    p: FloatArray
    v: FloatArray
    a: FloatArray
    j: FloatArray
    yaw: FloatArray
    snap: FloatArray | None = None


class TrajectoryGenerator(Protocol):
    def reference(self, t_s: ArrayLike) -> Reference: ...


def _t(t_s: ArrayLike) -> FloatArray:
    return np.atleast_1d(np.asarray(t_s, dtype=np.float64))


@dataclass(frozen=True, slots=True, kw_only=True)
class Hover:
    """Hold a point."""

    position_m: tuple[float, float, float] = (0.0, 0.0, 1.0)
    yaw_rad: float = 0.0

    def reference(self, t_s: ArrayLike) -> Reference:
        t = _t(t_s)
        z = np.zeros((len(t), 3))
        return Reference(
            p=np.tile(self.position_m, (len(t), 1)),
            v=z,
            a=z.copy(),
            j=z.copy(),
            yaw=np.full(len(t), self.yaw_rad),
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class Sigmoid:
    """Thesis 002's smooth point-to-point reference: on each axis with a non-zero amplitude,
    ``p(t) = start + amplitude / (1 + exp(-k (t - t_mid)))`` with ``k = 10 / duration_s``
    (1% to 99% of the move within the duration)."""

    start_m: tuple[float, float, float] = (0.0, 0.0, 5.0)
    amplitude_m: tuple[float, float, float] = (20.0, 20.0, 0.0)
    t_mid_s: float = 10.0
    duration_s: float = 10.0

    def __post_init__(self) -> None:
        if not self.duration_s > 0:
            raise ControlError(f"sigmoid duration_s must be > 0, got {self.duration_s}")

    def reference(self, t_s: ArrayLike) -> Reference:
        t = _t(t_s)
        k = 10.0 / self.duration_s
        sg = 1.0 / (1.0 + np.exp(-k * (t - self.t_mid_s)))
        d1 = k * sg * (1 - sg)
        d2 = k * d1 * (1 - 2 * sg)
        d3 = k * (d2 * (1 - 2 * sg) - 2 * d1 * d1)
        d4 = k * (d3 * (1 - 2 * sg) - 6 * d1 * d2)
        A = np.asarray(self.amplitude_m)
        return Reference(
            p=np.asarray(self.start_m) + np.outer(sg, A),
            v=np.outer(d1, A),
            a=np.outer(d2, A),
            j=np.outer(d3, A),
            yaw=np.zeros(len(t)),
            snap=np.outer(d4, A),
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class Circle:
    """A horizontal circle at constant speed, counter-clockwise seen from above."""

    center_m: tuple[float, float, float] = (0.0, 0.0, 1.0)
    radius_m: float = 2.0
    speed_m_s: float = 1.0
    yaw_rad: float = 0.0

    def __post_init__(self) -> None:
        if not (self.radius_m > 0 and self.speed_m_s > 0):
            raise ControlError("circle radius_m and speed_m_s must be > 0")

    def reference(self, t_s: ArrayLike) -> Reference:
        t = _t(t_s)
        w = self.speed_m_s / self.radius_m
        c, s = np.cos(w * t), np.sin(w * t)
        r = self.radius_m
        zero = np.zeros(len(t))
        return Reference(
            p=np.column_stack(
                [
                    self.center_m[0] + r * c,
                    self.center_m[1] + r * s,
                    np.full(len(t), self.center_m[2]),
                ]
            ),
            v=np.column_stack([-r * w * s, r * w * c, zero]),
            a=np.column_stack([-r * w * w * c, -r * w * w * s, zero]),
            j=np.column_stack([r * w**3 * s, -r * w**3 * c, zero]),
            yaw=np.full(len(t), self.yaw_rad),
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class Waypoints:
    """Straight legs between waypoints at a cruise speed, holding each point for ``hold_s``."""

    points_m: list[tuple[float, float, float]] = field(default_factory=lambda: [(0.0, 0.0, 1.0)])
    speed_m_s: float = 0.5
    hold_s: float = 2.0

    def __post_init__(self) -> None:
        if len(self.points_m) < 1 or not self.speed_m_s > 0 or self.hold_s < 0:
            raise ControlError("waypoints need >= 1 point, speed_m_s > 0 and hold_s >= 0")

    def _knots(self) -> tuple[FloatArray, FloatArray]:
        pts = np.asarray(self.points_m, dtype=np.float64)
        times, pos = [0.0], [pts[0]]
        for a, b in itertools.pairwise(pts):
            times.append(times[-1] + self.hold_s)
            pos.append(a)
            times.append(times[-1] + float(np.linalg.norm(b - a)) / self.speed_m_s)
            pos.append(b)
        times.append(times[-1] + self.hold_s)
        pos.append(pts[-1])
        return np.array(times), np.array(pos)

    def reference(self, t_s: ArrayLike) -> Reference:
        t = _t(t_s)
        times, pos = self._knots()
        p = np.column_stack([np.interp(t, times, pos[:, k]) for k in range(3)])
        k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
        dt = times[k + 1] - times[k]
        v = (pos[k + 1] - pos[k]) / np.where(dt > 0, dt, 1.0)[:, None]
        v[(t < times[0]) | (t >= times[-1])] = 0.0
        z = np.zeros_like(p)
        return Reference(p=p, v=v, a=z, j=z.copy(), yaw=np.zeros(len(t)))
