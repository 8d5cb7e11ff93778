"""Sensor channels: due-time timing, fault decorators, delay lines."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.messages import HeightSample, ImuSample, VehicleState
from quadnav.sim.channels import Channel, CorruptAt, Dropouts, LateAt, OffsetTruth, RepeatAt
from quadnav.sim.sensors import (
    BaroSensor,
    GpsSensor,
    IntegratingImu,
    MagSensor,
    RangeFinder,
    Ticker,
    VisionPoseSensor,
)

STEP_NS = 2_000_000  # the main job's 2 ms simulator step


def _state(t_ns: int, z: float = 1.0) -> VehicleState:
    return VehicleState(
        t_ns=t_ns,
        p_W_B=np.array([0.0, 0.0, z]),
        v_W_B=np.zeros(3),
        a_W_B=np.zeros(3),
        q_W_B_xyzw=Rotation.identity().as_quat(),
        w_B=np.zeros(3),
    )


def _sensors() -> dict[str, tuple[object, float]]:
    def period(hz: float) -> int:
        return round(1e9 / hz)

    return {
        "vision 30 Hz": (VisionPoseSensor(period_ns=period(30), sigma_m=0.01, yaw_sigma_rad=0.01), 30.0),
        "baro 50 Hz": (BaroSensor(period_ns=period(50), sigma_m=0.1), 50.0),
        "baro 33 Hz": (BaroSensor(period_ns=period(33), sigma_m=0.1), 33.0),
        "gps 5 Hz": (GpsSensor(datum_lla=(47.0, 8.0, 400.0), period_ns=period(5), sigma_h_m=0.5,
                               sigma_v_m=0.8, sigma_vel_m_s=0.1), 5.0),
        "mag 50 Hz": (MagSensor(period_ns=period(50)), 50.0),
        "range 20 Hz": (RangeFinder(period_ns=period(20), sigma_m=0.02), 20.0),
        "range 70 Hz": (RangeFinder(period_ns=period(70), sigma_m=0.02), 70.0),
        "imu 250 Hz": (IntegratingImu(period_ns=period(250), gyro_sigma_rad_s=0.0, accel_sigma_m_s2=0.0), 250.0),
        "imu 300 Hz": (IntegratingImu(period_ns=period(300), gyro_sigma_rad_s=0.0, accel_sigma_m_s2=0.0), 300.0),
    }  # fmt: skip


@pytest.mark.parametrize("name", list(_sensors()))
def test_every_sensor_keeps_its_rate_on_2_ms_steps(name: str) -> None:
    """Due times accumulate: a "30 Hz" camera polled every 2 ms gives 30 samples a second (the
    old next = now + period gave 29.4: each sample slipped to the next step)."""
    sensor, rate_hz = _sensors()[name]
    rng = np.random.default_rng(0)
    n = 0
    for k in range(5000):  # 10 s
        t = k * STEP_NS
        n += sensor.sample(_state(t), t, rng) is not None  # type: ignore[attr-defined]
    assert abs(n - 10 * rate_hz) <= 1, (name, n)


def test_a_ticker_restarts_its_grid_after_a_gap_without_a_burst() -> None:
    tick = Ticker(10)
    assert [t for t in range(0, 50, 3) if tick.due(t)] == [0, 12, 21, 30, 42]
    # polled again after a long gap: one sample, then the period again
    assert [t for t in (1000, 1003, 1006, 1009, 1012) if tick.due(t)] == [1000, 1012]


def test_dropouts_read_nothing_inside_their_windows() -> None:
    calls: list[int] = []

    class Probe:
        def sample(self, truth: VehicleState, t_ns: int, rng: np.random.Generator) -> HeightSample:
            calls.append(t_ns)
            return HeightSample(t_ns=t_ns, z_m=1.0, sigma_m=0.1)

    d = Dropouts(Probe(), [(10, 20), (30, 31)])
    got = [t for t in range(0, 40, 5) if d.sample(_state(t), t, np.random.default_rng(0))]
    assert got == [0, 5, 20, 25, 35] and calls == got  # the sensor is not even read


def test_offset_truth_moves_what_the_sensor_sees_only_in_its_windows() -> None:
    baro = BaroSensor(period_ns=1, sigma_m=1e-9)
    glitch = OffsetTruth(baro, [(100, 200, (0.0, 0.0, 5.0))])
    rng = np.random.default_rng(0)
    z = [glitch.sample(_state(t, z=1.0), t, rng) for t in (50, 150, 250)]
    assert [round(s.z_m, 6) for s in z if s is not None] == [1.0, 6.0, 1.0]


def _baro_channel(**kw: object) -> Channel:
    return Channel("baro", BaroSensor(period_ns=10, sigma_m=0.1), np.random.default_rng(0), **kw)  # type: ignore[arg-type]


def test_a_channel_delivers_after_its_delay_and_a_late_sample_later() -> None:
    ch = _baro_channel(delay_ns=25, faults=(LateAt([(20, 100)]),))
    arrivals: dict[int, list[int]] = {}
    for t in range(0, 200, 5):
        ch.step(_state(t), t)
        for s in ch.arrived(t):
            arrivals.setdefault(s.t_ns, []).append(t)
    assert arrivals[0] == [25] and arrivals[10] == [35]
    assert arrivals[20] == [145]  # 25 ns of delay + 100 ns late
    assert arrivals[30] == [55]  # only the first sample at or after 20 was late
    assert ch.sampled_t_ns[:4] == [0, 10, 20, 30]


def test_repeat_delivers_twice_and_corrupt_is_refused_and_counted() -> None:
    imu = IntegratingImu(period_ns=4, gyro_sigma_rad_s=0.0, accel_sigma_m_s2=0.0)
    corrupt = CorruptAt([8, 16], "gyro_rad_s", index=1)
    ch = Channel("imu", imu, np.random.default_rng(0), faults=(RepeatAt([12]), corrupt))
    out: list[ImuSample] = []
    for t in range(0, 25, 2):
        ch.step(_state(t), t)
        out.extend(ch.arrived(t))  # type: ignore[arg-type]
    times = [s.t_ns for s in out]
    assert times == [4, 12, 12, 20, 24]  # 8 and 16 refused, 12 twice
    assert corrupt.rejected_invalid == 2 and ch.rejected_invalid == 2


class _Hidden:
    """The same sensor with its idle hint hidden (polled every step), counting its polls."""

    def __init__(self, inner: object) -> None:
        self.inner, self.polls = inner, 0

    def sample(self, truth: VehicleState, t_ns: int, rng: np.random.Generator) -> object:
        self.polls += 1
        return self.inner.sample(truth, t_ns, rng)  # type: ignore[attr-defined]


@pytest.mark.parametrize("name", [n for n in _sensors() if not n.startswith("imu")])
def test_a_channel_skips_the_polls_its_sensor_would_ignore_and_delivers_the_same(
    name: str,
) -> None:
    """Stepped every 2 ms for 6 s, with dropouts: a channel that skips the polls the sensor
    says it would ignore gives the same samples, at the same times, as one polling every
    step; it polls about as often as the sensor samples (and not at all in a dropout)."""
    windows = [(1_000_000_000, 1_500_000_000), (3_002_000_000, 3_003_000_000)]
    skipping = Dropouts(_sensors()[name][0], windows)  # type: ignore[arg-type]
    counted = _Hidden(skipping)
    every = _Hidden(Dropouts(_sensors()[name][0], windows))  # type: ignore[arg-type]
    a = Channel("a", counted, np.random.default_rng(1))  # type: ignore[arg-type]
    a._idle = skipping.idle_until_ns  # the hint, with the polls still counted
    b = Channel("b", every, np.random.default_rng(1))  # type: ignore[arg-type]
    got: dict[str, list[object]] = {"a": [], "b": []}
    for k in range(3000):
        t = k * STEP_NS
        for ch in (a, b):
            ch.step(_state(t, z=1.0 + 1e-3 * k), t)
            got[ch.name] += ch.arrived(t)
    assert a.sampled_t_ns == b.sampled_t_ns and len(a.sampled_t_ns) > 5
    assert not [t for t in a.sampled_t_ns if any(s <= t < e for s, e in windows)]
    fields = [[getattr(x, f.name) for f in dataclasses.fields(x)] for x in got["a"]]  # type: ignore[arg-type]
    np.testing.assert_equal(  # (the same values: the same draws in the same order)
        fields,
        [[getattr(x, f.name) for f in dataclasses.fields(x)] for x in got["b"]],  # type: ignore[arg-type]
    )
    assert every.polls == 3000 and counted.polls <= len(a.sampled_t_ns) + 3
