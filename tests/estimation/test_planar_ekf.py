from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from quadnav.errors import EstimationError
from quadnav.estimation import PlanarEkf, PlanarEkfConfig, PlanarKinematics, planar_jacobians
from quadnav.messages import ImuSample, PositionSample

DT = 0.01


def f(kin: PlanarKinematics, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The prediction as a function of state and input u = [f_x, f_z, w]."""
    pos, vel, att = kin.integrate(
        x[0:2], x[2:4], x[4:5], np.array([0.0, u[2], 0.0]), np.array([u[0], 0.0, u[1]]), DT
    )
    return np.concatenate([pos, vel, att])


def central_diff(fun, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for k in range(len(x)):
        d = np.zeros_like(x)
        d[k] = eps
        cols.append((fun(x + d) - fun(x - d)) / (2 * eps))
    return np.column_stack(cols)


angles = st.floats(-3.0, 3.0)
values = st.floats(-20.0, 20.0)


@given(
    st.tuples(values, values, values, values, angles).map(np.array),
    st.tuples(values, values, st.floats(-5.0, 5.0)).map(np.array),
    st.sampled_from(["specific_force", "kinematic"]),
)
@settings(max_examples=60)
def test_jacobians_match_central_differences(x: np.ndarray, u: np.ndarray, model: str) -> None:
    kin = PlanarKinematics(9.8, model)  # type: ignore[arg-type]
    F, G = planar_jacobians(x, u[2], u[0:2], DT, kin=kin)
    np.testing.assert_allclose(F, central_diff(lambda xx: f(kin, xx, u), x), atol=1e-7)
    np.testing.assert_allclose(G, central_diff(lambda uu: f(kin, x, uu), u), atol=1e-7)


def test_gravity_is_compensated_only_for_a_specific_force_accelerometer() -> None:
    hover = np.array([0.0, 0.0, 9.8])
    zero = np.zeros(3)
    real = PlanarKinematics(9.8, "specific_force")
    kin = PlanarKinematics(9.8, "kinematic")
    _, v_real, _ = real.integrate(np.zeros(2), np.zeros(2), np.zeros(1), zero, hover, DT)
    _, v_kin, _ = kin.integrate(np.zeros(2), np.zeros(2), np.zeros(1), zero, zero, DT)
    np.testing.assert_allclose(v_real, 0.0, atol=1e-15)
    np.testing.assert_allclose(v_kin, 0.0, atol=1e-15)


def test_batched_integration_matches_single_rows() -> None:
    rng = np.random.default_rng(0)
    kin = PlanarKinematics()
    pos, vel, att = rng.normal(size=(7, 2)), rng.normal(size=(7, 2)), rng.normal(size=(7, 1))
    gyro, accel = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
    dt = rng.uniform(0.001, 0.02, 7)
    batch = kin.integrate(pos, vel, att, gyro, accel, dt)
    for i in range(7):
        single = kin.integrate(pos[i], vel[i], att[i], gyro[i], accel[i], float(dt[i]))
        for b, s in zip(batch, single, strict=True):
            np.testing.assert_allclose(b[i], s, atol=1e-14)


def make_ekf(**cfg: object) -> PlanarEkf:
    return PlanarEkf(PlanarEkfConfig(**cfg), x0=np.zeros(5), P0=np.diag([1.0, 1.0, 0.1, 0.1, 0.01]))  # type: ignore[arg-type]


def test_update_uses_joseph_form_and_keeps_covariance_healthy() -> None:
    # Very precise fixes are where the simple (I - KH) P form loses symmetry and definiteness.
    ekf = make_ekf(gate_probability=None)
    rng = np.random.default_rng(2)
    for k in range(200):
        ekf.predict(
            ImuSample(t_ns=k, gyro_rad_s=rng.normal(0, 0.1, 3), accel_m_s2=[0.3, 0, 9.8]), DT
        )
        if k % 10 == 0:
            before = np.trace(ekf.P[0:2, 0:2])
            res = ekf.fuse(PositionSample(t_ns=k, p_W_B=rng.normal(0, 0.01, 3), sigma_m=1e-4))
            assert res.accepted
            assert np.trace(ekf.P[0:2, 0:2]) < before
            # After a very precise fix the position variance is at most the fix's (1e-8 m^2).
            assert ekf.P[0, 0] <= 1e-8
        np.testing.assert_array_equal(ekf.P, ekf.P.T)
        assert np.min(np.linalg.eigvalsh(ekf.P)) > 0.0


def test_gate_threshold_is_the_chi_square_quantile() -> None:
    ekf = make_ekf(gate_probability=0.99)
    # P = 1 m^2 per axis, R = 0 + (1e-3)^2: S ~ 1. chi2(2) 99% quantile = 9.21.
    inside = ekf.fuse(PositionSample(t_ns=0, p_W_B=[2.9, 0.0, 0.0], sigma_m=1e-3))
    assert inside.accepted and inside.test_ratio == pytest.approx(2.9**2 / 9.2103, rel=1e-3)
    ekf2 = make_ekf(gate_probability=0.99)
    outside = ekf2.fuse(PositionSample(t_ns=0, p_W_B=[3.1, 0.0, 0.0], sigma_m=1e-3))
    assert not outside.accepted and outside.test_ratio > 1.0
    np.testing.assert_array_equal(ekf2.x, np.zeros(5))


def test_no_gate_fuses_anything() -> None:
    ekf = make_ekf(gate_probability=None)
    assert ekf.fuse(PositionSample(t_ns=0, p_W_B=[1e3, 0.0, 0.0], sigma_m=1e-3)).accepted


def test_bad_configuration_and_input() -> None:
    with pytest.raises(EstimationError):
        PlanarEkfConfig(accel_sigma_m_s2=0.0)
    with pytest.raises(EstimationError):
        PlanarEkfConfig(gate_probability=1.0)
    with pytest.raises(EstimationError, match="positive semi-definite"):
        PlanarEkf(PlanarEkfConfig(), x0=np.zeros(5), P0=-np.eye(5))
    with pytest.raises(EstimationError, match="x0"):
        PlanarEkf(PlanarEkfConfig(), x0=np.zeros(4), P0=np.eye(5))
    with pytest.raises(EstimationError, match="PositionSample"):
        make_ekf().fuse(ImuSample(t_ns=0, gyro_rad_s=[0, 0, 0], accel_m_s2=[0, 0, 0]))  # type: ignore[arg-type]
