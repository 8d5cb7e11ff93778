from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import EstimationError
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig, nav_jacobians, yaw_jacobian, yaw_of

G = 9.81


def step(R, v, p, bg, ba, w_m, f_m, dt, n=None):
    """The filter's nominal prediction, with optional IMU noise n = (n_g, n_a)."""
    n = np.zeros(6) if n is None else n
    w = w_m - bg - n[0:3]
    f = f_m - ba - n[3:6]
    R2 = R @ Rotation.from_rotvec(w * dt).as_matrix()
    v2 = v + dt * (R2 @ f + [0, 0, -G])
    return R2, v2, p + dt * v2


def boxminus(a, b):
    """Error-state difference a - b (attitude as Log(R_b^T R_a))."""
    Ra, va, pa, bga, baa = a
    Rb, vb, pb, bgb, bab = b
    return np.concatenate(
        [Rotation.from_matrix(Rb.T @ Ra).as_rotvec(), va - vb, pa - pb, bga - bgb, baa - bab]
    )


@pytest.mark.parametrize("seed", range(4))
def test_transition_jacobians_match_finite_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    v, p = rng.normal(size=3), rng.normal(size=3)
    bg, ba = 0.01 * rng.normal(size=3), 0.1 * rng.normal(size=3)
    w_m, f_m = rng.normal(0, 1.0, 3), rng.normal([0, 0, G], 2.0)
    dt = 0.004
    R2, v2, p2 = step(R, v, p, bg, ba, w_m, f_m, dt)
    nominal_after = (R2, v2, p2, bg, ba)
    F, Gm = nav_jacobians(R2, f_m - ba, w_m - bg, dt)
    eps = 1e-6
    F_num = np.zeros((15, 15))
    for k in range(15):
        cols = []
        for sgn in (1.0, -1.0):
            d = np.zeros(15)
            d[k] = sgn * eps
            Rt = R @ Rotation.from_rotvec(d[0:3]).as_matrix()
            st = step(Rt, v + d[3:6], p + d[6:9], bg + d[9:12], ba + d[12:15], w_m, f_m, dt)
            cols.append(boxminus((*st, bg + d[9:12], ba + d[12:15]), nominal_after))
        F_num[:, k] = (cols[0] - cols[1]) / (2 * eps)
    # First-order model of the step (right Jacobian of Exp taken as I): error O(|w| dt) relative.
    np.testing.assert_allclose(F, F_num, atol=2e-5)
    G_num = np.zeros((15, 6))
    for k in range(6):
        cols = []
        for sgn in (1.0, -1.0):
            n = np.zeros(6)
            n[k] = sgn * eps
            st = step(R, v, p, bg, ba, w_m, f_m, dt, n)
            cols.append(boxminus((*st, bg, ba), nominal_after))
        G_num[:, k] = (cols[0] - cols[1]) / (2 * eps)
    np.testing.assert_allclose(Gm[:, 0:6], G_num, atol=2e-5)


@pytest.mark.parametrize("seed", range(5))
def test_yaw_jacobian_matches_finite_differences(seed: int) -> None:
    R = Rotation.from_euler(
        "ZYX", np.random.default_rng(seed).uniform([-3, -0.6, -0.6], [3, 0.6, 0.6])
    ).as_matrix()
    eps = 1e-7
    num = [
        (
            yaw_of(R @ Rotation.from_rotvec(d).as_matrix())
            - yaw_of(R @ Rotation.from_rotvec(-d).as_matrix())
        )
        / (2 * eps)
        for d in np.eye(3) * eps
    ]
    np.testing.assert_allclose(yaw_jacobian(R), num, atol=1e-6)


def test_config_and_covariance_are_validated() -> None:
    with pytest.raises(EstimationError):
        NavEkfConfig(gyro_sigma_rad_s=0.0)
    with pytest.raises(EstimationError, match="P0"):
        NavEkf(NavEkfConfig(), p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=[0, 0, 0, 1], P0=-np.eye(15))


def hover_stream(jump_at_s: float, *, with_reset: bool, seconds: float = 6.0):
    """A vehicle hovering still at the origin: IMU (250 Hz) and vision poses (30 Hz). From
    ``jump_at_s`` the vision frame moves by (1, 0.5, 0) m and 0.3 rad of yaw."""
    from quadnav.messages import ImuSample, PoseSample

    rng = np.random.default_rng(0)
    out = []
    t, next_v = 0, 0
    while t < seconds * 1e9:
        t += 4_000_000
        if t >= next_v:
            next_v += 33_333_333
            jumped = t >= jump_at_s * 1e9
            p = np.array([1.0, 0.5, 0.0]) if jumped else np.zeros(3)
            q = Rotation.from_euler("z", 0.3 if jumped else 0.0).as_quat()
            out.append(PoseSample(t_ns=t, p_W_B=p + rng.normal(0, 0.005, 3), q_W_B_xyzw=q, sigma_pos_m=0.01, sigma_yaw_rad=0.01,
                                  reset_counter=1 if (jumped and with_reset) else 0))  # fmt: skip
        out.append(
            ImuSample(
                t_ns=t,
                gyro_rad_s=rng.normal(0, 0.002, 3),
                accel_m_s2=[0.0, 0.0, G] + rng.normal(0, 0.02, 3),
            )
        )
    return out


