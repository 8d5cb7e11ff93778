"""Sensor models: IMU, position fix, GNSS, magnetometer, barometer, external vision pose and
range finder, with noise, period, bias or drift where physical, dropouts and faults.

Each sensor's :meth:`sample` reads the true state at ``t_ns`` and returns a sample whose
``t_ns`` is that time of validity. Delay is not the sensor's business: a :class:`DelayLine`
holds samples until their arrival time, which is what a consumer sees.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from typing import Generic, Literal, Protocol, TypeVar

import numpy as np
from numpy.random import Generator
from numpy.typing import NDArray

from quadnav.errors import SimError
from quadnav.geometry.navsat import GeoDatum, NavSatTransform
from quadnav.geometry.rotations import quat_xyzw_one, rot_z, rotation_matrix_xyzw
from quadnav.jit import njit
from quadnav.messages import (
    GpsSample,
    HeightSample,
    ImuSample,
    MagSample,
    PoseSample,
    PositionSample,
    RangeSample,
    Sample,
    VehicleState,
)
from quadnav.units import GRAVITY_M_S2

__all__ = [
    "BaroSensor",
    "DelayLine",
    "GpsSensor",
    "ImuErrorDraw",
    "ImuErrors",
    "ImuSensor",
    "IntegratingImu",
    "MagSensor",
    "PositionSensor",
    "RangeFinder",
    "Sensor",
    "Ticker",
    "VisionPoseSensor",
]

FloatArray = NDArray[np.float64]
S = TypeVar("S", bound=Sample)
S_co = TypeVar("S_co", bound=Sample, covariant=True)


class Ticker:
    """When a periodic sensor is due: due times accumulate (``k * period`` from the first
    sample), so a 30 Hz sensor polled on 2 ms steps gives 30 samples a second, not the 29.5 of
    "next = now + period". A poll after a gap catches up without a burst."""

    __slots__ = ("_next_ns", "period_ns")

    def __init__(self, period_ns: int, *, first_ns: int | None = None) -> None:
        if period_ns <= 0:
            raise SimError(f"a sensor's period must be > 0 ns, got {period_ns}")
        self.period_ns = int(period_ns)
        self._next_ns: int | None = first_ns

    @property
    def next_ns(self) -> int | None:
        """The next due time (``None`` before the first poll)."""
        return self._next_ns

    def due(self, t_ns: int) -> bool:
        """True (and the next due time set) when a sample is due at ``t_ns``."""
        nxt = self._next_ns
        if nxt is not None and t_ns < nxt:
            return False
        if nxt is None or t_ns - nxt >= self.period_ns:
            nxt = t_ns  # the first poll, or after a gap: start the grid afresh
        self._next_ns = nxt + self.period_ns
        return True


class Sensor(Protocol[S_co]):
    """A sensor model: reads the truth at ``t_ns``; ``None`` when it has nothing to report.

    A sensor may also say, with ``idle_until_ns(t_ns)``, until when polls after the one at
    ``t_ns`` would return ``None`` and change nothing (as :class:`PeriodicSensor` does): a
    :class:`~quadnav.sim.channels.Channel` then skips them. ``None`` there: poll every step."""

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> S_co | None: ...


class PeriodicSensor:
    """A sensor read on its :class:`Ticker` and doing nothing between due times (its
    ``sample`` returns ``None`` before anything else when the ticker is not due)."""

    _ticker: Ticker

    def idle_until_ns(self, t_ns: int) -> int | None:
        """Polls before this time return ``None`` and change nothing (``None``: unknown yet)."""
        return self._ticker.next_ns


@dataclass(frozen=True, slots=True, kw_only=True)
class ImuSensor:
    """Gyroscope and accelerometer with white noise of a given standard deviation per sample.

    ``accel_model="specific_force"`` is a real accelerometer: it measures
    ``R_W_B^T (a_W - g_W)``, so it reads +g upwards at rest. ``"kinematic"`` measures
    ``R_W_B^T a_W`` as the thesis 000 simulator did (offered to reproduce the thesis).
    """

    accel_sigma_m_s2: float
    gyro_sigma_rad_s: float
    gravity_m_s2: float = GRAVITY_M_S2
    accel_model: Literal["specific_force", "kinematic"] = "specific_force"

    def __post_init__(self) -> None:
        for name in ("accel_sigma_m_s2", "gyro_sigma_rad_s"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0.0:
                raise SimError(f"IMU {name} must be finite and >= 0, got {value}")

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> ImuSample:
        a_W = truth.a_W_B.copy()
        if self.accel_model == "specific_force":
            a_W[2] += self.gravity_m_s2
        f_B = rotation_matrix_xyzw(truth.q_W_B_xyzw).T @ a_W
        noise = rng.standard_normal(6)
        return ImuSample(
            t_ns=t_ns,
            gyro_rad_s=truth.w_B + self.gyro_sigma_rad_s * noise[0:3],
            accel_m_s2=f_B + self.accel_sigma_m_s2 * noise[3:6],
        )


class PositionSensor:
    """A position fix (GPS-like) every ``period_ns``, with Gaussian noise of ``sigma_m`` per axis.

    The first fix is taken at ``t0_ns + phase_ns``; when the period is not a whole number of
    simulation steps, a fix is taken at the first step at or after each due time.
    """

    def __init__(
        self,
        *,
        sigma_m: float,
        period_ns: int,
        source: str = "gps",
        t0_ns: int = 0,
        phase_ns: int = 0,
    ) -> None:
        if not math.isfinite(sigma_m) or sigma_m <= 0.0:
            raise SimError(f"position fix sigma_m must be finite and > 0, got {sigma_m}")
        if period_ns <= 0:
            raise SimError(f"position fix period_ns must be > 0, got {period_ns}")
        self.sigma_m = float(sigma_m)
        self.period_ns = int(period_ns)
        self.source = source
        self._next_due_ns = int(t0_ns) + int(phase_ns)

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> PositionSample | None:
        if t_ns < self._next_due_ns:
            return None
        while self._next_due_ns <= t_ns:
            self._next_due_ns += self.period_ns
        return PositionSample(
            t_ns=t_ns,
            p_W_B=truth.p_W_B + self.sigma_m * rng.standard_normal(3),
            sigma_m=self.sigma_m,
            source=self.source,
        )


_NEVER = 2**63 - 1  # (later than any time stamp)


class DelayLine(Generic[S]):
    """Holds samples until ``t_ns + delay`` (plus optional uniform jitter) has passed.

    With jitter, samples can come out in a different order from their times of validity,
    as measurements from a real link do.
    """

    def __init__(self, *, delay_ns: int, jitter_ns: int = 0) -> None:
        if delay_ns < 0 or jitter_ns < 0:
            raise SimError(f"delay and jitter must be >= 0 ns, got {delay_ns}, {jitter_ns}")
        self.delay_ns = int(delay_ns)
        self.jitter_ns = int(jitter_ns)
        self._heap: list[tuple[int, int, S]] = []
        self._seq = 0
        #: When the first sample queued arrives (later than any time when none is queued).
        self.next_arrival_ns = _NEVER

    def push(self, sample: S, rng: Generator | None = None, *, extra_delay_ns: int = 0) -> int:
        """Queue a sample (``extra_delay_ns``: this one is late); returns its arrival time."""
        extra = int(extra_delay_ns)
        if self.jitter_ns:
            if rng is None:
                raise SimError("a DelayLine with jitter needs an rng")
            extra += int(rng.integers(0, self.jitter_ns + 1))
        arrival = sample.t_ns + self.delay_ns + extra
        heapq.heappush(self._heap, (arrival, self._seq, sample))
        self._seq += 1
        self.next_arrival_ns = self._heap[0][0]
        return arrival

    def due(self, now_ns: int) -> bool:
        """Whether a sample has arrived by ``now_ns``."""
        return self.next_arrival_ns <= now_ns

    def pop_arrived(self, now_ns: int) -> list[tuple[int, S]]:
        """Samples whose arrival time is <= ``now_ns``, as (arrival_ns, sample), in arrival order."""
        out: list[tuple[int, S]] = []
        while self._heap and self._heap[0][0] <= now_ns:
            arrival, _, sample = heapq.heappop(self._heap)
            out.append((arrival, sample))
        self.next_arrival_ns = self._heap[0][0] if self._heap else _NEVER
        return out


@dataclass(frozen=True, slots=True, kw_only=True)
class ImuErrorDraw:
    """What ``n`` consecutive IMU samples add to the truth, (n, 3) each: a sample reads
    ``truth + bias + noise``. The biases are a dataset's ground truth (``bw*``, ``ba*``)."""

    gyro_bias_rad_s: FloatArray
    accel_bias_m_s2: FloatArray
    gyro_noise_rad_s: FloatArray
    accel_noise_m_s2: FloatArray


