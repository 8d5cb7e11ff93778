"""A downward optical-flow sensor (PX4FLOW class) over a flat floor.

The camera sits at the body origin and looks along body -z at the floor ``z = floor_z_m``.
The flow it reports is the line-of-sight rate of the centre of its image, integrated over
its interval, with the signs of :class:`~quadnav.messages.FlowSample` (MAVLink's
``OPTICAL_FLOW_RAD``): a right-handed rotation of the sensor makes a positive flow. Here it
is computed from the moving scene point (the floor point on the optical axis, at distance
``r``, moving at ``-v_B - w_B x P`` in the body frame), not from the EKF's closed form, so
the two can check each other. The sensor's own gyro is integrated beside it, with its own
noise and bias.

Timing: :meth:`FlowSensor.sample` is called every simulator step; it integrates between
calls and returns one sample per period (due times accumulate, so 50 Hz on 2 ms steps is
50 Hz), time-stamped at the middle of its interval as PX4 fuses it. After a gap of more than
a period between calls (a dropout that did not read it) it opens a fresh interval rather
than integrate across the gap. Default rate 50 Hz:
PX4's px4flow driver ran the PX4FLOW at 10 Hz by default and at most 100 Hz (a 20 ms
interval in its first version), PX4 caps flow publication at ``SENS_FLOW_RATE`` = 70 Hz,
and EKF2 fuses every sample it gets. Delay is the channel's: PX4FLOW's is 15 ms (thesis 000,
fig. 2.1c), :data:`FLOW_DELAY_S`, counted from the time of validity.

Validity: below ``min_height_m`` (PX4FLOW's sonar, a MaxBotix HRLV-EZ4, reads from 0.3 m;
the lens loses focus too) or darker than ``min_illumination`` there is no output. Quality
is ``quality_max`` scaled by the illumination, and 0 (no valid flow) above ``max_height_m``
(the sonar's 5 m) or when the rate exceeds ``max_rate_rad_s``. The flow noise grows as the
light fades: ``flow_sigma_rad_s / illumination``. The range reading (``distance_m``) is
``None`` beyond ``max_tilt_rad`` or outside the sonar's span.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.random import Generator
from numpy.typing import NDArray

from quadnav.errors import SimError
from quadnav.geometry.rotations import cross3, rotation_matrix_xyzw
from quadnav.messages import FlowSample, VehicleState
from quadnav.units import s_to_ns

__all__ = ["FLOW_DELAY_S", "FlowSensor", "line_of_sight_rate"]

FloatArray = NDArray[np.float64]
#: PX4FLOW's measurement delay (thesis 000, fig. 2.1c): the default of a flow channel.
FLOW_DELAY_S = 0.015


def line_of_sight_rate(
    R_W_B: FloatArray, v_W: FloatArray, w_B: FloatArray, height_m: float
) -> FloatArray:
    """The flow rate (rad/s, about body x, y) a down-looking camera at ``height_m`` over a
    flat floor sees at its image centre, body rotation included (``== w_B[:2]`` at rest)."""
    u = np.array([0.0, 0.0, -1.0])  # the optical axis in the body frame
    r = height_m / float(R_W_B[2, 2])
    P = r * u
    dP = -(R_W_B.T @ v_W) - cross3(w_B, P)  # the scene point's velocity seen from the body
    omega_los = cross3(u, dP) / r  # the rotation of the line of sight, in the body frame
    return np.asarray(-omega_los[:2], dtype=np.float64)  # the sensor's sign: its own rotation


class FlowSensor:
    """The flow sensor; a :class:`~quadnav.sim.sensors.Sensor` of :class:`FlowSample`."""

    def __init__(
        self,
        *,
        rate_hz: float = 50.0,
        flow_sigma_rad_s: float = 0.05,
        gyro_sigma_rad_s: float = 0.005,
        gyro_bias_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0),
        distance_sigma_m: float = 0.01,
        min_height_m: float = 0.3,
        max_height_m: float = 5.0,
        max_rate_rad_s: float = 8.0,
        max_tilt_rad: float = 0.7,
        floor_z_m: float = 0.0,
        quality_max: int = 255,
        illumination: float = 1.0,
        min_illumination: float = 0.1,
        t0_ns: int = 0,
        source: str = "flow",
    ) -> None:
        for name, v in (
            ("rate_hz", rate_hz),
            ("max_rate_rad_s", max_rate_rad_s),
            ("min_illumination", min_illumination),
        ):
            if not (math.isfinite(v) and v > 0):
                raise SimError(f"flow sensor {name} must be finite and > 0, got {v}")
        for name, v in (
            ("flow_sigma_rad_s", flow_sigma_rad_s),
            ("gyro_sigma_rad_s", gyro_sigma_rad_s),
            ("distance_sigma_m", distance_sigma_m),
            ("illumination", illumination),
        ):
            if not (math.isfinite(v) and v >= 0):
                raise SimError(f"flow sensor {name} must be finite and >= 0, got {v}")
        if not 0 <= min_height_m < max_height_m or not 1 <= quality_max <= 255:
            raise SimError(
                "flow sensor needs 0 <= min_height_m < max_height_m and quality_max in 1..255, "
                f"got {min_height_m}, {max_height_m}, {quality_max}"
            )
        self.period_ns = s_to_ns(1.0 / rate_hz)
        self.flow_sigma, self.gyro_sigma = float(flow_sigma_rad_s), float(gyro_sigma_rad_s)
        self.gyro_bias = np.asarray(gyro_bias_rad_s, dtype=np.float64)
        self.distance_sigma = float(distance_sigma_m)
        self.min_height_m, self.max_height_m = float(min_height_m), float(max_height_m)
        self.max_rate, self.cos_max_tilt = float(max_rate_rad_s), math.cos(max_tilt_rad)
        self.floor_z, self.quality_max = float(floor_z_m), int(quality_max)
        self.illumination, self.min_illumination = float(illumination), float(min_illumination)
        self.source = source
        self.delay_s = FLOW_DELAY_S  # for the channel's delay line; the sensor does not delay
        self._t_start = int(t0_ns)  # the open interval's start (set again at the first call)
        self._t_last: int | None = None
        self._next_due = int(t0_ns) + self.period_ns
        self._flow = np.zeros(2)
        self._gyro = np.zeros(3)

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> FlowSample | None:
        R = rotation_matrix_xyzw(truth.q_W_B_xyzw)
        h = float(truth.p_W_B[2]) - self.floor_z
        if self._t_last is None or t_ns - self._t_last > self.period_ns:
            # The first call, or the first after a gap (a dropout that did not read the
            # sensor): a fresh interval opens here, on the same grid of due times.
            self._flow, self._gyro, self._t_start = np.zeros(2), np.zeros(3), t_ns
            while self._next_due <= t_ns:
                self._next_due += self.period_ns
        elif t_ns > self._t_last and h > 0 and R[2, 2] > 0:
            dt = (t_ns - self._t_last) * 1e-9
            self._flow += dt * line_of_sight_rate(R, truth.v_W_B, truth.w_B, h)
            self._gyro += dt * truth.w_B
        self._t_last = t_ns
        if t_ns < self._next_due:
            return None
        while self._next_due <= t_ns:
            self._next_due += self.period_ns
        flow, gyro, t_start = self._flow, self._gyro, self._t_start
        self._flow, self._gyro, self._t_start = np.zeros(2), np.zeros(3), t_ns
        if h < self.min_height_m or self.illumination < self.min_illumination:
            return None  # too close to focus (and below the sonar), or too dark
        T_ns = t_ns - t_start
        T = T_ns * 1e-9
        quality = round(self.quality_max * min(self.illumination, 1.0))
        if h > self.max_height_m or float(np.linalg.norm(flow)) / T > self.max_rate:
            quality = 0
        sigma = self.flow_sigma / min(self.illumination, 1.0)
        return FlowSample(
            t_ns=t_start + T_ns // 2,
            integration_ns=T_ns,
            flow_rad=flow + T * sigma * rng.standard_normal(2),
            gyro_rad=gyro + T * (self.gyro_bias + self.gyro_sigma * rng.standard_normal(3)),
            quality=quality,
            distance_m=self._distance(R, h, rng),
            source=self.source,
        )

    def _distance(self, R: FloatArray, h: float, rng: Generator) -> float | None:
        c = float(R[2, 2])
        if c < self.cos_max_tilt:
            return None
        d = h / c + self.distance_sigma * rng.standard_normal()
        return d if self.min_height_m <= d <= self.max_height_m else None
