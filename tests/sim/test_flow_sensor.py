"""The optical-flow message and the PX4FLOW-class sensor model."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import SampleError, SimError
from quadnav.estimation.flow_model import predict_flow
from quadnav.messages import FlowSample, VehicleState
from quadnav.sim.flow import FLOW_DELAY_S, FlowSensor, line_of_sight_rate

GOOD = {"t_ns": 10_000_000, "integration_ns": 20_000_000, "flow_rad": [0.01, -0.02],
        "gyro_rad": [0.001, 0.002, 0.003], "quality": 200, "distance_m": 1.5}  # fmt: skip


def test_a_flow_sample_carries_rates_over_its_interval() -> None:
    s = FlowSample(**GOOD)
    np.testing.assert_allclose(s.flow_rate_rad_s, [0.5, -1.0])
    np.testing.assert_allclose(s.gyro_rate_rad_s, [0.05, 0.1, 0.15])
    assert s.source == "flow" and s.quality == 200
    assert FlowSample(**{**GOOD, "distance_m": None}).distance_m is None
    with pytest.raises(AttributeError):
        s.quality = 3  # type: ignore[misc]


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("flow_rad", [0.1, float("nan")], "FlowSample.flow_rad holds a non-finite"),
        ("flow_rad", [0.1, 0.2, 0.3], r"FlowSample.flow_rad must have shape \(2,\)"),
        ("gyro_rad", [0.1, 0.2], r"FlowSample.gyro_rad must have shape \(3,\)"),
        ("quality", 256, "FlowSample.quality must be an integer in 0..255"),
        ("quality", -1, "FlowSample.quality must be an integer in 0..255"),
        ("quality", 3.5, "FlowSample.quality must be an integer in 0..255"),
        ("quality", True, "FlowSample.quality must be an integer in 0..255"),
        ("integration_ns", 0, "FlowSample.integration_ns must be an integer number of ns > 0"),
        ("integration_ns", 0.02, "FlowSample.integration_ns must be an integer number of ns"),
        ("distance_m", -0.5, "FlowSample.distance_m must be finite and >= 0"),
        ("distance_m", float("inf"), "FlowSample.distance_m must be finite and >= 0"),
        ("t_ns", 1.5, "FlowSample.t_ns must be an integer number of nanoseconds"),
    ],
)
def test_bad_flow_samples_are_refused_in_one_line(key: str, value: object, message: str) -> None:
    with pytest.raises(SampleError, match=message) as info:
        FlowSample(**{**GOOD, key: value})
    assert "\n" not in str(info.value)


def truth(
    t_ns: int, *, z: float = 2.0, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0), R=None
) -> VehicleState:
    q = Rotation.identity().as_quat() if R is None else Rotation.from_matrix(R).as_quat()
    return VehicleState(t_ns=t_ns, p_W_B=[0.0, 0.0, z], v_W_B=list(v), a_W_B=[0.0, 0.0, 0.0],
                        q_W_B_xyzw=q, w_B=list(w))  # fmt: skip


def run(sensor: FlowSensor, seconds: float, step_ns: int = 2_000_000, seed: int = 0, **kw):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(round(seconds * 1e9 / step_ns) + 1):
        s = sensor.sample(truth(k * step_ns, **kw), k * step_ns, rng)
        if s is not None:
            out.append(s)
    return out


def quiet(**kw) -> FlowSensor:
    return FlowSensor(flow_sigma_rad_s=0.0, gyro_sigma_rad_s=0.0, distance_sigma_m=0.0, **kw)


def test_the_rate_holds_on_uneven_steps_and_intervals_tile_time() -> None:
    # 50 Hz on 3 ms steps: due times accumulate (t + period would give 1 / 21 ms = 47.6 Hz)
    samples = run(quiet(), 3.0, step_ns=3_000_000)
    assert len(samples) == 150
    ends = [s.t_ns + s.integration_ns // 2 for s in samples]
    starts = [s.t_ns - s.integration_ns // 2 for s in samples]
    assert starts[0] == 0 and all(
        abs(a - b) <= 1 for a, b in zip(ends[:-1], starts[1:], strict=False)
    )
    assert FLOW_DELAY_S == 0.015 and quiet().delay_s == 0.015


def test_forward_flight_at_1_m_s_and_2_m_gives_minus_half_a_radian_per_second() -> None:
    samples = run(quiet(), 1.0, v=(1.0, 0.0, 0.0))
    for s in samples[1:]:
        np.testing.assert_allclose(s.flow_rate_rad_s, [0.0, -0.5], atol=1e-9)
        np.testing.assert_allclose(s.gyro_rad, 0.0)
        assert s.distance_m == pytest.approx(2.0) and s.quality == 255


def test_a_pure_rotation_shows_as_flow_equal_to_the_gyro() -> None:
    for s in run(quiet(), 1.0, w=(0.3, -0.4, 0.2))[1:]:
        np.testing.assert_allclose(s.flow_rad, s.gyro_rad[:2], atol=1e-12)
        np.testing.assert_allclose(s.gyro_rate_rad_s, [0.3, -0.4, 0.2], atol=1e-9)


@pytest.mark.parametrize("seed", range(5))
def test_the_sensor_and_the_ekf_model_agree_on_the_translational_flow(seed: int) -> None:
    rng = np.random.default_rng(seed)
    R = Rotation.from_euler("ZYX", rng.uniform([-3, -0.5, -0.5], [3, 0.5, 0.5])).as_matrix()
    v, w, h = rng.normal(0, 1, 3), rng.normal(0, 0.5, 3), float(rng.uniform(0.5, 4))
    seen = line_of_sight_rate(R, v, w, h) - w[:2]
    model = predict_flow(R, v, h, floor_z_m=0.0, min_height_m=0.3).flow_rate_rad_s
    np.testing.assert_allclose(seen, model, atol=1e-12)


def test_noise_and_gyro_bias_are_as_configured() -> None:
    sensor = FlowSensor(
        flow_sigma_rad_s=0.05, gyro_sigma_rad_s=0.01, gyro_bias_rad_s=(0.02, 0.0, -0.01)
    )
    samples = run(sensor, 40.0, step_ns=10_000_000, seed=3)
    flow = np.array([s.flow_rate_rad_s for s in samples])
    gyro = np.array([s.gyro_rate_rad_s for s in samples])
    assert flow.std(axis=0) == pytest.approx([0.05, 0.05], rel=0.1)
    np.testing.assert_allclose(gyro.mean(axis=0), [0.02, 0.0, -0.01], atol=0.002)
    assert gyro.std(axis=0) == pytest.approx([0.01] * 3, rel=0.1)


def test_too_low_or_too_dark_gives_nothing_and_dim_light_lowers_the_quality() -> None:
    assert run(quiet(), 1.0, z=0.25) == []  # below PX4FLOW's 0.3 m
    assert run(quiet(illumination=0.05), 1.0) == []  # darker than min_illumination
    dim = run(FlowSensor(illumination=0.4, flow_sigma_rad_s=0.05), 20.0, step_ns=10_000_000)
    assert {s.quality for s in dim} == {round(255 * 0.4)}
    assert np.std([s.flow_rate_rad_s[0] for s in dim]) == pytest.approx(0.05 / 0.4, rel=0.15)


def test_beyond_the_sonar_or_too_fast_the_flow_is_invalid() -> None:
    high = run(quiet(), 0.5, z=6.0)
    assert high and all(s.quality == 0 and s.distance_m is None for s in high)
    fast = run(quiet(max_rate_rad_s=2.0), 0.5, v=(5.0, 0.0, 0.0))  # 2.5 rad/s at 2 m
    assert fast and all(s.quality == 0 for s in fast[1:])
    tilted = run(quiet(), 0.5, R=Rotation.from_euler("x", 0.8).as_matrix())
    assert tilted and all(s.distance_m is None and s.quality == 255 for s in tilted)


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"rate_hz": 0.0}, "flow sensor rate_hz must be finite and > 0"),
        ({"flow_sigma_rad_s": -1.0}, "flow sensor flow_sigma_rad_s must be finite and >= 0"),
        ({"min_height_m": 6.0}, "0 <= min_height_m < max_height_m"),
        ({"quality_max": 300}, "quality_max in 1..255"),
    ],
)
def test_bad_sensor_settings_are_refused(kw: dict[str, float], message: str) -> None:
    with pytest.raises(SimError, match=message):
        FlowSensor(**kw)


def test_after_a_gap_in_the_calls_a_fresh_interval_opens() -> None:
    # A dropout that does not read the sensor for 0.3 s, while the body turns at 1 rad/s
    # about x: the next sample covers only time after the gap, still on the 50 Hz grid.
    sensor, rng = quiet(), np.random.default_rng(0)
    out = []
    for k in range(0, 500):
        t = k * 2_000_000
        if 200_000_000 <= t < 500_000_000:
            continue
        s = sensor.sample(truth(t, w=(1.0, 0.0, 0.0)), t, rng)
        if s is not None:
            out.append(s)
    after = [s for s in out if s.t_ns > 500_000_000]
    first = after[0]
    assert first.t_ns - first.integration_ns // 2 == 500_000_000
    assert first.t_ns + first.integration_ns // 2 == 520_000_000
    for s in after:
        np.testing.assert_allclose(s.gyro_rate_rad_s, [1.0, 0.0, 0.0], atol=1e-9)
        assert s.integration_ns <= 20_000_000


def test_called_only_at_its_own_rate_it_still_reports() -> None:
    samples = run(quiet(), 1.0, step_ns=20_000_000, v=(1.0, 0.0, 0.0))
    assert len(samples) == 50
    for s in samples[1:]:
        np.testing.assert_allclose(s.flow_rate_rad_s, [0.0, -0.5], atol=1e-9)