def hover_estimator():
    from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig

    ekf = NavEkf(
        NavEkfConfig(), p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=[0, 0, 0, 1.0], P0=np.eye(15) * 1e-4
    )
    return ekf, DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=100_000_000), t0_ns=0
    )


def test_a_vision_frame_jump_with_a_reset_counter_is_not_motion() -> None:
    ekf, est = hover_estimator()
    worst = 0.0
    for s in hover_stream(2.0, with_reset=True):
        est.push(s)
        worst = max(worst, float(np.linalg.norm(est.output_nav().pos)))
    assert worst < 0.03  # no jump in the output
    assert est.stats("vision").rejected_gate == 0
    assert any("re-anchored" in e for _, e in ekf.events)


def test_a_persistently_rejected_source_resets_the_state_and_says_so() -> None:
    ekf, est = hover_estimator()
    for s in hover_stream(2.0, with_reset=False):
        est.push(s)
    stats = est.stats("vision")
    assert stats.rejected_gate >= 50  # about 2 s of 30 Hz poses were gated out first
    assert any("position and heading reset" in e for _, e in ekf.events)
    np.testing.assert_allclose(
        ekf.p[0:2], [1.0, 0.5], atol=0.05
    )  # then it follows the sensor again


def test_gps_and_magnetometer_pull_position_and_heading_onto_the_truth() -> None:
    """A still vehicle at (3, -2, 1) m facing 0.4 rad; the filter starts at the origin facing
    0.2 rad and must find both from GNSS fixes and the magnetometer."""
    import pymap3d

    from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig
    from quadnav.messages import GpsSample, ImuSample
    from quadnav.sim.sensors import MagSensor

    datum = (47.397742, 8.545594, 488.0)
    p_true, yaw_true = np.array([3.0, -2.0, 1.0]), 0.4
    R_true = Rotation.from_euler("z", yaw_true)
    ekf = NavEkf(
        NavEkfConfig(datum_lla=datum, mag_declination_rad=0.05),
        p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=Rotation.from_euler("z", 0.2).as_quat(),
        P0=np.diag([1e-4, 1e-4, 0.3**2] + [0.1**2] * 3 + [5.0**2] * 3 + [1e-4] * 3 + [1e-3] * 3),
    )  # fmt: skip
    est = DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=200_000_000), t0_ns=0
    )
    mag = MagSensor(period_ns=20_000_000, declination_rad=0.05, noise_sigma=0.002)
    rng = np.random.default_rng(1)
    from quadnav.messages import VehicleState

    truth = VehicleState(
        t_ns=0,
        p_W_B=p_true,
        v_W_B=np.zeros(3),
        a_W_B=np.zeros(3),
        q_W_B_xyzw=R_true.as_quat(),
        w_B=np.zeros(3),
    )
    f_B = R_true.apply([0.0, 0.0, G], inverse=True)
    for k in range(1, 2500):  # 10 s
        t = k * 4_000_000
        if k % 50 == 0:
            lat, lon, alt = pymap3d.enu2geodetic(*(p_true + rng.normal(0, 0.3, 3)), *datum)
            est.push(GpsSample(t_ns=t, lat_deg=lat, lon_deg=lon, alt_m=alt, v_enu_m_s=rng.normal(0, 0.05, 3),
                               sigma_h_m=0.3, sigma_v_m=0.3, sigma_vel_m_s=0.05))  # fmt: skip
        m = mag.sample(truth, t, rng)
        if m is not None:
            est.push(m)
        est.push(
            ImuSample(
                t_ns=t, gyro_rad_s=rng.normal(0, 0.001, 3), accel_m_s2=f_B + rng.normal(0, 0.01, 3)
            )
        )
    np.testing.assert_allclose(ekf.p, p_true, atol=0.25)
    assert (
        abs(math.remainder(Rotation.from_matrix(ekf.R).as_euler("ZYX")[0] - yaw_true, 2 * math.pi))
        < 0.02
    )
    assert est.stats("gps").fused >= 45 and est.stats("mag").fused >= 450


def test_in_place_jacobians_match_the_reference() -> None:
    rng = np.random.default_rng(3)
    ekf = NavEkf(
        NavEkfConfig(), p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=[0, 0, 0, 1.0], P0=np.eye(15)
    )
    for _ in range(3):  # the first call sets the constant blocks, the others take the fast path
        R = Rotation.random(random_state=int(rng.integers(100))).as_matrix()
        f, w = rng.normal(size=3), rng.normal(size=3)
        F, G = ekf._jacobians_into(R, f, w, 0.004)
        F_ref, G_ref = nav_jacobians(R, f, w, 0.004)
        np.testing.assert_allclose(F, F_ref, atol=1e-15)
        np.testing.assert_allclose(G, G_ref, atol=1e-15)
