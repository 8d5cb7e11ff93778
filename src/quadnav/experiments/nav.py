"""A 3-D navigation run: the rigid body flies a trajectory (controller on the true state),
an integrating IMU, a delayed external pose (vision) and a barometer measure it, and the
navigation EKF on the delayed-horizon core estimates it. Returns arrays for evaluation.

This is the estimation half of the main job; closing the loop on the output predictor and
the scenario file come with the rest of issue 5.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.control.cascaded_pid import CascadedPid, Setpoint
from quadnav.control.trajectories import Circle
from quadnav.estimation.horizon import DelayedHorizonEstimator, HorizonConfig
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.messages import HeightSample, PoseSample
from quadnav.sim.rigid_body import RigidBodyQuadrotor
from quadnav.sim.sensors import DelayLine, IntegratingImu
from quadnav.vehicle import RigidBodyParams

__all__ = ["NavRunConfig", "NavRunResult", "run_nav"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class NavRunConfig:
    duration_s: float = 20.0
    sim_dt_s: float = 0.002
    imu_rate_hz: float = 250.0
    gyro_sigma_rad_s: float = 0.005
    accel_sigma_m_s2: float = 0.05
    gyro_bias_rw: float = 1e-4
    accel_bias_rw: float = 1e-3
    gyro_bias0_sigma_rad_s: float = 0.01
    accel_bias0_sigma_m_s2: float = 0.05
    vision_rate_hz: float = 30.0
    vision_delay_s: float = 0.25
    vision_sigma_m: float = 0.01
    vision_yaw_sigma_rad: float = 0.01
    baro_rate_hz: float = 50.0
    baro_sigma_m: float = 0.1
    baro_delay_s: float = 0.02


@dataclass(frozen=True, slots=True, kw_only=True)
class NavRunResult:
    t_ns: NDArray[np.int64]  # IMU steps (current horizon)
    truth_p: FloatArray
    output_p: FloatArray
    t_delayed_ns: NDArray[np.int64]
    delayed_err: (
        FloatArray  # (N, 15) true - estimate at the delayed horizon (attitude as a rotation vector)
    )
    delayed_P: FloatArray
    vision_fused: int
    vision_rejected: int


def run_nav(cfg: NavRunConfig, seed: int) -> NavRunResult:
    rng = np.random.default_rng(seed)
    params = RigidBodyParams()
    circ = Circle(center_m=(-2.0, 0.0, 1.5), radius_m=2.0, speed_m_s=1.0)
    sim = RigidBodyQuadrotor(params, dt_s=cfg.sim_dt_s, p0=(0.0, 0.0, 1.5), hovering=True)
    ctrl = CascadedPid(params, dt_s=cfg.sim_dt_s)
    imu_period_ns = round(1e9 / cfg.imu_rate_hz)
    bg0 = cfg.gyro_bias0_sigma_rad_s * rng.standard_normal(3)
    ba0 = cfg.accel_bias0_sigma_m_s2 * rng.standard_normal(3)
    imu = IntegratingImu(
        period_ns=imu_period_ns,
        gyro_sigma_rad_s=cfg.gyro_sigma_rad_s,
        accel_sigma_m_s2=cfg.accel_sigma_m_s2,
        gyro_bias_rw_rad_s_sqrt_s=cfg.gyro_bias_rw,
        accel_bias_rw_m_s2_sqrt_s=cfg.accel_bias_rw,
        gyro_bias0_rad_s=tuple(bg0),
        accel_bias0_m_s2=tuple(ba0),
        gravity_m_s2=params.gravity_m_s2,
    )
    vision_line: DelayLine[PoseSample] = DelayLine(delay_ns=round(cfg.vision_delay_s * 1e9))
    baro_line: DelayLine[HeightSample] = DelayLine(delay_ns=round(cfg.baro_delay_s * 1e9))
    vision_period_ns = round(1e9 / cfg.vision_rate_hz)
    baro_period_ns = round(1e9 / cfg.baro_rate_hz)
    next_vision, next_baro = 0, 0

    # Initial estimate: the truth perturbed by a draw from the initial covariance.
    sig0 = np.array(
        [0.02] * 3
        + [0.05] * 3
        + [0.02] * 3
        + [cfg.gyro_bias0_sigma_rad_s] * 3
        + [cfg.accel_bias0_sigma_m_s2] * 3
    )
    d0 = sig0 * rng.standard_normal(15)
    s0 = sim.state()
    q0 = (Rotation.from_quat(s0.q_W_B_xyzw) * Rotation.from_rotvec(-d0[0:3])).as_quat()
    ekf = NavEkf(
        NavEkfConfig(
            gyro_sigma_rad_s=cfg.gyro_sigma_rad_s,
            accel_sigma_m_s2=cfg.accel_sigma_m_s2,
            gyro_bias_rw_rad_s_sqrt_s=cfg.gyro_bias_rw,
            accel_bias_rw_m_s2_sqrt_s=cfg.accel_bias_rw,
            gravity_m_s2=params.gravity_m_s2,
        ),
        p0=s0.p_W_B - d0[6:9],
        v0=s0.v_W_B - d0[3:6],
        q0_xyzw=q0,
        P0=np.diag(sig0**2),
        bg0=bg0 - d0[9:12],
        ba0=ba0 - d0[12:15],
    )
    est = DelayedHorizonEstimator(
        ekf,
        HorizonConfig(
            imu_period_ns=imu_period_ns,
            max_delay_ns=round(max(cfg.vision_delay_s, cfg.baro_delay_s) * 1e9),
        ),
        t0_ns=s0.t_ns,
    )
    n = round(cfg.duration_s / cfg.sim_dt_s)
    t_ref = np.arange(n + 1) * cfg.sim_dt_s
    ref = circ.reference(t_ref)
    truth_hist: dict[int, tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]] = {}
    rows_t, rows_truth, rows_out, rows_td, rows_err, rows_P = [], [], [], [], [], []
    for i in range(n):
        state = sim.state()
        cmd = ctrl(state, Setpoint(p=ref.p[i], v=ref.v[i], a=ref.a[i], yaw_rad=0.0))
        sim.step(cmd)
        truth = sim.state()
        t = truth.t_ns
        if t >= next_vision:
            next_vision += vision_period_ns
            qn = (
                Rotation.from_quat(truth.q_W_B_xyzw)
                * Rotation.from_rotvec([0.0, 0.0, cfg.vision_yaw_sigma_rad * rng.standard_normal()])
            ).as_quat()
            vision_line.push(PoseSample(t_ns=t, p_W_B=truth.p_W_B + cfg.vision_sigma_m * rng.standard_normal(3), q_W_B_xyzw=qn,
                                        sigma_pos_m=cfg.vision_sigma_m, sigma_yaw_rad=cfg.vision_yaw_sigma_rad))  # fmt: skip
        if t >= next_baro:
            next_baro += baro_period_ns
            baro_line.push(
                HeightSample(
                    t_ns=t,
                    z_m=float(truth.p_W_B[2] + cfg.baro_sigma_m * rng.standard_normal()),
                    sigma_m=cfg.baro_sigma_m,
                )
            )
        sample = imu.accumulate(truth, cfg.sim_dt_s, rng)
        if sample is None:
            continue
        truth_hist[t] = (
            truth.p_W_B,
            truth.v_W_B,
            truth.q_W_B_xyzw,
            imu.bias_g.copy(),
            imu.bias_a.copy(),
        )
        for _, obs in vision_line.pop_arrived(t):
            est.push(obs)
        for _, obs_h in baro_line.pop_arrived(t):
            est.push(obs_h)
        est.push(sample)
        rows_t.append(t)
        rows_truth.append(truth.p_W_B)
        rows_out.append(est.output_nav().pos)
        td = est.t_delayed_ns
        rows_td.append(td)
        if td in truth_hist:
            p_t, v_t, q_t, bg_t, ba_t = truth_hist[td]
            dth = (Rotation.from_quat(ekf.q_xyzw).inv() * Rotation.from_quat(q_t)).as_rotvec()
            rows_err.append(
                np.concatenate([dth, v_t - ekf.v, p_t - ekf.p, bg_t - ekf.bg, ba_t - ekf.ba])
            )
        else:
            rows_err.append(np.full(15, np.nan))
        rows_P.append(ekf.P.copy())
    vs = est.stats("vision")
    return NavRunResult(
        t_ns=np.array(rows_t, dtype=np.int64),
        truth_p=np.array(rows_truth),
        output_p=np.array(rows_out),
        t_delayed_ns=np.array(rows_td, dtype=np.int64),
        delayed_err=np.array(rows_err),
        delayed_P=np.array(rows_P),
        vision_fused=vs.fused,
        vision_rejected=vs.rejected_gate + vs.rejected_too_old,
    )
