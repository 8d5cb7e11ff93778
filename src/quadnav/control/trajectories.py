"""Reference trajectories: position, velocity, acceleration (and jerk) and yaw at any time.

All are vectorised over time: ``reference(t_s)`` takes an array of seconds and returns
(N, 3) arrays, so a whole run's reference is one call.
"""

from __future__ import annotations

import itertools
import math
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


def _trapezoid(
    t: FloatArray, d: float, v_max: float, a_max: float
) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """Distance, speed and acceleration along a straight leg of length ``d`` that starts and
    ends at rest, limited to ``v_max`` and ``a_max`` (triangular when too short to cruise)."""
    if d <= 0:
        z = np.zeros_like(t)
        return z, z.copy(), z.copy(), 0.0
    v = min(v_max, math.sqrt(d * a_max))
    ta = v / a_max
    tc = (d - v * ta) / v
    T = 2 * ta + tc
    tt = np.clip(t, 0.0, T)
    acc_phase, dec_phase = tt < ta, tt > ta + tc
    s = np.where(
        acc_phase,
        0.5 * a_max * tt**2,
        np.where(dec_phase, d - 0.5 * a_max * (T - tt) ** 2, 0.5 * a_max * ta**2 + v * (tt - ta)),
    )
    sd = np.where(acc_phase, a_max * tt, np.where(dec_phase, a_max * (T - tt), v))
    sdd = np.where(acc_phase, a_max, np.where(dec_phase, -a_max, 0.0))
    inside = (t >= 0) & (t < T)
    return s, np.where(inside, sd, 0.0), np.where(inside, sdd, 0.0), T


@dataclass(frozen=True, slots=True, kw_only=True)
class Waypoints:
    """Straight legs between waypoints, each starting and ending at rest with a trapezoidal
    speed profile (``speed_m_s``, ``accel_m_s2``), holding each point for ``hold_s``."""

    points_m: list[tuple[float, float, float]] = field(default_factory=lambda: [(0.0, 0.0, 1.0)])
    speed_m_s: float = 0.5
    accel_m_s2: float = 1.0
    hold_s: float = 2.0

    def __post_init__(self) -> None:
        if (
            len(self.points_m) < 1
            or not self.speed_m_s > 0
            or not self.accel_m_s2 > 0
            or self.hold_s < 0
        ):
            raise ControlError(
                "waypoints need >= 1 point, speed_m_s > 0, accel_m_s2 > 0 and hold_s >= 0"
            )

    def leg_times(self) -> list[float]:
        return [
            _trapezoid(np.zeros(1), math.dist(a, b), self.speed_m_s, self.accel_m_s2)[3]
            for a, b in itertools.pairwise(self.points_m)
        ]

    @property
    def duration_s(self) -> float:
        return sum(self.leg_times()) + self.hold_s * len(self.points_m)

    def reference(self, t_s: ArrayLike) -> Reference:
        t = _t(t_s)
        pts = np.asarray(self.points_m, dtype=np.float64)
        p = np.tile(pts[0], (len(t), 1))
        v = np.zeros_like(p)
        a = np.zeros_like(p)
        t0 = self.hold_s
        for k, T in enumerate(self.leg_times()):
            d = pts[k + 1] - pts[k]
            L = float(np.linalg.norm(d))
            u = d / L if L > 0 else np.zeros(3)
            s, sd, sdd, _ = _trapezoid(t - t0, L, self.speed_m_s, self.accel_m_s2)
            on = t >= t0
            p[on] = pts[k] + np.outer(s[on], u)
            v[on] = np.outer(sd[on], u)
            a[on] = np.outer(sdd[on], u)
            t0 += T + self.hold_s
        return Reference(p=p, v=v, a=a, j=np.zeros_like(p), yaw=np.zeros(len(t)))
