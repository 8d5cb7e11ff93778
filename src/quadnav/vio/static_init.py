"""The static start (EuRoC's sequences and our flights begin at rest): from at least
``static_window_s`` of quiet IMU, gravity's direction in the body gives roll and pitch (the
smallest rotation taking the measured "up" onto the world's z, so yaw is that of the body),
the mean gyro is its bias, the velocity is zero. The accelerometer bias cannot be told from a
tilt at rest; it starts at zero and the window estimates it once the vehicle moves."""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.messages import ImuSample
from quadnav.units import s_to_ns
from quadnav.vio.config import VioConfig

__all__ = ["ImuStillness", "StaticStart", "gravity_rotation", "imu_stillness", "static_start"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class ImuStillness:
    """The IMU over a span: sample count, mean, and the standard deviation (norm over axes) of
    its low-passed values (means over short bins)."""

    n: int
    span_s: float
    gyro_mean: FloatArray
    accel_mean: FloatArray
    gyro_std: float
    accel_std: float


@dataclass(frozen=True, slots=True, kw_only=True)
class StaticStart:
    t_ns: int
    R_W_B: Rotation
    gyro_bias: FloatArray
    stillness: ImuStillness


def _stamp(s: ImuSample) -> int:
    return s.t_ns


def _binned_std(t_ns: NDArray[np.int64], x: FloatArray, bin_ns: int) -> float:
    """The standard deviation (norm over axes) of ``x``'s means over time bins of ``bin_ns``:
    a vehicle standing with its motors on vibrates, and the vibration averages out."""
    b = (t_ns - t_ns[0]) // max(bin_ns, 1)
    _, inv, cnt = np.unique(b, return_inverse=True, return_counts=True)
    sums = np.zeros((len(cnt), x.shape[1]))
    np.add.at(sums, inv, x)
    means = sums / cnt[:, None]
    return float(np.linalg.norm(means.std(axis=0))) if len(cnt) >= 3 else float("inf")


def imu_stillness(
    samples: Sequence[ImuSample], t0_ns: int, t1_ns: int, lowpass_s: float = 0.1
) -> ImuStillness | None:
    """The statistics of the samples (in time order) stamped in ``[t0_ns, t1_ns]`` (None with
    fewer than 10):
    the mean, and the spread of the means over ``lowpass_s`` bins."""
    i0 = bisect.bisect_left(samples, t0_ns, key=_stamp)
    i1 = bisect.bisect_right(samples, t1_ns, key=_stamp)
    sel = samples[i0:i1]
    if len(sel) < 10:
        return None
    t = np.array([s.t_ns for s in sel], np.int64)
    g = np.array([s.gyro_rad_s for s in sel])
    a = np.array([s.accel_m_s2 for s in sel])
    bin_ns = s_to_ns(lowpass_s)
    return ImuStillness(
        n=len(sel),
        span_s=(sel[-1].t_ns - sel[0].t_ns) * 1e-9,
        gyro_mean=g.mean(axis=0),
        accel_mean=a.mean(axis=0),
        gyro_std=_binned_std(t, g, bin_ns),
        accel_std=_binned_std(t, a, bin_ns),
    )


def is_still(st: ImuStillness | None, config: VioConfig, span_s: float) -> bool:
    return (
        st is not None
        and st.span_s >= 0.9 * span_s
        and st.gyro_std <= config.static_gyro_std_rad_s
        and st.accel_std <= config.static_accel_std_m_s2
    )


def gravity_rotation(accel_mean_B: FloatArray) -> Rotation:
    """``R_W_B`` taking the specific force measured at rest (pointing up) onto ``+z``."""
    a = np.asarray(accel_mean_B, dtype=np.float64)
    up = a / np.linalg.norm(a)
    ez = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, ez)
    s, c = float(np.linalg.norm(axis)), float(up @ ez)
    if s < 1e-12:
        return Rotation.identity() if c > 0 else Rotation.from_rotvec([np.pi, 0.0, 0.0])
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c))


def heading_of(R_W_B: Rotation, forward_B: FloatArray) -> Rotation:
    """``R_W_B`` turned about the vertical so that ``forward_B`` (a vehicle's forward axis in
    the body frame) points along the world's +x: the world's heading is the vehicle's, not that
    of a body mounted on its side (EuRoC's IMU, x up: the smallest rotation from its "up" put
    the vehicle's nose at 180 degrees). A forward axis along the vertical leaves it as it is."""
    f = R_W_B.apply(np.asarray(forward_B, dtype=np.float64))
    if math.hypot(float(f[0]), float(f[1])) < 1e-6:
        return R_W_B
    return Rotation.from_euler("z", -math.atan2(float(f[1]), float(f[0]))) * R_W_B


def static_start(
    samples: Sequence[ImuSample], t_ns: int, config: VioConfig, g_tolerance: float | None = None
) -> StaticStart | None:
    """A start at ``t_ns`` when the IMU has been still for the last ``static_window_s`` and
    reads gravity's magnitude within ``g_tolerance`` m/s^2; None otherwise. At rest an
    accelerometer reads gravity plus its bias: by default the tolerance is what a bias of three
    times the start's prior (``init_accel_bias_sigma_m_s2`` per axis) can add, 0.5 m/s^2 at
    least. (A fixed 0.5 refused the start of a realistic IMU whose drawn bias was 0.67 m/s^2: the
    monocular VIO then never started on those 42 s of laps.)"""
    if g_tolerance is None:
        g_tolerance = max(0.5, 3.0 * math.sqrt(3.0) * config.init_accel_bias_sigma_m_s2)
    span = config.static_window_s
    st = imu_stillness(samples, t_ns - s_to_ns(span), t_ns, config.static_lowpass_s)
    if st is None or not is_still(st, config, span):
        return None
    if abs(float(np.linalg.norm(st.accel_mean)) - config.g_norm) > g_tolerance:
        return None
    return StaticStart(
        t_ns=int(t_ns),
        R_W_B=gravity_rotation(st.accel_mean),
        gyro_bias=st.gyro_mean.copy(),
        stillness=st,
    )