def _walk(steps: FloatArray, sigma: float, start: FloatArray) -> FloatArray:
    """Turn standard normal ``steps`` (N, 3), in place, into a random walk from ``start`` with
    steps of ``sigma``: row k the bias before step k; returns the bias after the last."""
    steps *= sigma
    np.cumsum(steps, axis=0, out=steps)
    end = start + steps[-1]
    steps[1:] = steps[:-1]
    steps[0] = 0.0
    steps += start
    return np.asarray(end, dtype=np.float64)


class ImuErrors:
    """An IMU's errors: white noise of a standard deviation per sample and biases that start at
    ``*_bias0`` and random-walk (``rw * sqrt(dt)`` per sample, ``rw`` a continuous density).
    :class:`IntegratingImu` and :func:`quadnav.sim.motion.synthesize_imu` both draw from it."""

    def __init__(
        self,
        *,
        gyro_sigma_rad_s: float,
        accel_sigma_m_s2: float,
        gyro_bias_rw_rad_s_sqrt_s: float = 0.0,
        accel_bias_rw_m_s2_sqrt_s: float = 0.0,
        gyro_bias0_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0),
        accel_bias0_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        for name, v in (
            ("gyro_sigma_rad_s", gyro_sigma_rad_s),
            ("accel_sigma_m_s2", accel_sigma_m_s2),
            ("gyro_bias_rw_rad_s_sqrt_s", gyro_bias_rw_rad_s_sqrt_s),
            ("accel_bias_rw_m_s2_sqrt_s", accel_bias_rw_m_s2_sqrt_s),
        ):
            if not (math.isfinite(v) and v >= 0):
                raise SimError(f"IMU {name} must be finite and >= 0, got {v}")
        self.sg, self.sa = float(gyro_sigma_rad_s), float(accel_sigma_m_s2)
        self.rw_g, self.rw_a = float(gyro_bias_rw_rad_s_sqrt_s), float(accel_bias_rw_m_s2_sqrt_s)
        self.bias_g = np.asarray(gyro_bias0_rad_s, dtype=np.float64).copy()
        self.bias_a = np.asarray(accel_bias0_m_s2, dtype=np.float64).copy()
        for name, b in (("gyro_bias0_rad_s", self.bias_g), ("accel_bias0_m_s2", self.bias_a)):
            if b.shape != (3,) or not np.isfinite(b).all():
                raise SimError(f"IMU {name} must be 3 finite numbers, got {b.tolist()}")

    def draw_one(
        self, dt_s: float, rng: Generator
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """:meth:`draw` of one sample, the same numbers without its arrays: the gyro and
        accelerometer biases the sample carries, then its gyro and accelerometer noise."""
        z = rng.standard_normal(12)  # the same numbers as four draws of 3, in that order
        sq = math.sqrt(dt_s)
        bg, ba = self.bias_g, self.bias_a
        out = (np.empty(3), np.empty(3), np.empty(3), np.empty(3))  # (new arrays: see _draw_one)
        _draw_one(z, bg, ba, self.sg, self.sa, self.rw_g * sq, self.rw_a * sq, out)
        ng, na, self.bias_g, self.bias_a = out
        return bg, ba, ng, na

    def reading_one(
        self, sums: tuple[FloatArray, FloatArray], dt_s: float, rng: Generator,
        gyro: FloatArray, accel: FloatArray,
    ) -> bool:  # fmt: skip
        """One sample's reading into ``gyro`` and ``accel``: the mean rate and specific force of
        its period's ``sums`` (rate, specific force: zeroed) plus :meth:`draw_one`'s errors (the
        same numbers, in one kernel); the biases move on. Whether all is finite."""
        z = rng.standard_normal(12)
        sq = math.sqrt(dt_s)
        bg1, ba1 = np.empty(3), np.empty(3)  # (new arrays: see _draw_one)
        ok: bool = _draw_reading(z, self.bias_g, self.bias_a, self.sg, self.sa, self.rw_g * sq,
                                 self.rw_a * sq, bg1, ba1, sums[0], sums[1], dt_s, gyro, accel)  # fmt: skip
        self.bias_g, self.bias_a = bg1, ba1
        return ok

    def draw(self, n: int, dt_s: float, rng: Generator) -> ImuErrorDraw:
        """The errors of the next ``n`` samples, ``dt_s`` apart; the biases move on past them.
        (One sample draws gyro noise, accel noise, gyro step, accel step: 3 normals each.)"""
        # In place, the same numbers as with copies: a dataset's 30 minutes at 200 Hz draw
        # 360,000 rows of each (8.6 MB), which copies made ~90 MB at once.
        noise_g, noise_a = rng.standard_normal((n, 3)), rng.standard_normal((n, 3))
        noise_g *= self.sg
        noise_a *= self.sa
        sq = math.sqrt(dt_s)
        bg, ba = rng.standard_normal((n, 3)), rng.standard_normal((n, 3))
        self.bias_g = _walk(bg, self.rw_g * sq, self.bias_g)
        self.bias_a = _walk(ba, self.rw_a * sq, self.bias_a)
        return ImuErrorDraw(
            gyro_bias_rad_s=bg,
            accel_bias_m_s2=ba,
            gyro_noise_rad_s=noise_g,
            accel_noise_m_s2=noise_a,
        )


class IntegratingImu:
    """A 3-D IMU that averages the simulator's fine steps over its own period, as a real IMU's
    delta angle and delta velocity do, with white noise per sample and random-walk biases.

    Call :meth:`accumulate` after every simulator step; it returns a sample when one is due.
    """

    def __init__(
        self,
        *,
        period_ns: int,
        gyro_sigma_rad_s: float,
        accel_sigma_m_s2: float,
        gyro_bias_rw_rad_s_sqrt_s: float = 0.0,
        accel_bias_rw_m_s2_sqrt_s: float = 0.0,
        gyro_bias0_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0),
        accel_bias0_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0),
        gravity_m_s2: float = GRAVITY_M_S2,
        t0_ns: int = 0,
        lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        if period_ns <= 0:
            raise SimError(f"IMU period_ns must be > 0, got {period_ns}")
        # The IMU's mount offset from the centre of mass in the body frame: it adds the
        # rotational terms dw/dt x r + w x (w x r) to the specific force it measures.
        self.lever_arm = np.asarray(lever_arm_m, dtype=np.float64)
        if self.lever_arm.shape != (3,) or not np.isfinite(self.lever_arm).all():
            raise SimError(f"IMU lever_arm_m must be 3 finite numbers, got {lever_arm_m}")
        self._w_prev: np.ndarray | None = None
        self._has_lever_arm = bool(self.lever_arm.any())
        self.errors = ImuErrors(
            gyro_sigma_rad_s=gyro_sigma_rad_s,
            accel_sigma_m_s2=accel_sigma_m_s2,
            gyro_bias_rw_rad_s_sqrt_s=gyro_bias_rw_rad_s_sqrt_s,
            accel_bias_rw_m_s2_sqrt_s=accel_bias_rw_m_s2_sqrt_s,
            gyro_bias0_rad_s=gyro_bias0_rad_s,
            accel_bias0_m_s2=accel_bias0_m_s2,
        )
        self.period_ns = int(period_ns)
        self.g = float(gravity_m_s2)
        self._t_last = int(t0_ns)
        self._t_poll: int | None = None
        self._ticker = Ticker(self.period_ns, first_ns=self._t_last + self.period_ns)
        self._sum_w = np.zeros(3)
        self._sum_f = np.zeros(3)
        self._sums = (self._sum_w, self._sum_f)
        self._sum_dt = 0.0

    @property
    def bias_g(self) -> FloatArray:
        """The gyro bias the next sample carries (rad/s)."""
        return self.errors.bias_g

    @property
    def bias_a(self) -> FloatArray:
        """The accelerometer bias the next sample carries (m/s^2)."""
        return self.errors.bias_a

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> ImuSample | None:
        """The :class:`Sensor` form, polled every simulator step: the step integrated is the
        time since the previous poll (the first poll only starts the clock)."""
        t_prev, self._t_poll = self._t_poll, t_ns
        if t_prev is None or t_ns <= t_prev:
            return None
        return self.accumulate(truth, (t_ns - t_prev) * 1e-9, rng)

    def accumulate(self, truth: VehicleState, dt_s: float, rng: Generator) -> ImuSample | None:
        if self._has_lever_arm:
            a = truth.a_W_B.copy()
            a[2] += self.g
            f_B = rotation_matrix_xyzw(truth.q_W_B_xyzw).T @ a
            w = truth.w_B
            dw = (w - self._w_prev) / dt_s if self._w_prev is not None else np.zeros(3)
            r = self.lever_arm
            f_B = f_B + np.cross(dw, r) + np.cross(w, np.cross(w, r))
            self._w_prev = truth.w_B.copy()
            self._sum_f += f_B * dt_s
            self._sum_w += truth.w_B * dt_s
        else:  # the hot path, every simulator step
            _accumulate(truth.a_W_B, truth.q_W_B_xyzw, truth.w_B, dt_s, self.g,
                        self._sum_f, self._sum_w)  # fmt: skip
        self._sum_dt += dt_s
        if not self._ticker.due(truth.t_ns):
            return None
        gyro, accel = np.empty(3), np.empty(3)
        if not self.errors.reading_one(self._sums, self._sum_dt, rng, gyro, accel):
            raise SimError(f"IMU at t_ns={truth.t_ns}: a non-finite reading (the state diverged)")
        self._t_last = truth.t_ns
        self._sum_dt = 0.0
        return ImuSample.from_checked(truth.t_ns, gyro, accel)


