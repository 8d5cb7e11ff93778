"""Sensor channels: a sensor, its faults, its delay line and its own random stream.

A closed loop iterates over a list of :class:`Channel`s: each step, every channel reads the
truth through its sensor (wrapped by the fault decorators that act on what is measured), lets
the delivery faults act on what comes out (late, repeated or corrupted samples), and queues the
result in its delay line; :meth:`Channel.arrived` hands over what has arrived by now.

Two kinds of decorators, so the loop has no fault branches:

- a *sensor fault* wraps a :class:`~quadnav.sim.sensors.Sensor` and is one itself:
  :class:`Dropouts` (no sample inside windows), :class:`OffsetTruth` (the truth the sensor sees
  is displaced, as a GNSS glitch displaces the fixes), :class:`FrameJumps` (an external pose's
  frame re-initialises and its reset counter goes up);
- a *delivery fault* acts on a sample once it is measured: :class:`LateAt` (this one arrives
  later), :class:`RepeatAt` (delivered twice: the copy is out of order), :class:`CorruptAt`
  (a reading with NaN, refused at the driver boundary and counted, as a real driver would).

Every channel has its own generator (the closed loop spawns one ``SeedSequence`` child per
registered channel), so enabling one sensor does not change another's noise for the same seed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.random import Generator
from scipy.spatial.transform import Rotation

from quadnav.errors import SampleError, SimError
from quadnav.messages import PoseSample, Sample, VehicleState
from quadnav.sim.sensors import DelayLine, Sensor

__all__ = [
    "Channel",
    "CorruptAt",
    "DeliveryFault",
    "Dropouts",
    "FrameJump",
    "FrameJumps",
    "LateAt",
    "OffsetTruth",
    "RepeatAt",
    "in_windows",
]


def in_windows(t_ns: int, windows_ns: Sequence[tuple[int, int]]) -> bool:
    """Whether ``t_ns`` lies in one of the ``[start, end)`` windows."""
    for a, b in windows_ns:  # noqa: SIM110 (a loop, not any(): every simulator step asks)
        if a <= t_ns < b:
            return True
    return False


# -- sensor faults (wrap a Sensor, are a Sensor) -------------------------------------------------
@dataclass
class Dropouts:
    """No sample inside the ``[start, end)`` windows (the sensor is not even read: a camera
    renders nothing)."""

    inner: Sensor[Any]
    windows_ns: Sequence[tuple[int, int]]

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> Any:
        if in_windows(t_ns, self.windows_ns):
            return None
        return self.inner.sample(truth, t_ns, rng)

    def idle_until_ns(self, t_ns: int) -> int | None:
        """Inside a window, its end (nothing is read there); outside, the inner sensor's."""
        for a, b in self.windows_ns:
            if a <= t_ns < b:
                return b
        inner = getattr(self.inner, "idle_until_ns", None)
        return None if inner is None else inner(t_ns)


@dataclass
class OffsetTruth:
    """Inside each window the sensor sees the truth displaced by the window's world offset
    (a GNSS multipath glitch: the fixes jump by metres)."""

    inner: Sensor[Any]
    windows_ns: Sequence[tuple[int, int, tuple[float, float, float]]]

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> Any:
        off = np.zeros(3)
        for a, b, d in self.windows_ns:
            if a <= t_ns < b:
                off = off + np.asarray(d, dtype=np.float64)
        if off.any():
            truth = dataclasses.replace(truth, p_W_B=truth.p_W_B + off)
        return self.inner.sample(truth, t_ns, rng)


@dataclass(frozen=True, slots=True)
class FrameJump:
    """At ``t_ns`` the external pose's frame turns by ``yaw_rad`` about the vertical and moves
    by ``offset_m`` (in the frame before the jump), and its reset counter goes up."""

    t_ns: int
    yaw_rad: float
    offset_m: tuple[float, float, float]


@dataclass
class FrameJumps:
    """An external pose sensor whose frame re-initialises at the given times: the poses are
    expressed in the new frame ``V'`` (``T_V_V'`` accumulated over the jumps so far) and carry
    the reset counter."""

    inner: Sensor[PoseSample]
    jumps: Sequence[FrameJump]
    reset_counter: int = 0
    _R_V_Vn: Rotation = field(default_factory=Rotation.identity)
    _p_V_Vn: np.ndarray = field(default_factory=lambda: np.zeros(3))
    _done: int = 0

    def __post_init__(self) -> None:
        self.jumps = sorted(self.jumps, key=lambda j: j.t_ns)

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> PoseSample | None:
        jumps = self.jumps
        while self._done < len(jumps) and jumps[self._done].t_ns <= t_ns:
            j = jumps[self._done]
            self._p_V_Vn = self._p_V_Vn + self._R_V_Vn.apply(j.offset_m)
            self._R_V_Vn = self._R_V_Vn * Rotation.from_euler("z", j.yaw_rad)
            self._done += 1
            self.reset_counter += 1
        pose = self.inner.sample(truth, t_ns, rng)
        if pose is None or self._done == 0:
            return pose
        R_V_B = Rotation.from_quat(pose.q_W_B_xyzw)
        return dataclasses.replace(
            pose,
            p_W_B=self._R_V_Vn.apply(pose.p_W_B - self._p_V_Vn, inverse=True),
            q_W_B_xyzw=(self._R_V_Vn.inv() * R_V_B).as_quat(),
            reset_counter=pose.reset_counter + self.reset_counter,
        )


