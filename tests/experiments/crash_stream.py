"""A simulated crash as a PX4 log would hold it: a vehicle at rest, a 0.5 s tumble at up to
14 rad/s with impacts beyond the accelerometer's 16 g range (clipped, and flagged per axis as
``sensor_combined.accelerometer_clipping`` does), then at rest again in a new attitude."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.io.ulog_sensors import UlogSensors

G = 9.81
RANGE_M_S2 = 16 * G
FIELD_W = np.array([0.0, 0.21, -0.42])  # gauss, ENU: north and down


def _attitudes(
    t: np.ndarray, t_crash: float, rng: np.random.Generator
) -> tuple[Rotation, np.ndarray]:
    """Attitude and body rate at each time: still, a tumble, still again."""
    w_B = np.zeros((len(t), 3))
    tau = t - t_crash
    inside = (tau >= 0) & (tau < 0.5)
    s = tau[inside]
    env = np.sin(np.pi * s / 0.5)  # spin up and down over the half second
    w_B[inside] = (
        14.0 * env[:, None] * np.column_stack([np.cos(9 * s), 0.7 * np.sin(7 * s), 0.4 + 0 * s])
    )
    # integrate at the stream's own (1 kHz) rate, exactly per step
    R = [Rotation.identity()]
    for k in range(1, len(t)):
        R.append(R[-1] * Rotation.from_rotvec(w_B[k - 1] * (t[k] - t[k - 1])))
    return Rotation.concatenate(R), w_B


def crash_sensors(
    *,
    seed: int = 0,
    duration_s: float = 25.0,
    t_crash_s: float = 6.0,
    gyro_scale_error: float = 0.0,
) -> tuple[UlogSensors, Rotation]:
    """The sensor streams (IMU 200 Hz, magnetometer and barometer 50 Hz, land detector) and
    the true final attitude (ENU/FLU). ``gyro_scale_error`` scales the gyro's x, y, z axes by
    1 + e, 1 - e, 1 + e (a MEMS gyro's sensitivity is within some 1-3 % of nominal): over the
    tumble's turns the integrated attitude then ends degrees off, as on a real crash."""
    rng = np.random.default_rng(seed)
    t_fine = np.arange(0.0, duration_s, 0.001)
    R_fine, w_fine = _attitudes(t_fine, t_crash_s, rng)
    # world acceleration: impacts of 35-40 g, 20-30 ms each, in pairs that cancel (the vehicle
    # ends where it started, at rest)
    a_W = np.zeros((len(t_fine), 3))
    hits = ((0.10, 0.03, 40, (0.8, 0.6, 0.0)), (0.18, 0.02, 35, (0.0, 0.0, 1.0)), (0.23, 0.02, -35, (0.0, 0.0, 1.0)),
            (0.32, 0.03, -40, (0.8, 0.6, 0.0)))  # fmt: skip
    for t_hit, dur, g_s, axis in hits:
        on = (t_fine >= t_crash_s + t_hit) & (t_fine < t_crash_s + t_hit + dur)
        a_W[on] = g_s * G * np.array(axis)
    f_fine = R_fine.inv().apply(a_W + np.array([0.0, 0.0, G]))
    # the IMU: 200 Hz, each sample the mean over its 5 ms (what an integrating IMU delivers)
    step = 5
    n = len(t_fine) // step
    t_imu_s = t_fine[step - 1 :: step][:n]
    gyro = w_fine[: n * step].reshape(n, step, 3).mean(axis=1)
    accel_true = f_fine[: n * step].reshape(n, step, 3).mean(axis=1)
    accel = np.clip(accel_true + rng.normal(0, 0.05, (n, 3)), -RANGE_M_S2, RANGE_M_S2)
    gyro = gyro * (1.0 + gyro_scale_error * np.array([1.0, -1.0, 1.0]))
    gyro = gyro + rng.normal(0, 0.003, (n, 3))
    clip_axes = (np.abs(accel) >= RANGE_M_S2).astype(np.int64) @ np.array([1, 2, 4])
    t_ns = np.round(t_imu_s * 1e9).astype(np.int64) + 1_000_000_000
    # magnetometer and barometer at 50 Hz
    k_slow = np.arange(0, len(t_fine), 20)
    mag = R_fine[k_slow].inv().apply(FIELD_W) + rng.normal(0, 0.002, (len(k_slow), 3))
    t_slow = np.round(t_fine[k_slow] * 1e9).astype(np.int64) + 1_000_000_000
    baro = 400.0 + rng.normal(0, 0.03, len(k_slow))
    # the land detector: landed, not landed from the crash for 2 s, landed again
    t_land = np.arange(0.0, duration_s, 0.1)
    landed = ~((t_land >= t_crash_s) & (t_land < t_crash_s + 2.0))
    s = UlogSensors(
        path=Path("crash.ulg"), duration_s=duration_s, imu_t_ns=t_ns, gyro_rad_s=gyro, accel_m_s2=accel,
        imu_clipping=clip_axes, baro={"t_ns": t_slow, "alt": baro}, mag={"t_ns": t_slow, "field_B": mag},
        landed={"t_ns": np.round(t_land * 1e9).astype(np.int64) + 1_000_000_000, "landed": landed},
        earth_field_declination_rad=0.0, t_start_ns=1_000_000_000,
    )  # fmt: skip
    return s, R_fine[-1]