class GpsSensor(PeriodicSensor):
    """A GNSS receiver: geodetic fixes (the local ENU truth about a datum, through
    :class:`~quadnav.geometry.navsat.NavSatTransform`) and
    ENU velocity, with Gaussian noise, at a fixed rate. Outages and glitches are fault
    decorators (:class:`~quadnav.sim.channels.Dropouts`, :class:`~quadnav.sim.channels.OffsetTruth`)."""

    def __init__(
        self,
        *,
        datum_lla: tuple[float, float, float],
        period_ns: int,
        sigma_h_m: float,
        sigma_v_m: float,
        sigma_vel_m_s: float,
    ) -> None:
        if period_ns <= 0 or min(sigma_h_m, sigma_v_m, sigma_vel_m_s) <= 0:
            raise SimError(
                f"GNSS needs period_ns > 0 and positive sigma_h_m, sigma_v_m, sigma_vel_m_s, got "
                f"{period_ns}, {sigma_h_m}, {sigma_v_m}, {sigma_vel_m_s}"
            )
        self.datum = datum_lla
        self._plane = NavSatTransform(GeoDatum(*datum_lla))
        self.period_ns = int(period_ns)
        self.sh, self.sv, self.svel = float(sigma_h_m), float(sigma_v_m), float(sigma_vel_m_s)
        self._ticker = Ticker(self.period_ns)

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> GpsSample | None:
        if not self._ticker.due(t_ns):
            return None
        p_E = truth.p_W_B + rng.standard_normal(3) * np.array([self.sh, self.sh, self.sv])
        lat, lon, alt = self._plane.to_geodetic(p_E)[0]
        return GpsSample(
            t_ns=t_ns,
            lat_deg=float(lat),
            lon_deg=float(lon),
            alt_m=float(alt),
            v_enu_m_s=truth.v_W_B + self.svel * rng.standard_normal(3),
            sigma_h_m=self.sh,
            sigma_v_m=self.sv,
            sigma_vel_m_s=self.svel,
        )