# -- delivery faults (act on a measured sample) --------------------------------------------------
class DeliveryFault(Protocol):
    def deliver(self, sample: Any) -> list[tuple[Any, int]]:
        """The (sample, extra delay ns) pairs to queue in place of ``sample`` (none: refused)."""
        ...


def _take_due(times_ns: list[int], t_ns: int) -> bool:
    """Pops the first of the sorted ``times_ns`` once ``t_ns`` has reached it."""
    if times_ns and t_ns >= times_ns[0]:
        times_ns.pop(0)
        return True
    return False


@dataclass
class LateAt:
    """The first sample at or after each time arrives this much later than its delay."""

    late_ns: list[tuple[int, int]]

    def __post_init__(self) -> None:
        self.late_ns = sorted(self.late_ns)

    def deliver(self, sample: Any) -> list[tuple[Any, int]]:
        if self.late_ns and sample.t_ns >= self.late_ns[0][0]:
            return [(sample, self.late_ns.pop(0)[1])]
        return [(sample, 0)]


@dataclass
class RepeatAt:
    """The first sample at or after each time is delivered twice (the copy is out of order)."""

    times_ns: list[int]

    def __post_init__(self) -> None:
        self.times_ns = sorted(self.times_ns)

    def deliver(self, sample: Any) -> list[tuple[Any, int]]:
        if _take_due(self.times_ns, sample.t_ns):
            return [(sample, 0), (sample, 0)]
        return [(sample, 0)]


@dataclass
class CorruptAt:
    """The first sample at or after each time carries NaN in ``field_name[index]``. The reading
    is rebuilt through its message's constructor, as a driver would hand it over; the message
    refuses it and the refusal is counted in :attr:`rejected_invalid`."""

    times_ns: list[int]
    field_name: str
    index: int = 0
    rejected_invalid: int = 0

    def __post_init__(self) -> None:
        self.times_ns = sorted(self.times_ns)

    def deliver(self, sample: Any) -> list[tuple[Any, int]]:
        if not _take_due(self.times_ns, sample.t_ns):
            return [(sample, 0)]
        value = np.array(getattr(sample, self.field_name), dtype=np.float64)
        value.flat[self.index] = math.nan
        try:
            return [(dataclasses.replace(sample, **{self.field_name: value}), 0)]
        except SampleError:
            self.rejected_invalid += 1
            return []


# -- the channel ---------------------------------------------------------------------------------
@dataclass
class Channel:
    """One sensor stream of a closed loop: ``sensor`` (already wrapped by its sensor faults),
    then ``faults`` on each sample, then a delay line of ``delay_ns``; its own ``rng``.

    A loop of many steps may read two times first (plain attributes, cheaper than a call):
    :meth:`step` does nothing before ``idle_until_ns`` and :meth:`arrived` has nothing before
    ``next_arrival_ns``."""

    name: str
    sensor: Sensor[Any]
    rng: Generator
    delay_ns: int = 0
    faults: Sequence[DeliveryFault] = ()
    sampled_t_ns: list[int] = field(default_factory=list)
    _line: DelayLine[Any] = field(init=False)

    def __post_init__(self) -> None:
        if self.delay_ns < 0:
            raise SimError(f"channel {self.name!r}: the delay must be >= 0 ns, got {self.delay_ns}")
        self._line = DelayLine(delay_ns=self.delay_ns)
        self._idle: Callable[[int], int | None] | None = getattr(self.sensor, "idle_until_ns", None)
        #: Polls before this time do nothing (the sensor's ``idle_until_ns``).
        self.idle_until_ns = 0
        #: Nothing arrives before this time (the delay line's first arrival).
        self.next_arrival_ns = self._line.next_arrival_ns

    def step(self, truth: VehicleState, t_ns: int) -> None:
        """Read the sensor at ``t_ns``; what it measures goes through the faults into the line.
        Polls the sensor says would do nothing (its ``idle_until_ns``) are skipped."""
        if t_ns < self.idle_until_ns:
            return
        s = self.sensor.sample(truth, t_ns, self.rng)
        if self._idle is not None:
            self.idle_until_ns = self._idle(t_ns) or 0
        if s is None:
            return
        self.sampled_t_ns.append(s.t_ns)
        line = self._line
        if not self.faults:  # (most channels: the sample as it is)
            line.push(s)
        else:
            out: list[tuple[Any, int]] = [(s, 0)]
            for fault in self.faults:
                out = [(d, extra + more) for x, extra in out for d, more in fault.deliver(x)]
            for d, extra in out:
                line.push(d, extra_delay_ns=extra)
        self.next_arrival_ns = line.next_arrival_ns

    def arrived(self, t_ns: int) -> list[Sample]:
        """Samples that have arrived by ``t_ns``, in arrival order."""
        if t_ns < self.next_arrival_ns:  # (DelayLine.due, without its call)
            return []
        out = [s for _, s in self._line.pop_arrived(t_ns)]
        self.next_arrival_ns = self._line.next_arrival_ns
        return out

    @property
    def rejected_invalid(self) -> int:
        """Readings the channel's drivers refused (a message's own validation)."""
        return sum(getattr(f, "rejected_invalid", 0) for f in self.faults)
