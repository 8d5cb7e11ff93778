"""The IMU's white noise measured from its own readings, while it flies.

A datasheet states the sensor's noise on a bench; on a vehicle, rotor vibration raises it many
times (EuRoC's ADIS16448: 16x on the gyroscope, 31x on the accelerometer; see
:meth:`~quadnav.rig.ImuNoiseModel.euroc_adis16448_in_flight`). A VIO told the datasheet's noise
trusts its IMU too much and its covariance is overconfident; told a constant inflation, it is
wrong on the ground and on another vehicle. VINS-Mono and OpenVINS take the inflation as a
setting the user tunes.

:class:`ImuNoiseMonitor` measures it instead, over the last ``window_s`` of readings, from each
axis's second differences ``x[k+1] - 2 x[k] + x[k-1]``: for white noise of per-sample standard
deviation ``s`` their variance is ``6 s**2``, and a vehicle's motion adds almost nothing to them at
an IMU's rate (an angular jerk of 50 rad/s^3 adds 1e-3 rad/s at 200 Hz against EuRoC's in-flight
0.1). The density is ``s * sqrt(dt)``. Samples after a gap (more than 1.5 times the typical step)
start the differences afresh; non-finite readings are skipped.

A shock is not noise: a touchdown at 2 m/s reads 290 m/s^2 for one sample, and in the mean it
made the accelerometer's noise 650 times the stated one for the window's two seconds, in which
the VIO, its IMU weighed at almost nothing, drifted off and the flight's estimate with it
(``outdoor_vio_gps_realistic``, 2026-12-05). Each squared difference is capped at
:data:`SHOCK_CAP` times the typical one (a median, over the chi-square's median 0.455): Gaussian
noise loses 6e-5 of its samples to the cap and keeps its mean; a vibration's sinusoid none. The
typical one is the larger of the window's median and the last :data:`RECENT_S`'s, so that the
noise's rise at a take-off (16x and 31x within a sample) is not capped at the ground's level
until it fills half the window; a touchdown's few samples move neither median. An axis whose
median is zero (readings quantised to the same value) is not capped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.units import NS_PER_S

__all__ = ["ImuNoiseMonitor", "MeasuredNoise"]

FloatArray = NDArray[np.float64]

#: a squared second difference is capped at this many times the window's typical one (4 sigma)
SHOCK_CAP = 16.0
#: the span of the recent readings whose median the cap also follows (s)
RECENT_S = 0.25
#: the median of a chi-square variable of one degree of freedom: a squared Gaussian's median
#: over its mean
CHI2_1_MEDIAN = 0.4549364


@dataclass(frozen=True, slots=True)
class MeasuredNoise:
    """White-noise densities per axis (gyroscope rad/s/sqrt(Hz), accelerometer
    m/s^2/sqrt(Hz)) over ``samples`` second differences."""

    gyro: FloatArray
    accel: FloatArray
    samples: int


class ImuNoiseMonitor:
    """The IMU's white-noise densities over its last ``window_s`` of readings (see the module)."""

    def __init__(self, window_s: float = 2.0, rate_hz: float = 200.0) -> None:
        if not (math.isfinite(window_s) and window_s > 0.0):
            raise ValueError(f"window_s must be positive, got {window_s}")
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f"rate_hz must be positive, got {rate_hz}")
        self._n = max(round(window_s * rate_hz), 8)
        self._recent = min(max(round(RECENT_S * rate_hz), 8), self._n)
        self._sq = np.zeros((self._n, 6))  # squared second differences, a ring
        self._dt = np.zeros(self._n)
        self._count = 0
        self._head = 0
        self._prev: list[tuple[int, FloatArray]] = []  # the last two (t_ns, reading)
        self._step_ns = 0.0  # the typical step between samples

    def push(self, t_ns: int, gyro: FloatArray, accel: FloatArray) -> None:
        """One reading (in time order)."""
        x = np.concatenate([np.asarray(gyro, np.float64), np.asarray(accel, np.float64)])
        if not np.all(np.isfinite(x)):
            return
        if self._prev and t_ns <= self._prev[-1][0]:
            return
        if self._prev:
            step = t_ns - self._prev[-1][0]
            if self._step_ns == 0.0:
                self._step_ns = float(step)
            if step > 1.5 * self._step_ns:
                self._prev.clear()  # a gap: start afresh
            else:
                self._step_ns += 0.01 * (step - self._step_ns)
        self._prev.append((t_ns, x))
        if len(self._prev) > 3:
            del self._prev[0]
        if len(self._prev) == 3:
            (_, a), (_, b), (_, c) = self._prev
            self._sq[self._head] = (c - 2.0 * b + a) ** 2
            self._dt[self._head] = self._step_ns / NS_PER_S
            self._head = (self._head + 1) % self._n
            self._count = min(self._count + 1, self._n)

    def noise(self, min_samples: int = 100) -> MeasuredNoise | None:
        """The densities over the window; None before ``min_samples`` second differences."""
        if self._count < min(min_samples, self._n):
            return None
        sq = self._sq[: self._count] if self._count < self._n else self._sq
        dt = self._dt[: self._count] if self._count < self._n else self._dt
        m = min(self._recent, self._count)
        recent = self._sq[(self._head - 1 - np.arange(m)) % self._n]
        typical = np.maximum(np.median(sq, axis=0), np.median(recent, axis=0)) / CHI2_1_MEDIAN
        capped = np.minimum(sq, np.where(typical > 0.0, SHOCK_CAP * typical, np.inf))
        density = np.sqrt(capped.mean(axis=0) / 6.0 * float(dt.mean()))
        return MeasuredNoise(gyro=density[:3], accel=density[3:], samples=self._count)