class MagSensor(PeriodicSensor):
    """A magnetometer: the earth field (pointing to magnetic north, declination east of true
    north, dipping down) in the body frame, plus white noise and a hard-iron offset."""

    def __init__(
        self,
        *,
        period_ns: int,
        declination_rad: float = 0.0,
        inclination_rad: float = 1.1,
        strength: float = 0.5,
        noise_sigma: float = 0.005,
        hard_iron: tuple[float, float, float] = (0.0, 0.0, 0.0),
        sigma_heading_rad: float = 0.03,
    ) -> None:
        if period_ns <= 0 or strength <= 0 or noise_sigma < 0 or sigma_heading_rad <= 0:
            raise SimError(
                "magnetometer needs period_ns > 0, strength > 0, noise_sigma >= 0 and "
                f"sigma_heading_rad > 0, got {period_ns}, {strength}, {noise_sigma}, {sigma_heading_rad}"
            )
        h = strength * math.cos(inclination_rad)
        self.field_W = np.array(
            [
                h * math.sin(declination_rad),
                h * math.cos(declination_rad),
                -strength * math.sin(inclination_rad),
            ]
        )
        self.period_ns = int(period_ns)
        self.noise = float(noise_sigma)
        self.hard_iron = np.asarray(hard_iron, dtype=np.float64)
        self.sigma_heading = float(sigma_heading_rad)
        self._ticker = Ticker(self.period_ns)

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> MagSample | None:
        if not self._ticker.due(t_ns):
            return None
        m_B = rotation_matrix_xyzw(truth.q_W_B_xyzw).T @ self.field_W
        return MagSample(
            t_ns=t_ns,
            field_B=m_B + self.hard_iron + self.noise * rng.standard_normal(3),
            sigma_heading_rad=self.sigma_heading,
        )


