"""The sensor channels of the main job's flight, as a registry.

Each :class:`ChannelEntry` builds one channel from the scenario (or nothing when its section
is disabled): the sensor model, wrapped by the fault decorators the scenario asks for, its delay
and its own random stream. The loop (:func:`quadnav.experiments.nav.run_nav`) iterates over
what :func:`build_channels` returns; adding a sensor is one entry here.

Streams: each channel draws from its own child of ``SeedSequence(seed)``, keyed by the channel's
name (the child ``SeedSequence.spawn`` would make, with a spawn key from the name rather than a
position), so enabling the range finder, or registering a new sensor, leaves the vision noise of
the same seed as it was. The IMU's turn-on biases have a child of their own.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.random import Generator

from quadnav.experiments.nav_config import RANGE_MIN_M, NavScenario
from quadnav.experiments.vio_flight import OdometrySink, build_vio_sensor
from quadnav.messages import TruthSample, VehicleState, VelocitySample
from quadnav.sim.channels import (
    Channel,
    CorruptAt,
    DeliveryFault,
    Dropouts,
    FrameJump,
    FrameJumps,
    LateAt,
    OffsetTruth,
    RepeatAt,
)
from quadnav.sim.flow import FlowSensor
from quadnav.sim.sensors import (
    BaroSensor,
    GpsSensor,
    IntegratingImu,
    MagSensor,
    RangeFinder,
    Sensor,
    Ticker,
    VisionPoseSensor,
)
from quadnav.units import s_to_ns

__all__ = [
    "CHANNELS",
    "CHANNEL_BY_NAME",
    "ChannelEntry",
    "FlightPhase",
    "build_channels",
    "imu_sensor",
    "is_pseudo_source",
]


@dataclass
class FlightPhase:
    """What the loop knows about the flight that is not a measurement: whether the motors are
    off on the ground (the zero-velocity pseudo-measurement reads it)."""

    motors_off: bool = True


@dataclass(frozen=True, slots=True)
class BuildContext:
    seed: int
    phase: FlightPhase
    gravity_m_s2: float
    bias_rng: Generator
    odometry_sink: OdometrySink | None = None  # where the VIO's odometry also goes (MAVLink)


Builder = Callable[[NavScenario, BuildContext, Generator], Channel | None]


@dataclass(frozen=True, slots=True)
class ChannelEntry:
    name: str
    build: Builder
    description: str
    #: A pseudo-measurement (of the flight phase, not of the world): no NIS statistics.
    pseudo: bool = False


def _windows(spans_s: list[tuple[float, float]]) -> list[tuple[int, int]]:
    return [(s_to_ns(a), s_to_ns(b)) for a, b in spans_s]


def _vision(sc: NavScenario, ctx: BuildContext, rng: Generator) -> Channel | None:
    vs = sc.vision
    if not vs.enabled:
        return None
    period = s_to_ns(1.0 / vs.rate_hz)
    sensor: Sensor[Any]
    if vs.source == "camera":
        # (the marker camera renders and detects with OpenCV: loaded only for a camera)
        from quadnav.experiments.marker_camera import MarkerCameraSensor, marker_field, thesis_mount

        field = marker_field(
            vs.marker_grid, vs.marker_spacing_m, vs.marker_length_m, vs.marker_origin_m
        )
        seed = int(rng.integers(2**31))  # the image noise draws from its own generator
        sensor = MarkerCameraSensor(
            period_ns=period,
            markers=field,
            T_B_C=thesis_mount(),
            noise_sigma=vs.image_noise,
            min_sigma_m=vs.min_sigma_m,
            seed=seed,
        )
    else:
        sensor = VisionPoseSensor(
            period_ns=period,
            sigma_m=vs.sigma_m,
            yaw_sigma_rad=vs.yaw_sigma_rad,
            frame_yaw_rad=math.radians(vs.frame_yaw_deg),
            frame_offset_m=vs.frame_offset_m,
        )
        if vs.jumps:
            jumps = [
                FrameJump(s_to_ns(t), math.radians(y), (dx, dy, dz))
                for t, y, dx, dy, dz in vs.jumps
            ]
            sensor = FrameJumps(sensor, jumps)
    if vs.dropouts_s:
        sensor = Dropouts(sensor, _windows(vs.dropouts_s))
    late = [(s_to_ns(t), s_to_ns(d)) for t, d in sc.faults.vision_late_s]
    faults: tuple[DeliveryFault, ...] = (LateAt(late),) if late else ()
    return Channel("vision", sensor, rng, delay_ns=s_to_ns(vs.delay_s), faults=faults)


def _vio(sc: NavScenario, ctx: BuildContext, rng: Generator) -> Channel | None:
    if not sc.vio.enabled:
        return None
    bias_rng = channel_rng(ctx.seed, "vio_turn_on_bias")
    sensor = build_vio_sensor(sc, rng, bias_rng, ctx.gravity_m_s2, ctx.odometry_sink)
    return Channel("vio", sensor, rng, delay_ns=s_to_ns(sc.vio.delay_s))


def _baro(sc: NavScenario, ctx: BuildContext, rng: Generator) -> Channel | None:
    b = sc.baro
    if not b.enabled:
        return None
    sensor = BaroSensor(
        period_ns=s_to_ns(1.0 / b.rate_hz), sigma_m=b.sigma_m, drift_m_sqrt_s=b.drift_m_sqrt_s
    )
    return Channel("baro", sensor, rng, delay_ns=s_to_ns(b.delay_s))


def _gps(sc: NavScenario, ctx: BuildContext, rng: Generator) -> Channel | None:
    g = sc.gps
    if not g.enabled:
        return None
    sensor: Sensor[Any] = GpsSensor(
        datum_lla=g.datum_lla,
        period_ns=s_to_ns(1.0 / g.rate_hz),
        sigma_h_m=g.sigma_h_m,
        sigma_v_m=g.sigma_v_m,
        sigma_vel_m_s=g.sigma_vel_m_s,
    )
    glitches = [(s_to_ns(a), s_to_ns(b), (e, n, 0.0)) for a, b, e, n in sc.faults.gps_glitch]
    if glitches:
        sensor = OffsetTruth(sensor, glitches)
    if g.outages_s:
        sensor = Dropouts(sensor, _windows(g.outages_s))
    return Channel("gps", sensor, rng, delay_ns=s_to_ns(g.delay_s))


def _range(sc: NavScenario, ctx: BuildContext, rng: Generator) -> Channel | None:
    r = sc.range
    if not r.enabled:
        return None
    sensor = RangeFinder(
        period_ns=s_to_ns(1.0 / r.rate_hz), sigma_m=r.sigma_m, min_m=RANGE_MIN_M, max_m=r.max_m
    )
    return Channel("range", sensor, rng, delay_ns=s_to_ns(r.delay_s))


def _mag(sc: NavScenario, ctx: BuildContext, rng: Generator) -> Channel | None:
    m = sc.mag
    if not m.enabled:
        return None
    sensor = MagSensor(
        period_ns=s_to_ns(1.0 / m.rate_hz),
        declination_rad=m.declination_rad,
        noise_sigma=m.noise_sigma,
        sigma_heading_rad=m.sigma_heading_rad,
    )
    return Channel("mag", sensor, rng)


def _flow(sc: NavScenario, ctx: BuildContext, rng: Generator) -> Channel | None:
    f = sc.flow
    if not f.enabled:
        return None
    sensor = FlowSensor(
        rate_hz=f.rate_hz,
        flow_sigma_rad_s=f.flow_sigma_rad_s,
        gyro_sigma_rad_s=f.gyro_sigma_rad_s,
        min_height_m=f.min_height_m,
        max_height_m=f.max_height_m,
    )
    return Channel("flow", sensor, rng, delay_ns=s_to_ns(f.delay_s))


@dataclass
class ZeroVelocityAtRest:
    """PX4's zero-velocity update at rest: "standing still" at ``rate_hz`` while the motors are
    off on the ground (a pseudo-measurement of the flight phase, not of the truth)."""

    phase: FlightPhase
    period_ns: int
    sigma_m_s: float = 0.02

    def __post_init__(self) -> None:
        self._ticker = Ticker(self.period_ns)

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> VelocitySample | None:
        del truth, rng
        if not self.phase.motors_off or not self._ticker.due(t_ns):
            return None
        return VelocitySample(t_ns=t_ns, v_W_B=np.zeros(3), sigma_m_s=self.sigma_m_s)


def _zero_velocity(sc: NavScenario, ctx: BuildContext, rng: Generator) -> Channel | None:
    if not sc.estimator.zero_velocity_on_ground or sc.estimator.kind != "ekf":
        return None
    return Channel("landed", ZeroVelocityAtRest(ctx.phase, period_ns=40_000_000), rng)


@dataclass
class TruthSensor:
    """The true state at every step (for ``estimator.kind=truth``)."""

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> TruthSample:
        del rng
        return TruthSample(t_ns=t_ns, state=truth)


def _truth(sc: NavScenario, ctx: BuildContext, rng: Generator) -> Channel | None:
    return Channel("truth", TruthSensor(), rng) if sc.estimator.kind == "truth" else None


def imu_sensor(sc: NavScenario, gravity_m_s2: float, bias_rng: Generator) -> IntegratingImu:
    """The IMU of the scenario, with its turn-on biases drawn from ``bias_rng``."""
    ic = sc.imu
    return IntegratingImu(
        period_ns=s_to_ns(1.0 / ic.rate_hz),
        gyro_sigma_rad_s=ic.gyro_sigma_rad_s,
        accel_sigma_m_s2=ic.accel_sigma_m_s2,
        gyro_bias_rw_rad_s_sqrt_s=ic.gyro_bias_rw_rad_s_sqrt_s,
        accel_bias_rw_m_s2_sqrt_s=ic.accel_bias_rw_m_s2_sqrt_s,
        gyro_bias0_rad_s=tuple(ic.gyro_bias0_sigma_rad_s * bias_rng.standard_normal(3)),
        accel_bias0_m_s2=tuple(ic.accel_bias0_sigma_m_s2 * bias_rng.standard_normal(3)),
        gravity_m_s2=gravity_m_s2,
        lever_arm_m=ic.lever_arm_m,
    )


def _imu(sc: NavScenario, ctx: BuildContext, rng: Generator) -> Channel:
    f = sc.faults
    faults: list[DeliveryFault] = []
    if f.imu_nan_s:
        # A corrupted reading from the driver: refused at the boundary and counted.
        faults.append(CorruptAt([s_to_ns(t) for t in f.imu_nan_s], "gyro_rad_s", index=1))
    if f.imu_repeat_s:
        faults.append(RepeatAt([s_to_ns(t) for t in f.imu_repeat_s]))
    return Channel("imu", imu_sensor(sc, ctx.gravity_m_s2, ctx.bias_rng), rng, faults=faults)


#: Every channel the main job knows, in delivery order within a step (the IMU last: it moves
#: the estimator's clock on once the step's observations are in).
CHANNELS: tuple[ChannelEntry, ...] = (
    ChannelEntry("vision", _vision, "external pose: marker camera or the pose shortcut"),
    ChannelEntry("vio", _vio, "external odometry: a VIO on rendered images, or its shortcut"),
    ChannelEntry("baro", _baro, "barometric height with a drifting offset"),
    ChannelEntry("gps", _gps, "GNSS fixes and velocity"),
    ChannelEntry("range", _range, "downward range finder"),
    ChannelEntry("mag", _mag, "magnetometer heading"),
    ChannelEntry("flow", _flow, "downward optical flow (PX4FLOW class)"),
    ChannelEntry("landed", _zero_velocity, "zero velocity while the motors are off", pseudo=True),
    ChannelEntry("truth", _truth, "the true state, for estimator.kind=truth"),
    ChannelEntry("imu", _imu, "the IMU, integrated over its period"),
)


CHANNEL_BY_NAME: dict[str, ChannelEntry] = {e.name: e for e in CHANNELS}


def is_pseudo_source(source: str) -> bool:
    """Whether a fusion source is a registered pseudo-measurement (standing still)."""
    entry = CHANNEL_BY_NAME.get(source)
    return entry is not None and entry.pseudo


def build_channels(
    sc: NavScenario,
    seed: int,
    phase: FlightPhase,
    *,
    gravity_m_s2: float,
    odometry_sink: OdometrySink | None = None,
) -> list[Channel]:
    """The scenario's enabled channels, each with its own random stream."""
    bias_rng = channel_rng(seed, "imu_turn_on_bias")
    ctx = BuildContext(seed, phase, gravity_m_s2, bias_rng, odometry_sink)
    out = []
    for entry in CHANNELS:
        ch = entry.build(sc, ctx, channel_rng(seed, entry.name))
        if ch is not None:
            out.append(ch)
    return out


def channel_rng(seed: int, name: str) -> Generator:
    """The generator of one channel: the child of ``SeedSequence(seed)`` keyed by its name."""
    key = zlib.crc32(name.encode())
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(key,)))
