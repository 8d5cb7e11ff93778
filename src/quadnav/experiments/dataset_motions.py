"""The motions of the built-in dataset sequences: a quadrotor-like flight through a box.

A Lissajous path through the flight box, entered from rest (the sequences start still, as
EuRoC's do, so a static initialization has something to work on), with the heading turning
towards the direction of travel plus a sway, and roll and pitch those of a multirotor that
makes the path's acceleration: the thrust axis along ``a + g e_z`` (differential flatness).
The poses are sampled densely and go through the same spline as a recorded motion.

``kind="laps"`` flies laps of the ellipse inscribed in the box instead, anticlockwise, the speed
swinging and the height bobbing as a pilot's do: the first lap in the lower half of the box, the
later ones in the upper half and looking ``lap_heading_deg`` further left (the change made over
the last sixth of the first lap), so that a loop closer meets the first lap's places again from
another height and heading.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import ConfigError
from quadnav.geometry.trajectory import Trajectory
from quadnav.units import GRAVITY_M_S2, NS_PER_S

__all__ = ["FlightPath", "flight_path_trajectory"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class FlightPath:
    """A Lissajous flight: centre and half-extent of the box (m), the mean speed it is scaled to
    (m/s), the sway of the heading (deg) and its period (s), the still time at the start (s),
    the ramp from rest (s), the duration (s) and the seed of the phases."""

    centre_m: tuple[float, float, float]
    half_extent_m: tuple[float, float, float]
    mean_speed_m_s: float
    yaw_sway_deg: float = 20.0
    yaw_sway_period_s: float = 6.0
    still_s: float = 2.0
    ramp_s: float = 3.0
    duration_s: float = 60.0
    seed: int = 0
    kind: str = "lissajous"
    lap_heading_deg: float = 25.0

    def __post_init__(self) -> None:
        if not (0.0 < self.mean_speed_m_s <= 10.0):
            raise ConfigError(f"mean_speed_m_s must be in (0, 10], got {self.mean_speed_m_s}")
        if min(self.half_extent_m) <= 0.0:
            raise ConfigError(f"half_extent_m must be positive, got {self.half_extent_m}")
        if not (self.duration_s > 0.0 and self.still_s >= 0.0 and self.ramp_s > 0.0):
            raise ConfigError(
                f"duration_s ({self.duration_s}) and ramp_s ({self.ramp_s}) must be > 0 and "
                f"still_s ({self.still_s}) >= 0"
            )
        if self.kind not in ("lissajous", "laps"):
            raise ConfigError(f"a flight path's kind is lissajous or laps, got {self.kind!r}")


def _smoothstep(x: FloatArray) -> FloatArray:
    """0 -> 1 with zero first, second and third derivatives at both ends (septic)."""
    x = np.clip(x, 0.0, 1.0)
    return np.asarray(x**4 * (35.0 - 84.0 * x + 70.0 * x**2 - 20.0 * x**3), dtype=np.float64)


def _ramped_angle(tau: FloatArray, ramp_s: float) -> FloatArray:
    """The integral of :func:`_smoothstep` over ``[0, tau / ramp_s]`` times ``ramp_s``: how far a
    rate that ramps up from rest has turned by ``tau`` (``tau - ramp_s / 2`` after the ramp)."""
    x = np.clip(tau / ramp_s, 0.0, 1.0)
    inside = ramp_s * x**5 * (7.0 - 14.0 * x + 10.0 * x**2 - 2.5 * x**3)
    return np.asarray(np.where(tau < ramp_s, inside, tau - 0.5 * ramp_s), dtype=np.float64)


def _lap_change(turned: FloatArray) -> FloatArray:
    """0 on the first lap, 1 from the second: the change made over the last sixth of the first."""
    return _smoothstep((turned / (2.0 * math.pi) - 5.0 / 6.0) * 6.0)


#: The laps' speed swings by this fraction over this period, and the height bobs by this fraction
#: of the box's half-height over that one: a flight at constant speed round a circle keeps its
#: acceleration constant in the body, which a monocular VIO cannot tell from a bias (its scale
#: drifted to 0.65 on such laps of the hall); a pilot's laps are not that regular.
LAP_SPEED_SWING, LAP_SPEED_PERIOD_S = 0.4, 5.0
LAP_BOB, LAP_BOB_PERIOD_S = 0.3, 7.0


def _lap_angle(path: FlightPath, t: FloatArray, rate: float) -> FloatArray:
    """How far round the laps the vehicle is at ``t``: the rate ramps up from rest, then swings."""
    tau = np.clip(t - path.still_s, 0.0, None)
    w = 2.0 * math.pi / LAP_SPEED_PERIOD_S
    swing = LAP_SPEED_SWING / w * np.sin(w * tau) * _smoothstep(tau / path.ramp_s - 1.0)
    return np.asarray(rate * (_ramped_angle(tau, path.ramp_s) + swing), dtype=np.float64)


def _laps(path: FlightPath, t: FloatArray, rate: float) -> FloatArray:
    """Laps of the ellipse inscribed in the box (90 % of it), the first low, the next high."""
    c, a = np.asarray(path.centre_m), np.asarray(path.half_extent_m)
    turned = _lap_angle(path, t, rate)
    tau = np.clip(t - path.still_s, 0.0, None)
    bob = LAP_BOB * np.sin(2.0 * math.pi * tau / LAP_BOB_PERIOD_S) * _smoothstep(tau / path.ramp_s)
    z = 0.7 * (-0.5 + _lap_change(turned)) + bob
    ring = np.column_stack([np.cos(turned), np.sin(turned), z])
    return np.asarray(c + 0.9 * a * ring, dtype=np.float64)


def _lissajous(path: FlightPath, t: FloatArray, rate: float) -> FloatArray:
    """Positions on the path at times ``t`` (s) with the frequency scale ``rate`` (the laps'
    positions for ``kind="laps"``)."""
    if path.kind == "laps":
        return _laps(path, t, rate)
    rng = np.random.default_rng(path.seed)
    phase = rng.uniform(0.0, 2.0 * math.pi, 3)
    freq = np.array([1.0, 1.0 / 1.6, 1.0 / 2.3]) * rate
    c, a = np.asarray(path.centre_m), np.asarray(path.half_extent_m)
    tau = np.clip(t - path.still_s, 0.0, None)
    blend = _smoothstep(tau / path.ramp_s)[:, None]
    wave = np.sin(freq[None, :] * tau[:, None] + phase[None, :]) - np.sin(phase)[None, :]
    return np.asarray(c + 0.9 * a * (np.sin(phase) + blend * wave), dtype=np.float64)


def _rate_for_speed(path: FlightPath) -> float:
    """The frequency scale that gives the path its mean speed (speed is linear in it)."""
    t0 = path.still_s + path.ramp_s
    t = np.linspace(t0, t0 + max(path.duration_s, 60.0), 4000)
    p = _lissajous(path, t, 1.0)
    speed1 = float(np.mean(np.linalg.norm(np.diff(p, axis=0), axis=1)) / (t[1] - t[0]))
    return path.mean_speed_m_s / speed1


#: Samples the path's attitude works on at once (its arrays of (N, 3, 3) for 30 minutes at
#: 200 Hz took ~200 MB in one piece); the derivatives look 2 samples either side.
CHUNK = 32768
_HALO = 2


def _chunks(n: int) -> Iterator[tuple[int, int, int, int]]:
    """``(a, b, lo, hi)``: the samples ``a:b`` of each chunk and the span ``lo:hi`` around it
    whose second differences hold at ``a:b`` as over the whole path (``np.gradient``'s one-sided
    ends only at the path's own ends)."""
    for a in range(0, n, CHUNK):
        b = min(a + CHUNK, n)
        yield a, b, max(a - _HALO, 0), min(b + _HALO, n)


def _derivatives(p: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
    v = np.gradient(p, dt, axis=0)
    return v, np.gradient(v, dt, axis=0)


def _heading(path: FlightPath, t: FloatArray, rate: float) -> FloatArray:
    """The heading (rad): towards the travel direction (held where the vehicle hardly moves,
    smoothed over 2 s: it lags the path), plus the sway, blended in over the ramp."""
    dt = float(t[1] - t[0])
    speed, heading = np.empty(len(t)), np.empty(len(t))
    for a, b, lo, hi in _chunks(len(t)):
        v = _derivatives(_lissajous(path, t[lo:hi], rate), dt)[0][a - lo : b - lo]
        speed[a:b] = np.linalg.norm(v[:, :2], axis=1)
        heading[a:b] = np.arctan2(v[:, 1], v[:, 0])
    heading = np.unwrap(heading)
    # Where the vehicle hardly moves, hold the heading it had when it was moving.
    moving = speed > 0.3 * path.mean_speed_m_s
    if moving.any():
        idx = np.where(moving, np.arange(len(t)), -1)
        idx = np.maximum.accumulate(idx)
        first = int(np.flatnonzero(moving)[0])
        idx[idx < 0] = first
        heading = heading[idx]
    k = max(int(2.0 / dt), 1)  # a 2 s moving average: the heading lags the path
    kernel = np.ones(k) / k
    heading = np.convolve(np.pad(heading, (k // 2, k - 1 - k // 2), mode="edge"), kernel, "valid")
    sway = np.radians(path.yaw_sway_deg) * np.sin(2.0 * math.pi * t / path.yaw_sway_period_s)
    if path.kind == "laps":  # the later laps look another way
        turned = _lap_angle(path, t, rate)
        sway = sway + np.radians(path.lap_heading_deg) * _lap_change(turned)
    ramp = _smoothstep((t - path.still_s) / path.ramp_s)
    return np.asarray(heading[0] + ramp * (heading - heading[0] + sway), dtype=np.float64)


def _attitude_xyzw(
    path: FlightPath, t: FloatArray, rate: float, yaw: FloatArray, a: int, b: int, lo: int, hi: int
) -> FloatArray:
    """A multirotor's attitude at samples ``a:b`` (quaternions xyzw): thrust axis along ``a +
    g e_z``, x as near the heading ``yaw`` as that allows."""
    acc = _derivatives(_lissajous(path, t[lo:hi], rate), float(t[1] - t[0]))[1][a - lo : b - lo]
    z_B = acc + np.array([0.0, 0.0, GRAVITY_M_S2])
    z_B /= np.linalg.norm(z_B, axis=1, keepdims=True)
    x_c = np.column_stack([np.cos(yaw[a:b]), np.sin(yaw[a:b]), np.zeros(b - a)])
    y_B = np.cross(z_B, x_c)
    y_B /= np.linalg.norm(y_B, axis=1, keepdims=True)
    x_B = np.cross(y_B, z_B)
    return np.asarray(Rotation.from_matrix(np.stack([x_B, y_B, z_B], axis=2)).as_quat())


def flight_path_trajectory(
    path: FlightPath, *, rate_hz: float = 200.0, t0_ns: int = 0
) -> Trajectory:
    """The path's poses at ``rate_hz`` from ``t0_ns``."""
    n = int(path.duration_s * rate_hz) + 1
    t = np.arange(n) / rate_hz
    rate = _rate_for_speed(path)
    yaw = _heading(path, t, rate)
    p, q = np.empty((n, 3)), np.empty((n, 4))
    for a, b, lo, hi in _chunks(n):  # a few MB at a time, however long the flight
        p[a:b] = _lissajous(path, t[a:b], rate)
        q[a:b] = _attitude_xyzw(path, t, rate, yaw, a, b, lo, hi)
    return Trajectory(
        t_ns=t0_ns + np.round(t * NS_PER_S).astype(np.int64),
        p_W_B=p,
        q_W_B_xyzw=q,
        name="flight_path",
    )