class BaroSensor(PeriodicSensor):
    """A barometric altimeter: height above the world origin plus white noise and a slowly
    drifting offset (a random walk, as weather and temperature move a real one)."""

    def __init__(
        self, *, period_ns: int, sigma_m: float, drift_m_sqrt_s: float = 0.0, offset_m: float = 0.0
    ) -> None:
        if period_ns <= 0 or not sigma_m > 0 or not drift_m_sqrt_s >= 0:
            raise SimError(
                "barometer needs period_ns > 0, sigma_m > 0 and drift_m_sqrt_s >= 0, got "
                f"{period_ns}, {sigma_m}, {drift_m_sqrt_s}"
            )
        self.period_ns = int(period_ns)
        self.sigma = float(sigma_m)
        self.drift = float(drift_m_sqrt_s)
        self.offset = float(offset_m)
        self._ticker = Ticker(self.period_ns)

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> HeightSample | None:
        if not self._ticker.due(t_ns):
            return None
        self.offset += self.drift * math.sqrt(self.period_ns * 1e-9) * rng.standard_normal()
        z = float(truth.p_W_B[2]) + self.offset + self.sigma * rng.standard_normal()
        # (finite: the truth is, and so are the sigmas; the sample needs no checks)
        return HeightSample.from_checked(t_ns, z, self.sigma)


