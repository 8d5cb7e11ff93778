"""The navigation EKF's observation models as a registry: a sensor the filter has never heard
of joins it through a message type, a model and one registration, with no edit of the filter
or of the delayed horizon that feeds it."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from quadnav.errors import EstimationError
from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig
from quadnav.estimation.horizon import FusionResult
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.estimation.nav_observations import NavUpdater, yaw_jacobian
from quadnav.geometry.rotations import yaw_of
from quadnav.messages import ImuSample, PositionSample
from quadnav.units import GRAVITY_M_S2

TRUE_YAW = 0.0
START_YAW = 0.5  # the filter's heading at the start, 0.5 rad off
DUAL_ANTENNA_SIGMA = 0.01


@dataclass(frozen=True, slots=True, kw_only=True)
class AntennaHeading:
    """A dual-antenna GNSS compass's heading (ENU, from east, counter-clockwise): a message
    the project does not have."""

    t_ns: int
    yaw_rad: float
    sigma_rad: float
    source: str = "compass"


class AntennaHeadingModel:
    """Its observation model: the heading against the filter's, wrapped, one row."""

    def __init__(self) -> None:
        self.calls = 0

    def accepts(self, ekf: NavUpdater, obs: AntennaHeading) -> bool:
        return math.isfinite(obs.yaw_rad)

    def fuse(self, ekf: NavUpdater, obs: AntennaHeading) -> FusionResult:
        self.calls += 1
        H = np.zeros((1, 15))
        H[0, 0:3] = yaw_jacobian(ekf.R)
        r = np.array([math.remainder(obs.yaw_rad - yaw_of(ekf.R), 2 * math.pi)])
        return ekf.gated_update(obs, r, H, np.array([[obs.sigma_rad**2]]), None)


def _estimator() -> tuple[NavEkf, DelayedHorizonEstimator]:
    P0 = np.diag([1e-4, 1e-4, 1.0] + [1e-4] * 12)  # the heading unknown to a radian
    q0 = [0.0, 0.0, math.sin(START_YAW / 2), math.cos(START_YAW / 2)]
    ekf = NavEkf(NavEkfConfig(), p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=q0, P0=P0)
    horizon = HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=100_000_000)
    return ekf, DelayedHorizonEstimator(ekf, horizon, t0_ns=0)


def _fly(est: DelayedHorizonEstimator, seconds: float = 4.0) -> None:
    """A still vehicle facing east: IMU at 250 Hz, the compass at 5 Hz (one NaN among them)."""
    rng = np.random.default_rng(3)
    for k in range(1, int(seconds * 250) + 1):
        t = k * 4_000_000
        est.push(ImuSample(t_ns=t, gyro_rad_s=rng.normal(0, 0.002, 3),
                           accel_m_s2=[0.0, 0.0, GRAVITY_M_S2] + rng.normal(0, 0.02, 3)))  # fmt: skip
        if k % 50 == 0:
            yaw = math.nan if k == 100 else TRUE_YAW + rng.normal(0, DUAL_ANTENNA_SIGMA)
            est.push(AntennaHeading(t_ns=t, yaw_rad=yaw, sigma_rad=DUAL_ANTENNA_SIGMA))


def test_a_new_sensor_is_fused_through_a_registered_model() -> None:
    ekf, est = _estimator()
    model = AntennaHeadingModel()
    ekf.register(AntennaHeading, model)
    _fly(est)
    stats = est.stats("compass")
    assert stats.rejected_unsupported == 1  # the NaN heading, refused by the model's check
    assert stats.fused >= 15 and model.calls == stats.fused + stats.rejected_gate
    assert abs(math.remainder(yaw_of(ekf.R) - TRUE_YAW, 2 * math.pi)) < 0.02


def test_without_its_model_the_sensor_is_counted_unsupported_and_changes_nothing() -> None:
    ekf, est = _estimator()
    _fly(est)
    stats = est.stats("compass")
    assert stats.received == 20 and stats.rejected_unsupported == 20 and stats.fused == 0
    assert abs(math.remainder(yaw_of(ekf.R) - START_YAW, 2 * math.pi)) < 0.02
    with pytest.raises(EstimationError, match="cannot fuse AntennaHeading"):
        ekf.fuse(AntennaHeading(t_ns=0, yaw_rad=0.0, sigma_rad=0.01))  # type: ignore[arg-type]


def test_a_model_registered_for_a_type_replaces_the_built_in_one() -> None:
    """A user's own position model (here: one that ignores the fixes) takes the place of the
    built-in one for that type; a filter's models are its own."""

    class Ignore:
        def accepts(self, ekf: NavUpdater, obs: PositionSample) -> bool:
            return False

        def fuse(self, ekf: NavUpdater, obs: PositionSample) -> FusionResult:
            raise AssertionError("not accepted, so never fused")

    ekf, _ = _estimator()
    other, _ = _estimator()
    ekf.register(PositionSample, Ignore())
    fix = PositionSample(t_ns=4_000_000, p_W_B=[1.0, 0.0, 0.0], sigma_m=0.1, source="gps")
    assert not ekf.can_fuse(fix)
    assert other.can_fuse(fix)
