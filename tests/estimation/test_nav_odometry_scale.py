"""Relative odometry with a scale error (issue 25: a monocular VIO's motion is a few per cent
too long or short): the scale as a state of the frame's drift, found from GNSS fixes."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.errors import EstimationError
from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.messages import ImuSample, OdometrySample, PositionSample
from quadnav.units import GRAVITY_M_S2

SPEED_M_S = 3.0
SCALE_ERROR = 0.05  # the odometry's motion is 5 % too long
SECONDS = 60.0
GPS_SIGMA_M = 1.0


def _fly(seed: int, scale_sigma: float) -> tuple[NavEkf, float]:
    """A straight flight along x at 3 m/s (an exact IMU), the odometry at 20 Hz (2 cm noise),
    GNSS positions at 2 Hz (1 m). Returns the filter and its position error at the end."""
    rng = np.random.default_rng(seed)
    cfg = NavEkfConfig(
        odometry_mode="relative", odometry_fuse=("pos", "yaw"), odometry_pos_noise_m=0.02,
        odometry_yaw_noise_rad=0.005, odometry_scale_sigma=scale_sigma,
        odometry_scale_rw_sqrt_s=1e-3 if scale_sigma else 0.0,
    )  # fmt: skip
    P0 = np.diag([1e-6] * 3 + [1e-4] * 3 + [1e-4] * 3 + [1e-8] * 6)
    v = np.array([SPEED_M_S, 0.0, 0.0])
    ekf = NavEkf(cfg, p0=np.zeros(3), v0=v, q0_xyzw=[0, 0, 0, 1.0], P0=P0)
    est = DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=100_000_000), t0_ns=0
    )
    cov_pose = np.diag([0.02**2] * 3 + [0.005**2] * 3)
    for k in range(1, int(SECONDS * 250) + 1):
        t = k * 4_000_000
        est.push(ImuSample(t_ns=t, gyro_rad_s=np.zeros(3), accel_m_s2=[0.0, 0.0, GRAVITY_M_S2]))
        p = v * t * 1e-9
        if k % 12 == 0:  # (48 ms: about 20 Hz)
            est.push(OdometrySample(
                t_ns=t, p_W_B=(1 + SCALE_ERROR) * p + rng.normal(0, 0.02, 3),
                q_W_B_xyzw=[0, 0, 0, 1.0], v_W_B=(1 + SCALE_ERROR) * v, cov_pose=cov_pose,
                cov_v=np.eye(3) * 0.01,
            ))  # fmt: skip
        if k % 125 == 0:
            fix = p + rng.normal(0, GPS_SIGMA_M, 3)
            est.push(PositionSample(t_ns=t, p_W_B=fix, sigma_m=GPS_SIGMA_M, source="gps"))
    return ekf, float(np.linalg.norm(ekf.p - v * SECONDS))


@pytest.mark.parametrize("seed", range(2))
def test_the_scale_error_is_found_and_the_position_holds(seed: int) -> None:
    ekf, err = _fly(seed, scale_sigma=0.1)
    assert ekf.odometry_drift[4] == pytest.approx(SCALE_ERROR, abs=0.01)
    # the frame's random walk (0.02 m/sqrt(s)) against 1 m fixes at 2 Hz leaves about 0.12 m
    # a horizontal axis (sqrt(sqrt(q R dt))): 0.6 m is 3 sigma of the horizontal error
    assert err < 0.6
    if seed == 0:  # without the scale state the odometry's 9 m of stretch fights the fixes
        _, err_without = _fly(seed, scale_sigma=0.0)
        assert err_without > 3 * err


def test_scale_settings_are_validated_by_name() -> None:
    with pytest.raises(EstimationError, match="odometry_scale_sigma must be within"):
        NavEkfConfig(odometry_mode="relative", odometry_scale_sigma=float("nan"))
    with pytest.raises(EstimationError, match="odometry_scale_rw_sqrt_s must be within"):
        NavEkfConfig(odometry_mode="relative", odometry_scale_rw_sqrt_s=2.0)