class RangeFinder(PeriodicSensor):
    """A downward range finder over flat ground at ``ground_z_m``: the distance along the
    body's -z axis, with noise; nothing outside its span or beyond ``max_tilt_rad``."""

    def __init__(
        self,
        *,
        period_ns: int,
        sigma_m: float,
        min_m: float = 0.05,
        max_m: float = 10.0,
        ground_z_m: float = 0.0,
        max_tilt_rad: float = 0.7,
    ) -> None:
        if period_ns <= 0 or not sigma_m > 0 or not 0 <= min_m < max_m:
            raise SimError(
                "range finder needs period_ns > 0, sigma_m > 0 and 0 <= min_m < max_m, got "
                f"{period_ns}, {sigma_m}, {min_m}, {max_m}"
            )
        self.period_ns = int(period_ns)
        self.sigma, self.min_m, self.max_m = float(sigma_m), float(min_m), float(max_m)
        self.ground_z = float(ground_z_m)
        self.cos_max_tilt = math.cos(max_tilt_rad)
        self._ticker = Ticker(self.period_ns)

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> RangeSample | None:
        if not self._ticker.due(t_ns):
            return None
        q = truth.q_W_B_xyzw  # R_W_B[2, 2] of the unit quaternion
        c = 1.0 - 2.0 * float(q[0] * q[0] + q[1] * q[1])
        if c < self.cos_max_tilt:
            return None
        rng_m = (float(truth.p_W_B[2]) - self.ground_z) / c + self.sigma * rng.standard_normal()
        if not self.min_m <= rng_m <= self.max_m:
            return None
        return RangeSample(
            t_ns=t_ns, range_m=rng_m, sigma_m=self.sigma, min_m=self.min_m, max_m=self.max_m
        )


