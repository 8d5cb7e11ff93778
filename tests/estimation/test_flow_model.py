"""PX4's optical-flow observation: its Jacobian, its signs and sizes, its noise."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.estimation.flow_model import (
    compensated_flow_rate,
    flow_noise_sigma,
    predict_flow,
)
from quadnav.estimation.layout import NAV_ERROR
from quadnav.messages import FlowSample

from .differences import central_differences


def _pred(R, v, z, *, min_h=0.3):
    return predict_flow(R, v, z, floor_z_m=0.1, min_height_m=min_h)


def _numeric_H(R, v, z, *, min_h=0.3):
    """Central differences of the prediction over the 15-element error state."""

    def perturbed(d):
        Rt = R @ Rotation.from_rotvec(d[NAV_ERROR["att"]]).as_matrix()
        vt = v + d[NAV_ERROR["vel"]]
        return _pred(Rt, vt, z + d[NAV_ERROR.index("z")], min_h=min_h).flow_rate_rad_s

    return central_differences(perturbed, NAV_ERROR.size)


@pytest.mark.parametrize("seed", range(8))
def test_the_flow_jacobian_matches_central_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    ypr = [rng.uniform(-math.pi, math.pi), rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5)]
    R = Rotation.from_euler("ZYX", ypr).as_matrix()
    v = rng.normal(0.0, 1.5, 3)
    z = rng.uniform(0.6, 4.0)
    H = _pred(R, v, z).H
    np.testing.assert_allclose(H, _numeric_H(R, v, z), rtol=1e-6, atol=1e-8)
    assert np.abs(H[:, NAV_ERROR["att"]]).max() > 0.01  # the attitude columns are exercised
    assert np.abs(H[:, NAV_ERROR.index("z")]).max() > 0.01


def test_below_the_minimum_height_the_height_is_bounded_and_unobserved() -> None:
    R = Rotation.from_euler("ZYX", [0.3, 0.1, -0.1]).as_matrix()
    v = np.array([0.5, -0.3, 0.1])
    low = _pred(R, v, 0.2, min_h=0.3)  # 0.1 m over the floor at z = 0.1
    assert low.height_m == 0.3
    np.testing.assert_allclose(low.flow_rate_rad_s, _pred(R, v, 0.4).flow_rate_rad_s)
    assert not low.H[:, NAV_ERROR.index("z")].any()
    np.testing.assert_allclose(low.H, _numeric_H(R, v, 0.2), atol=1e-8)


def level(yaw_rad: float = 0.0) -> np.ndarray:
    return Rotation.from_euler("z", yaw_rad).as_matrix()


def test_hover_predicts_no_flow() -> None:
    p = predict_flow(level(1.0), np.zeros(3), 2.0, floor_z_m=0.0, min_height_m=0.3)
    np.testing.assert_array_equal(p.flow_rate_rad_s, [0.0, 0.0])
    assert p.range_m == pytest.approx(2.0)


@pytest.mark.parametrize(
    ("yaw_rad", "v_W", "expected"),
    [
        (0.0, [1.0, 0.0, 0.0], [0.0, -0.5]),  # forward at 1 m/s, 2 m up: -v/h about y
        (math.pi / 2, [0.0, 1.0, 0.0], [0.0, -0.5]),  # facing north, flying north: forward
        (0.0, [0.0, 1.0, 0.0], [0.5, 0.0]),  # to the left (body +y): +v/h about x
        (0.0, [0.0, 0.0, -1.0], [0.0, 0.0]),  # descending straight down: no flow at the centre
    ],
)
def test_level_flight_at_2_m(yaw_rad: float, v_W: list[float], expected: list[float]) -> None:
    p = predict_flow(level(yaw_rad), np.array(v_W), 2.0, floor_z_m=0.0, min_height_m=0.3)
    np.testing.assert_allclose(p.flow_rate_rad_s, expected, atol=1e-12)


def test_a_pitched_body_sees_the_floor_farther_away() -> None:
    # pitched 0.3 rad nose down, moving east at 1 m/s, 2 m up: v_B = (cos, 0, sin), the
    # range along the tilted axis is 2 / cos: flow about y = -cos * cos / 2
    R = Rotation.from_euler("y", 0.3).as_matrix()
    p = predict_flow(R, np.array([1.0, 0.0, 0.0]), 2.0, floor_z_m=0.0, min_height_m=0.3)
    np.testing.assert_allclose(p.flow_rate_rad_s, [0.0, -(math.cos(0.3) ** 2) / 2], atol=1e-12)
    assert p.range_m == pytest.approx(2.0 / math.cos(0.3))


def test_a_pure_rotation_is_compensated_by_the_sensor_gyro() -> None:
    # Turning at (0.4, -0.2, 0.1) rad/s over still ground for 20 ms: the flow equals the gyro.
    w = np.array([0.4, -0.2, 0.1])
    s = FlowSample(t_ns=10_000_000, integration_ns=20_000_000, flow_rad=0.02 * w[:2],
                   gyro_rad=0.02 * w, quality=255)  # fmt: skip
    np.testing.assert_allclose(compensated_flow_rate(s, np.zeros(3)), [0.0, 0.0], atol=1e-12)
    # a gyro bias of the sensor shows as flow until it is removed
    biased = FlowSample(t_ns=10_000_000, integration_ns=20_000_000, flow_rad=0.02 * w[:2],
                        gyro_rad=0.02 * (w + [0.01, -0.02, 0.0]), quality=255)  # fmt: skip
    np.testing.assert_allclose(compensated_flow_rate(biased, np.zeros(3)), [-0.01, 0.02])
    bias = np.array([0.01, -0.02, 0.0])
    np.testing.assert_allclose(compensated_flow_rate(biased, bias), [0.0, 0.0], atol=1e-12)


def test_noise_follows_the_quality_as_px4() -> None:
    kw = {"quality_min": 1, "sigma_best_rad_s": 0.15, "sigma_worst_rad_s": 0.5}
    assert flow_noise_sigma(255, **kw) == pytest.approx(0.15)
    assert flow_noise_sigma(1, **kw) == pytest.approx(0.5)
    assert flow_noise_sigma(0, **kw) == pytest.approx(0.5)
    assert flow_noise_sigma(128, **kw) == pytest.approx(0.325)  # halfway between 1 and 255
    # PX4 floors both at 0.05 rad/s
    assert (
        flow_noise_sigma(255, quality_min=1, sigma_best_rad_s=0.01, sigma_worst_rad_s=0.5) == 0.05
    )
