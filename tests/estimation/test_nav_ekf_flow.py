"""The navigation EKF with optical flow: IMU + flow + height, no position source.

A small hand-made loop (the main loop is being rewritten): an analytic flight over a flat
floor, an averaging IMU, the flow sensor behind its 15 ms delay line, a height every 50 ms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig
from quadnav.estimation.layout import NAV_ERROR
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.messages import FlowSample, HeightSample, ImuSample, VehicleState
from quadnav.sim.flow import FLOW_DELAY_S, FlowSensor
from quadnav.sim.sensors import DelayLine, IntegratingImu

G = 9.81
STEP_NS = 2_000_000  # the simulator's step: the IMU averages two
IMU_NS = 4_000_000


def truth_states(seconds: float) -> list[VehicleState]:
    """Every step's truth: a circle of 2 m radius at 1 m/s, 1.5 m up with a slow height wave,
    yawing and rocking (vectorised; the body rate from central differences of the attitude)."""
    t = np.arange(round(seconds * 1e9 / STEP_NS) + 1) * STEP_NS * 1e-9
    A, om = 2.0, 0.5
    p = np.stack([A * np.sin(om * t), A * (1 - np.cos(om * t)), 1.5 + 0.3 * np.sin(0.4 * t)], 1)
    v = np.stack([A * om * np.cos(om * t), A * om * np.sin(om * t), 0.12 * np.cos(0.4 * t)], 1)
    a = np.stack(
        [-A * om**2 * np.sin(om * t), A * om**2 * np.cos(om * t), -0.048 * np.sin(0.4 * t)], 1
    )

    def R(tt: np.ndarray) -> Rotation:
        return Rotation.from_euler(
            "ZYX", np.stack([0.3 * tt, 0.08 * np.sin(0.9 * tt + 0.5), 0.1 * np.sin(1.1 * tt)], 1)
        )

    h = 1e-5
    w = (R(t - h).inv() * R(t + h)).as_rotvec() / (2 * h)
    q = R(t).as_quat()
    return [VehicleState(t_ns=k * STEP_NS, p_W_B=p[k], v_W_B=v[k], a_W_B=a[k], q_W_B_xyzw=q[k], w_B=w[k])
            for k in range(len(t))]  # fmt: skip


@dataclass
class Run:
    v_err: np.ndarray  # (N, 2) horizontal velocity error at the delayed horizon, after 2 s
    v_cov: np.ndarray  # (N, 2, 2) the filter's covariance of it
    est: DelayedHorizonEstimator


def fly(seed: int, *, flow: bool, seconds: float = 15.0, flow_noise_rad_s: float = 0.15) -> Run:
    rng = np.random.default_rng(seed)
    imu = IntegratingImu(period_ns=IMU_NS, gyro_sigma_rad_s=0.003, accel_sigma_m_s2=0.03,
                         gyro_bias0_rad_s=(0.002, -0.001, 0.001), accel_bias0_m_s2=(0.05, -0.04, 0.02),
                         gravity_m_s2=G)  # fmt: skip
    sensor = FlowSensor(gyro_bias_rad_s=(0.003, -0.002, 0.0))
    line: DelayLine[FlowSample] = DelayLine(delay_ns=round(FLOW_DELAY_S * 1e9))  # type: ignore[type-var]
    truths = truth_states(seconds)
    t0 = truths[0]
    P0 = np.diag([0.02**2] * 3 + [0.5**2] * 3 + [0.1**2] * 3 + [0.005**2] * 3 + [0.1**2] * 3)
    cfg = NavEkfConfig(gravity_m_s2=G, flow_noise_min_rad_s=flow_noise_rad_s)
    ekf = NavEkf(cfg, p0=t0.p_W_B, v0=t0.v_W_B + rng.normal(0, 0.3, 3),
                 q0_xyzw=t0.q_W_B_xyzw, P0=P0)  # fmt: skip
    est = DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=IMU_NS, max_delay_ns=40_000_000), t0_ns=0
    )
    err, sig = [], []
    iv = NAV_ERROR["vel"]
    for tr in truths[1:]:
        t = tr.t_ns
        if flow:
            s = sensor.sample(tr, t, rng)
            if s is not None:
                line.push(s)
            for _, arrived in line.pop_arrived(t):
                est.push(arrived)
        if t % 50_000_000 == 0:
            est.push(HeightSample(t_ns=t, z_m=tr.p_W_B[2] + rng.normal(0, 0.02), sigma_m=0.02, source="height"))  # fmt: skip
        sample = imu.accumulate(tr, STEP_NS * 1e-9, rng)
        if sample is None:
            continue
        est.push(sample)
        if est.t_delayed_ns >= 2_000_000_000 and t % 20_000_000 == 0:
            d = est.delayed()
            err.append(d.v_W_B[:2] - truths[d.t_ns // STEP_NS].v_W_B[:2])
            sig.append(ekf.P[iv, iv][:2, :2].copy())
    return Run(np.array(err), np.array(sig), est)


SEEDS = range(5)


@pytest.fixture(scope="module")
def flow_runs() -> list[Run]:
    return [fly(seed, flow=True) for seed in SEEDS]


def test_flow_keeps_the_horizontal_velocity_error_small_and_bounded(flow_runs: list[Run]) -> None:
    rms = [float(np.sqrt(np.mean(np.sum(r.v_err**2, axis=1)))) for r in flow_runs]
    worst = [float(np.max(np.linalg.norm(r.v_err, axis=1))) for r in flow_runs]
    print(f"flow: horizontal velocity RMSE per seed {np.round(rms, 3)}, max {np.round(worst, 3)}")
    assert max(rms) < 0.05
    assert max(worst) < 0.15
    # bounded: the last quarter is no worse than the whole
    late = [
        float(np.sqrt(np.mean(np.sum(r.v_err[-len(r.v_err) // 4 :] ** 2, axis=1))))
        for r in flow_runs
    ]
    assert np.mean(late) < 1.5 * np.mean(rms)
    for r in flow_runs:
        st = r.est.stats("flow")
        assert st.fused >= 0.95 * st.received > 0


def test_with_the_sensor_s_own_noise_the_velocity_nees_is_consistent() -> None:
    # PX4's default noise (0.15 rad/s) is three times the simulated sensor's: conservative.
    # Told the sensor's 0.05 rad/s, the filter's horizontal-velocity NEES (2 dof) should
    # average about 2; the IMU averaging and the flow's rectangle integration make it lower.
    nees = []
    for seed in range(4):
        r = fly(100 + seed, flow=True, seconds=10.0, flow_noise_rad_s=0.05)
        nees.append(np.einsum("ni,nij,nj->n", r.v_err, np.linalg.inv(r.v_cov), r.v_err))
    mean = float(np.mean(np.concatenate(nees)))
    print(f"flow: mean horizontal-velocity NEES {mean:.2f} (2 dof)")
    assert 0.5 < mean < 4.0


def test_without_flow_the_same_flights_drift(flow_runs: list[Run]) -> None:
    for seed, with_flow in zip(SEEDS[:2], flow_runs[:2], strict=False):
        blind = fly(seed, flow=False)
        e_blind = float(np.sqrt(np.mean(np.sum(blind.v_err**2, axis=1))))
        e_flow = float(np.sqrt(np.mean(np.sum(with_flow.v_err**2, axis=1))))
        assert e_blind > 4 * e_flow


def _flow(t_ns: int, *, quality: int, rate: float = 0.0) -> FlowSample:
    return FlowSample(t_ns=t_ns, integration_ns=20_000_000, flow_rad=[0.02 * rate, 0.0],
                      gyro_rad=[0.0, 0.0, 0.0], quality=quality)  # fmt: skip


def _hover(z: float, **config: float) -> tuple[NavEkf, DelayedHorizonEstimator]:
    ekf = NavEkf(NavEkfConfig(gravity_m_s2=G, **config), p0=np.array([0.0, 0.0, z]), v0=np.zeros(3),
                 q0_xyzw=np.array([0.0, 0.0, 0.0, 1.0]), P0=np.eye(15) * 1e-4)  # fmt: skip
    est = DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=IMU_NS, max_delay_ns=40_000_000), t0_ns=0
    )
    return ekf, est


def _push_hover(est: DelayedHorizonEstimator, samples: list[FlowSample]) -> None:
    by_t = {s.t_ns: s for s in samples}
    for k in range(1, 200):
        t = k * IMU_NS
        if t in by_t:
            est.push(by_t[t])
        est.push(ImuSample(t_ns=t, gyro_rad_s=np.zeros(3), accel_m_s2=np.array([0.0, 0.0, G])))


def test_bad_flow_samples_are_rejected_and_counted_never_raised() -> None:
    ekf, est = _hover(1.0)
    assert not ekf.can_fuse(_flow(0, quality=0))  # below EKF2_OF_QMIN
    assert not ekf.can_fuse(_flow(0, quality=255, rate=9.0))  # beyond SENS_FLOW_MAXR
    assert ekf.can_fuse(_flow(0, quality=1))
    _push_hover(est, [_flow(IMU_NS * k, quality=0) for k in range(10, 20)]
                + [_flow(IMU_NS * k, quality=200, rate=9.0) for k in range(30, 35)]
                + [_flow(IMU_NS * k, quality=200) for k in range(50, 60)])  # fmt: skip
    st = est.stats("flow")
    assert (st.received, st.rejected_unsupported, st.fused) == (25, 15, 10)


def test_flow_whose_compensated_rate_is_too_fast_is_not_fused() -> None:
    _, est = _hover(1.0, flow_gate_sigma=1e4)  # no innovation gate would stop it
    spin = [FlowSample(t_ns=IMU_NS * k, integration_ns=20_000_000, flow_rad=[0.0, 0.0],
                       gyro_rad=[0.2, 0.0, 0.0], quality=255) for k in range(10, 20)]  # fmt: skip
    _push_hover(est, spin)  # 10 rad/s of flow against the sensor's gyro: beyond 8 rad/s
    st = est.stats("flow")
    assert st.received == 10 and st.fused == 0 and st.rejected_gate == 10


def test_flow_is_not_fused_below_its_minimum_height() -> None:
    _, est = _hover(0.2)  # 0.2 m over the floor: below 0.3 m
    _push_hover(est, [_flow(IMU_NS * k, quality=255) for k in range(10, 20)])
    st = est.stats("flow")
    assert st.received == 10 and st.fused == 0 and st.rejected_gate == 10