class VisionPoseSensor(PeriodicSensor):
    """An external pose (marker or VIO system): the body's position and attitude in a vision
    frame ``V`` that is turned by ``frame_yaw_rad`` about the vertical and offset by
    ``frame_offset_m`` from the world (``T_W_V``), with position and yaw noise. Dropouts and
    frame jumps are fault decorators (:class:`~quadnav.sim.channels.Dropouts`,
    :class:`~quadnav.sim.channels.FrameJumps`)."""

    def __init__(
        self,
        *,
        period_ns: int,
        sigma_m: float,
        yaw_sigma_rad: float,
        frame_yaw_rad: float = 0.0,
        frame_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        if period_ns <= 0 or not sigma_m > 0 or not yaw_sigma_rad > 0:
            raise SimError(
                "vision pose needs period_ns > 0 and positive sigma_m, yaw_sigma_rad, got "
                f"{period_ns}, {sigma_m}, {yaw_sigma_rad}"
            )
        self.period_ns = int(period_ns)
        self.sigma, self.yaw_sigma = float(sigma_m), float(yaw_sigma_rad)
        self._R_V_W = rot_z(-float(frame_yaw_rad))  # (matrices: SciPy's Rotation per sample
        self.p_W_V = np.asarray(frame_offset_m, dtype=np.float64)  # cost most of a flight step)
        self._ticker = Ticker(self.period_ns)

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> PoseSample | None:
        if not self._ticker.due(t_ns):
            return None
        yaw_err = self.yaw_sigma * rng.standard_normal()
        noise = rng.standard_normal(3)
        p, q = np.empty(3), np.empty(4)
        _vision_pose(self._R_V_W, self.p_W_V, truth.p_W_B, truth.q_W_B_xyzw, yaw_err,
                     self.sigma, noise, p, q)  # fmt: skip
        # (fresh finite arrays, a unit quaternion: the sample needs no checks)
        return PoseSample.from_checked(t_ns, p, q, self.sigma, self.yaw_sigma)


@njit
def _vision_pose(
    R_V_W: FloatArray, p_W_V: FloatArray, p_W_B: FloatArray, q_W_B: FloatArray, yaw_err: float,
    sigma: float, noise: FloatArray, p: FloatArray, q: FloatArray,
) -> None:  # fmt: skip
    """:class:`VisionPoseSensor`'s reading into ``p`` and ``q``: the position in the vision
    frame, ``R_V_W (p_W_B - p_W_V) + sigma noise``, and the quaternion of
    ``R_V_B = R_V_W R(q_W_B) R_z(yaw_err)``."""
    R = np.empty((3, 3))
    qx, qy, qz, qw = q_W_B[0], q_W_B[1], q_W_B[2], q_W_B[3]
    R[0, 0], R[0, 1], R[0, 2] = (
        1 - 2 * (qy * qy + qz * qz),
        2 * (qx * qy - qw * qz),
        2 * (qx * qz + qw * qy),
    )
    R[1, 0], R[1, 1], R[1, 2] = (
        2 * (qx * qy + qw * qz),
        1 - 2 * (qx * qx + qz * qz),
        2 * (qy * qz - qw * qx),
    )
    R[2, 0], R[2, 1], R[2, 2] = (
        2 * (qx * qz - qw * qy),
        2 * (qy * qz + qw * qx),
        1 - 2 * (qx * qx + qy * qy),
    )
    c, s = math.cos(yaw_err), math.sin(yaw_err)
    M = np.empty((3, 3))  # R_V_W R(q_W_B) R_z(yaw_err)
    for i in range(3):
        d = p_W_B[0] - p_W_V[0], p_W_B[1] - p_W_V[1], p_W_B[2] - p_W_V[2]
        p[i] = R_V_W[i, 0] * d[0] + R_V_W[i, 1] * d[1] + R_V_W[i, 2] * d[2] + sigma * noise[i]
        a0 = R_V_W[i, 0] * R[0, 0] + R_V_W[i, 1] * R[1, 0] + R_V_W[i, 2] * R[2, 0]
        a1 = R_V_W[i, 0] * R[0, 1] + R_V_W[i, 1] * R[1, 1] + R_V_W[i, 2] * R[2, 1]
        a2 = R_V_W[i, 0] * R[0, 2] + R_V_W[i, 1] * R[1, 2] + R_V_W[i, 2] * R[2, 2]
        M[i, 0], M[i, 1], M[i, 2] = a0 * c + a1 * s, a1 * c - a0 * s, a2
    q[:] = quat_xyzw_one(M)


@njit
def _accumulate(
    a_W: FloatArray, q: FloatArray, w: FloatArray, dt: float, g: float, sum_f: FloatArray,
    sum_w: FloatArray,
) -> None:  # fmt: skip
    """Adds one simulator step's specific force (``R_W_B^T (a_W + g z)``) and body rate, each
    times ``dt``, into the sums (in place)."""
    qx, qy, qz, qw = q[0], q[1], q[2], q[3]
    ax, ay, az = a_W[0], a_W[1], a_W[2] + g
    # R_W_B's columns dotted with a: R^T a
    f0 = (1 - 2 * (qy * qy + qz * qz)) * ax + 2 * (qx * qy + qw * qz) * ay
    f0 += 2 * (qx * qz - qw * qy) * az
    f1 = 2 * (qx * qy - qw * qz) * ax + (1 - 2 * (qx * qx + qz * qz)) * ay
    f1 += 2 * (qy * qz + qw * qx) * az
    f2 = 2 * (qx * qz + qw * qy) * ax + 2 * (qy * qz - qw * qx) * ay
    f2 += (1 - 2 * (qx * qx + qy * qy)) * az
    sum_f[0] += f0 * dt
    sum_f[1] += f1 * dt
    sum_f[2] += f2 * dt
    for k in range(3):
        sum_w[k] += w[k] * dt


@njit
def _draw_one(
    z: FloatArray, bg: FloatArray, ba: FloatArray, sg: float, sa: float, step_g: float,
    step_a: float, out: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
) -> None:  # fmt: skip
    """:meth:`ImuErrors.draw_one` from its 12 standard normals ``z``, into ``out``: the gyro
    and accelerometer noise (``z[0:3] sg``, ``z[3:6] sa``), then the biases after the sample
    (``bg + z[6:9] step_g``, ``ba + z[9:12] step_a``). New arrays each sample: the biases
    before it are what the sample carries (and what a log keeps)."""
    ng, na, bg1, ba1 = out
    for k in range(3):
        ng[k] = z[k] * sg
        na[k] = z[3 + k] * sa
        bg1[k] = bg[k] + z[6 + k] * step_g
        ba1[k] = ba[k] + z[9 + k] * step_a


@njit
def _draw_reading(
    z: FloatArray, bg: FloatArray, ba: FloatArray, sg: float, sa: float, step_g: float,
    step_a: float, bg1: FloatArray, ba1: FloatArray, sum_w: FloatArray, sum_f: FloatArray,
    T: float, gyro: FloatArray, accel: FloatArray,
) -> bool:  # fmt: skip
    """:func:`_draw_one` (the noise and the biases after the sample into ``bg1``, ``ba1``) and
    :func:`_reading` with it, in one kernel: :meth:`ImuErrors.reading_one`."""
    ng, na = np.empty(3), np.empty(3)
    _draw_one(z, bg, ba, sg, sa, step_g, step_a, (ng, na, bg1, ba1))
    ok: bool = _reading(sum_w, sum_f, T, bg, ba, ng, na, gyro, accel)
    return ok


@njit
def _reading(
    sum_w: FloatArray, sum_f: FloatArray, T: float, bg: FloatArray, ba: FloatArray,
    ng: FloatArray, na: FloatArray, gyro: FloatArray, accel: FloatArray,
) -> bool:  # fmt: skip
    """One IMU sample from its period's sums (the mean rate and specific force plus the
    biases and noise) into ``gyro`` and ``accel``; the sums zeroed. Whether all is finite."""
    ok = True
    for k in range(3):
        gyro[k] = sum_w[k] / T + bg[k] + ng[k]
        accel[k] = sum_f[k] / T + ba[k] + na[k]
        ok = ok and math.isfinite(gyro[k]) and math.isfinite(accel[k])
        sum_w[k] = 0.0
        sum_f[k] = 0.0
    return ok
