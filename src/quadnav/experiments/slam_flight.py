"""Thesis 002's position loop in simulation (sections 5.7-5.10): a companion computer sends the
position to the flight controller as ``X<cm>Y<cm>Z<cm>F`` frames at about 10 Hz over a UART,
and the flight controller differentiates it (Euler, step 0.1 s) for its PD or nested-saturation
laws. Here the UART is a pseudo-terminal pair (:class:`~quadnav.io.serial_frame.PtyLink`), the
frames go through :class:`~quadnav.io.serial_frame.FrameSender` and
:class:`~quadnav.io.serial_frame.FrameReceiver`, and the position sent is

* ``slam``: the stereo SLAM's (:class:`~quadnav.slam.odometry.SlamOdometry`) on the rig's
  images rendered in a 3-D world as the vehicle flies (the camera plumbing of
  :class:`~quadnav.experiments.vio_flight.VioCameraSensor`), moved from the SLAM's world (the
  vehicle at its first frame, taken at the start) into the flight's by the take-off pose the
  companion knows (the configured initial pose);
* ``serial_truth``: the true position at the frame rate (the link's own share of the error:
  10 Hz, whole centimetres, the Euler velocity).

Attitude and body rate stay the flight controller's own (the true ones: its attitude estimator
is not modelled). Line noise (``garbage_per_frame`` random bytes before each frame) is counted
by the decoder and never stops the loop. Without a new frame for ``lost_after_s`` (a SLAM
loss, a frame lost to noise) the last position is held, the velocity is zero, and the time is
counted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from quadnav.config_model import ConfigModel
from quadnav.geometry.rotations import Pose
from quadnav.io.serial_frame import FrameReceiver, FrameSender, PtyLink
from quadnav.messages import StateEstimate, VehicleState
from quadnav.sim.sensors import Ticker
from quadnav.units import ns_to_s, s_to_ns

if TYPE_CHECKING:  # (OpenCV, the renderer and the SLAM only when flying on images)
    from quadnav.experiments.vio_flight import VioCameraSensor

__all__ = ["SerialLinkSection", "SerialPositionLoop", "SerialRecord"]

FloatArray = NDArray[np.float64]


class SerialLinkSection(ConfigModel):
    """The companion computer and its serial link (``position_source`` ``slam`` or
    ``serial_truth``)."""

    rig: Literal["zed"] = Field("zed", description="the stereo rig on the vehicle (thesis 002's)")
    world: Literal["room", "hall"] = Field("room", description="the 3-D world it is rendered in")
    camera_rate_hz: float = Field(
        10.0, gt=0, le=60.0, description="stereo pairs into the SLAM per second"
    )
    frame_rate_hz: float = Field(10.0, gt=0, le=100.0, description="frames sent per second")
    image_noise: float = Field(2.0, ge=0, le=50.0, description="read noise, grey levels")
    garbage_per_frame: float = Field(
        0.0, ge=0, le=100.0, description="mean random bytes of line noise before each frame"
    )
    lost_after_s: float = Field(
        0.5, gt=0, le=10.0, description="no frame for this long: position held, velocity zero"
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class SerialRecord:
    """What went over the link in one flight: each frame's time, the position sent (the
    flight's world) and the true one then; the link's counts; the SLAM's frames, states and
    events (``slam`` source)."""

    source: str
    t_s: FloatArray
    p_sent: FloatArray
    p_true: FloatArray
    counts: dict[str, float] = field(default_factory=dict)
    events: tuple[tuple[float, str], ...] = ()

    def metrics(self) -> dict[str, object]:
        """The position sent against the truth (RMS and largest error), and the counts."""
        err = np.linalg.norm(self.p_sent - self.p_true, axis=1)
        rms = float(np.sqrt(np.mean(err**2))) if len(err) else math.nan
        return {
            "position_source": self.source,
            "sent_position_rmse_m": rms,
            "sent_position_max_error_m": float(err.max()) if len(err) else math.nan,
            **self.counts,
            "events": [f"{t:.2f} s {text}" for t, text in self.events],
        }


class SerialPositionLoop:
    """The companion computer, the pseudo-terminal link and the flight controller's decoder:
    :meth:`estimate` turns the true state into the flight controller's (position and velocity
    from the frames, attitude and rate its own); :meth:`close` ends the link and the record."""

    def __init__(
        self,
        section: SerialLinkSection,
        source: Literal["serial_truth", "slam"],
        *,
        start: Pose,
        path_W: FloatArray,
        seed: int,
    ) -> None:
        self.section, self.source, self.start = section, source, start
        self._rng = np.random.default_rng(seed)
        self.link = PtyLink()
        self.sender = FrameSender(self._send, rate_hz=section.frame_rate_hz)
        self.receiver = FrameReceiver()
        self._lost_ns = s_to_ns(section.lost_after_s)
        self._last_rx_ns = 0
        self._held_ns = 0
        self._t_prev: int | None = None
        self._rows: list[tuple[int, FloatArray, FloatArray]] = []
        self.sensor: VioCameraSensor | None = None
        self._ticker = Ticker(s_to_ns(1.0 / section.frame_rate_hz), first_ns=0)
        if source == "slam":
            self.sensor = _slam_sensor(section, path_W, seed)

    def _send(self, frame: bytes) -> None:
        n = int(self._rng.poisson(self.section.garbage_per_frame))
        if n:
            self.link.write(self._rng.integers(0, 256, n, dtype=np.uint8).tobytes())
        self.link.write(frame)

    def _companion(self, truth: VehicleState) -> FloatArray | None:
        """The position the companion computer has at this step (the flight's world), if any."""
        if self.sensor is None:
            return truth.p_W_B if self._ticker.due(truth.t_ns) else None
        odo = self.sensor.sample(truth, truth.t_ns, self._rng)
        return None if odo is None else self.start @ np.array(odo.p_W_B)  # (scipy: no read-only)

    def estimate(self, est: StateEstimate, truth: VehicleState) -> StateEstimate:
        """The flight controller's estimate from the perfect one ``est`` and the ``truth``
        the companion's camera sees."""
        t = est.t_ns
        p = self._companion(truth)
        if p is not None and self.sender.offer(t, p) is not None:
            self._rows.append((t, np.asarray(p, dtype=np.float64), est.p_W_B.copy()))
        if self.receiver.feed(self.link.read()):
            self._last_rx_ns = t
        rx = self.receiver
        pos = self.start.p_A_B if rx.position_m is None else np.array(rx.position_m)
        vel = np.array(rx.velocity_m_s)
        if t - self._last_rx_ns > self._lost_ns:
            vel = np.zeros(3)
            if self._t_prev is not None:
                self._held_ns += t - self._t_prev
        self._t_prev = t
        x = est.x.copy()
        x[0:3], x[6:9] = pos, vel
        return replace(est, p_W_B=pos, v_W_B=vel, x=x)

    def close(self) -> SerialRecord:
        self.receiver.feed(self.link.read())
        self.link.close()
        d = self.receiver.decoder
        counts: dict[str, float] = {
            "frames_sent": self.sender.sent,
            "frames_received": d.frames,
            "frames_dropped": d.dropped,
            "garbage_bytes": d.garbage_bytes,
            "unsendable_positions": self.sender.unsendable,
            "position_held_s": ns_to_s(self._held_ns),
        }
        events: tuple[tuple[float, str], ...] = ()
        if self.sensor is not None:
            rec = self.sensor.record()
            counts |= {"slam_frames": rec.frames, "slam_states": rec.states,
                       **{f"slam_{k}_ms": v for k, v in rec.stage_ms.items()}}  # fmt: skip
            events = tuple((ns_to_s(t), text) for t, text in rec.events)
        rows = self._rows
        return SerialRecord(
            source=self.source,
            t_s=np.array([ns_to_s(r[0]) for r in rows]),
            p_sent=np.array([r[1] for r in rows]).reshape(-1, 3),
            p_true=np.array([r[2] for r in rows]).reshape(-1, 3),
            counts=counts,
            events=events,
        )


def _slam_sensor(section: SerialLinkSection, path_W: FloatArray, seed: int) -> VioCameraSensor:
    """The stereo rig rendered in the world around the path, into the SLAM."""
    from quadnav.experiments.vio_flight import VioCameraSensor, world_around
    from quadnav.rig import rig_named
    from quadnav.sim.render import RenderEffects, Renderer
    from quadnav.slam.odometry import SlamOdometry

    rig = rig_named(section.rig)
    return VioCameraSensor(
        rig=rig,
        vio=SlamOdometry(rig),
        renderer=Renderer(world_around(path_W, section.world, seed), rig.cameras[0].camera),
        imu=None,
        image_rng=np.random.default_rng(seed + 1),
        effects=RenderEffects(read_noise_sigma=section.image_noise),
        rate_hz=section.camera_rate_hz,
        first_ns=0,  # (the SLAM's world is the vehicle at its first frame: the take-off pose)
    )
