"""Thesis 002's serial frame: the companion computer sends the position to the flight
controller as ASCII ``X<x cm>Y<y cm>Z<z cm>F`` over a UART at 115200 8N1.

:func:`encode` writes a frame; :class:`FrameDecoder` reads a byte stream of them, robust to
garbage, partial frames, missing fields, overlong numbers and line noise: a frame is output
only when its bytes arrive complete and well formed, anything else is dropped and counted.
The protocol has no checksum, so a noise burst that happens to spell a well-formed frame
cannot be told from one; everything else is. :class:`VelocityEstimator` differentiates the
positions: the thesis's Euler difference and a low-pass filtered derivative.

The two ends of the thesis's link: :class:`FrameSender` (the companion computer: positions in as
they are estimated, a frame out at most at its rate, 10 Hz in the thesis) and
:class:`FrameReceiver` (the flight controller: bytes in, the newest position and its Euler
velocity of step 0.1 s). :class:`PtyLink` is a pseudo-terminal pair standing for the UART cable.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import IoError
from quadnav.units import s_to_ns

__all__ = [
    "DecodedFrame",
    "FrameDecoder",
    "FrameReceiver",
    "FrameSender",
    "PtyLink",
    "VelocityEstimator",
    "encode",
]

MAX_DIGITS = 6  # +-9999.99 m: anything longer is line noise


def encode(x_m: float, y_m: float, z_m: float) -> bytes:
    """A frame for a position in metres (rounded to whole centimetres, as the thesis sends)."""
    vals = []
    for v in (x_m, y_m, z_m):
        if not math.isfinite(v):
            raise IoError(f"serial frame: cannot send a non-finite position {v}")
        cm = round(v * 100.0)
        if abs(cm) >= 10**MAX_DIGITS:
            raise IoError(f"serial frame: {v} m does not fit in {MAX_DIGITS} digits of centimetres")
        vals.append(cm)
    return f"X{vals[0]}Y{vals[1]}Z{vals[2]}F".encode("ascii")


@dataclass(frozen=True, slots=True)
class DecodedFrame:
    x_cm: int
    y_cm: int
    z_cm: int

    @property
    def position_m(self) -> tuple[float, float, float]:
        return (self.x_cm / 100.0, self.y_cm / 100.0, self.z_cm / 100.0)


@dataclass
class FrameDecoder:
    """Feed bytes as they arrive; get the complete frames. Counters say what was dropped."""

    frames: int = 0
    dropped: int = 0  # started frames that were not completed well formed
    garbage_bytes: int = 0  # bytes outside any frame
    _field: int = -1  # -1: waiting for X; 0, 1, 2: reading x, y, z
    _digits: bytearray = field(default_factory=bytearray)
    _values: list[int] = field(default_factory=list)

    _NEXT = (ord("Y"), ord("Z"), ord("F"))

    def _abort(self) -> None:
        self.dropped += 1
        self._field = -1
        self._digits.clear()
        self._values.clear()

    def feed(self, data: bytes) -> list[DecodedFrame]:
        out: list[DecodedFrame] = []
        for b in data:
            if b == 0x58:  # "X": a frame starts, whatever was pending is dropped
                if self._field >= 0:
                    self._abort()
                self._field = 0
                self._digits.clear()
                self._values.clear()
                continue
            if self._field < 0:
                self.garbage_bytes += 1
                continue
            if 0x30 <= b <= 0x39 or (b == 0x2D and not self._digits):  # a digit, or a leading "-"
                self._digits.append(b)
                if len(self._digits) > MAX_DIGITS + 1 or (
                    len(self._digits) > MAX_DIGITS and self._digits[0] != 0x2D
                ):
                    self._abort()  # overlong number
                continue
            if b == self._NEXT[self._field] and self._digits and self._digits != b"-":
                self._values.append(int(self._digits.decode("ascii")))
                self._digits.clear()
                self._field += 1
                if self._field == 3:
                    out.append(DecodedFrame(*self._values))
                    self.frames += 1
                    self._field = -1
                    self._values.clear()
                continue
            self._abort()  # anything else inside a frame: a missing field, noise
            self.garbage_bytes += 1
        return out


@dataclass
class VelocityEstimator:
    """Velocity from consecutive positions: ``euler`` is the thesis's (x_k - x_{k-1}) / dt (dt
    0.1 s there); ``filtered`` passes it through a first-order low-pass of time constant
    ``tau_s``. Timestamps, when given, replace the nominal ``dt_s``."""

    dt_s: float = 0.1
    tau_s: float = 0.2
    _last: tuple[float, float, float] | None = None
    _last_t: float | None = None
    filtered: tuple[float, float, float] = (0.0, 0.0, 0.0)
    euler: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def update(
        self, p: tuple[float, float, float], t_s: float | None = None
    ) -> tuple[float, float, float]:
        if self._last is not None:
            dt = self.dt_s if t_s is None or self._last_t is None else t_s - self._last_t
            if dt > 0:
                self.euler = tuple((a - b) / dt for a, b in zip(p, self._last, strict=True))  # type: ignore[assignment]
                alpha = dt / (self.tau_s + dt)
                self.filtered = tuple(
                    f + alpha * (e - f) for f, e in zip(self.filtered, self.euler, strict=True)
                )  # type: ignore[assignment]
        self._last, self._last_t = p, t_s
        return self.filtered


@dataclass
class FrameSender:
    """The companion computer's end: :meth:`offer` a position (metres) whenever one is
    estimated; a frame is written to ``write`` when the next due time of a ``rate_hz`` grid has
    come (a tenth of a period early is on time: a 10 Hz estimate with jitter is sent whole). A
    position a frame cannot carry (non-finite, too large) is not sent and is counted."""

    write: Callable[[bytes], object]
    rate_hz: float = 10.0
    sent: int = 0
    unsendable: int = 0
    _next_ns: int | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise IoError(
                f"serial frame: the send rate must be a finite number > 0, got {self.rate_hz}"
            )

    def offer(self, t_ns: int, p_m: Sequence[float] | NDArray[np.float64]) -> bytes | None:
        """The frame written for the position ``p_m`` at ``t_ns``, or None (not due, or
        unsendable)."""
        period = s_to_ns(1.0 / self.rate_hz)
        nxt = self._next_ns
        if nxt is not None and t_ns < nxt - period // 10:
            return None
        try:
            frame = encode(*(float(v) for v in p_m))
        except IoError:
            self.unsendable += 1
            return None
        self.write(frame)
        self.sent += 1
        # due times on a grid (k periods from the first frame), started afresh after a gap
        self._next_ns = (t_ns if nxt is None or t_ns - nxt >= period else nxt) + period
        return frame


@dataclass
class FrameReceiver:
    """The flight controller's end: :meth:`feed` the bytes read from the link; the newest
    position (metres) and the thesis's Euler velocity ``(x_k - x_(k-1)) / dt_s`` over the frames
    as they come (nominal step, as the thesis differentiates). Garbage is the decoder's to count."""

    dt_s: float = 0.1
    decoder: FrameDecoder = field(default_factory=FrameDecoder)
    position_m: tuple[float, float, float] | None = None
    velocity_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        self._velocity = VelocityEstimator(dt_s=self.dt_s)

    def feed(self, data: bytes) -> int:
        """The number of complete frames in ``data`` (with what came before)."""
        frames = self.decoder.feed(data)
        for f in frames:
            self.position_m = f.position_m
            self._velocity.update(f.position_m)
            self.velocity_m_s = self._velocity.euler
        return len(frames)


class PtyLink:
    """A pseudo-terminal pair as the serial cable between a companion computer and a flight
    controller: :meth:`write` goes in at the terminal end (raw: no echo, no line editing), and
    :meth:`read` takes what has arrived at the other end without waiting. :meth:`close` both."""

    def __init__(self) -> None:
        import tty

        self._reader, self._writer = os.openpty()
        for fd in (self._reader, self._writer):
            tty.setraw(fd)
        os.set_blocking(self._reader, False)
        self.port = os.ttyname(self._writer)

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(self._writer, view) :]

    def read(self) -> bytes:
        chunks = []
        while True:
            try:
                chunk = os.read(self._reader, 4096)
            except BlockingIOError:
                break
            if not chunk:
                break
            chunks.append(chunk)
        return b"".join(chunks)

    def close(self) -> None:
        for fd in (self._reader, self._writer):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> PtyLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
