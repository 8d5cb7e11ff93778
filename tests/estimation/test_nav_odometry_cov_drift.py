"""Relative odometry whose frame drifts as its own covariance says (issue 25): a VIO's marginal
covariance grows with its drift, and ``odometry_drift_from_covariance`` lets the frame's drift
grow by that rise instead of only by fixed rates, with the odometry's noise its floors alone."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.messages import ImuSample, OdometrySample, PositionSample
from quadnav.units import GRAVITY_M_S2

SPEED_M_S = 3.0
DRIFT_M_SQRT_S = 0.15  # the odometry frame's true random walk: a realistic VIO's (~1 m a minute)
NOISE_M = 0.02
SECONDS = 60.0
GPS_SIGMA_M = 1.5
_IMU_NS = 4_000_000


def _config(from_cov: bool) -> NavEkfConfig:
    # the fixed rates are the scenarios' (0.02 m/sqrt(s)): too slow for this odometry
    return NavEkfConfig(
        odometry_mode="relative", odometry_fuse=("pos", "yaw"), odometry_pos_noise_m=NOISE_M,
        odometry_yaw_noise_rad=0.005, odometry_drift_from_covariance=from_cov,
    )  # fmt: skip


def _filter(from_cov: bool) -> tuple[NavEkf, DelayedHorizonEstimator]:
    P0 = np.diag([1e-6] * 3 + [1e-4] * 3 + [1e-4] * 3 + [1e-8] * 6)
    v = np.array([SPEED_M_S, 0.0, 0.0])
    ekf = NavEkf(_config(from_cov), p0=np.zeros(3), v0=v, q0_xyzw=[0, 0, 0, 1.0], P0=P0)
    est = DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=_IMU_NS, max_delay_ns=100_000_000), t0_ns=0
    )
    return ekf, est


def _odometry(t_ns: int, p: np.ndarray, var_m2: float, counter: int = 0) -> OdometrySample:
    return OdometrySample(
        t_ns=t_ns, p_W_B=p, q_W_B_xyzw=[0, 0, 0, 1.0], v_W_B=[SPEED_M_S, 0.0, 0.0],
        cov_pose=np.diag([var_m2] * 3 + [0.005**2] * 3), cov_v=np.eye(3) * 0.01,
        reset_counter=counter,
    )  # fmt: skip


def _fly(seed: int, from_cov: bool) -> tuple[float, float]:
    """A straight flight along x at 3 m/s (an exact IMU); the odometry at about 20 Hz, its frame
    drifting at 0.15 m/sqrt(s) per axis and its covariance growing so (as an honest VIO's);
    GNSS positions at 2 Hz (1.5 m). Returns the position RMSE and the mean position NEES over
    the last 40 s, at the delayed horizon."""
    rng = np.random.default_rng(seed)
    ekf, est = _filter(from_cov)
    v = np.array([SPEED_M_S, 0.0, 0.0])
    drift, errs, nees = np.zeros(3), [], []
    for k in range(1, int(SECONDS * 250) + 1):
        t = k * _IMU_NS
        est.push(ImuSample(t_ns=t, gyro_rad_s=np.zeros(3), accel_m_s2=[0.0, 0.0, GRAVITY_M_S2]))
        if k % 12 == 0:  # (48 ms: about 20 Hz)
            drift += rng.normal(0.0, DRIFT_M_SQRT_S * np.sqrt(12 * _IMU_NS * 1e-9), 3)
            var = NOISE_M**2 + DRIFT_M_SQRT_S**2 * t * 1e-9
            p_odo = v * t * 1e-9 + drift + rng.normal(0, NOISE_M, 3)
            est.push(_odometry(t, p_odo, var))
        if k % 125 == 0:
            fix = v * t * 1e-9 + rng.normal(0, GPS_SIGMA_M, 3)
            est.push(PositionSample(t_ns=t, p_W_B=fix, sigma_m=GPS_SIGMA_M, source="gps"))
            if t * 1e-9 > SECONDS - 40:
                e = ekf.p - v * est.t_delayed_ns * 1e-9
                errs.append(e)
                nees.append(float(e @ np.linalg.solve(ekf.P[6:9, 6:9], e)))
    return float(np.sqrt(np.mean(np.square(errs)) * 3)), float(np.mean(nees))


def test_the_drift_block_grows_by_the_rise_of_the_odometry_covariance() -> None:
    ekf, _ = _filter(True)
    p, Rz = np.zeros(3), np.eye(3)
    steps = [  # (variance an axis, yaw variance, reset counter, the drift block's expected rise)
        (0.04, 1e-4, 0, 0.0),  # the first sample: nothing to rise from
        (0.29, 3e-4, 0, 0.25),  # risen by 0.25 m^2 an axis and 2e-4 rad^2
        (0.10, 1e-4, 0, 0.0),  # the odometry more certain: the drift does not shrink by it
        (0.50, 5e-4, 1, 0.0),  # a new frame (reset counter): no rise across it
    ]
    for var, var_yaw, counter, rise in steps:
        before = ekf._P.copy()
        ekf._grow_drift(_odometry(0, p, var, counter), Rz * var, var_yaw)
        grown = ekf._P - before
        assert np.allclose(grown[15:18, 15:18], np.eye(3) * rise, atol=1e-15)
        assert grown[18, 18] == pytest.approx(rise and 2e-4, abs=1e-15)
        grown[15:19, 15:19] = 0.0
        assert not grown.any()  # (nothing else moves)
    # a rise in one direction only (a correlated covariance) stays in that direction
    ekf._grow_drift(_odometry(0, p, 0.5, 1), np.diag([0.5, 0.5, 0.5]), 5e-4)
    before = ekf._P[15:18, 15:18].copy()
    d = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    ekf._grow_drift(_odometry(0, p, 0.5, 1), np.diag([0.5, 0.5, 0.5]) + 0.3 * np.outer(d, d), 5e-4)
    assert np.allclose(ekf._P[15:18, 15:18] - before, 0.3 * np.outer(d, d), atol=1e-12)


def test_a_drift_the_odometry_reports_is_corrected_by_the_fixes() -> None:
    """Seeds 0-3 (one flight each way per seed): a random walk of 0.15 m/sqrt(s) against
    1.5 m fixes at 2 Hz leaves about (q R dt)^(1/4) = 0.3 m an axis. With the fixed rate alone
    (0.02 m/sqrt(s)) the filter leaves the drift to the odometry, which wanders over a metre in
    60 s, and thinks it knows its position to 0.1 m."""
    runs = [(_fly(s, from_cov=True), _fly(s, from_cov=False)) for s in range(4)]
    rmse_cov = np.mean([c[0] for c, _ in runs])
    rmse_fixed = np.mean([f[0] for _, f in runs])
    assert rmse_cov < 0.7 * rmse_fixed
    assert 0.5 < np.mean([c[1] for c, _ in runs]) / 3 < 2.0
    assert np.mean([f[1] for _, f in runs]) / 3 > 4.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_relative_odometry_started_in_the_air_does_not_move_the_filter(seed: int) -> None:
    """A VIO that starts in flight has its frame at its first keyframe (here 2.4 m below and
    3 m behind where the filter is at its first sample, turned 35 degrees): in relative mode,
    beside GNSS, that frame is anchored where the filter is, so the odometry's first samples
    move nothing. (Taken as the navigation frame itself, it pulled outdoor_vio_gps's filter
    2.5 m down at the VIO's start.)"""
    rng = np.random.default_rng(seed)
    ekf, est = _filter(True)
    v = np.array([SPEED_M_S, 0.0, 0.0])
    start = np.array([SPEED_M_S * 1.0, 0.0, -2.4])  # the VIO's origin in the world
    c, s = np.cos(np.radians(35.0)), np.sin(np.radians(35.0))
    R_V_W = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # world into its frame
    q_V_B = [0.0, 0.0, -np.sin(np.radians(17.5)), np.cos(np.radians(17.5))]
    worst = 0.0
    for k in range(1, int(10.0 * 250) + 1):
        t = k * _IMU_NS
        est.push(ImuSample(t_ns=t, gyro_rad_s=np.zeros(3), accel_m_s2=[0.0, 0.0, GRAVITY_M_S2]))
        if k > 500 and k % 12 == 0:  # the odometry from 2 s on
            p_odo = R_V_W @ (v * t * 1e-9 - start) + rng.normal(0, NOISE_M, 3)
            cov = np.diag([NOISE_M**2] * 3 + [0.005**2] * 3)
            odo = OdometrySample(
                t_ns=t, p_W_B=p_odo, q_W_B_xyzw=q_V_B, v_W_B=R_V_W @ v, cov_pose=cov,
                cov_v=np.eye(3) * 0.01,
            )  # fmt: skip
            est.push(odo)
        if k % 125 == 0:  # GNSS at 2 Hz, 1.5 m
            fix = v * t * 1e-9 + rng.normal(0, GPS_SIGMA_M, 3)
            est.push(PositionSample(t_ns=t, p_W_B=fix, sigma_m=GPS_SIGMA_M, source="gps"))
        worst = max(worst, float(np.linalg.norm(ekf.p - v * est.t_delayed_ns * 1e-9)))
    assert worst < 0.1  # 15 m with the frame taken as the world's
    # the yaw of the odometry's frame is the filter's, not the odometry's
    assert abs(ekf.R[1, 0]) < 0.02
