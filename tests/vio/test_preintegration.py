"""IMU preintegration: GTSAM's combined measurements from our samples and the rig's densities."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from quadnav.errors import VioError
from quadnav.messages import ImuSample
from quadnav.rig import ImuNoiseModel
from quadnav.units import GRAVITY_M_S2
from quadnav.vio.preintegration import imu_params, preintegrate


def _samples(w: np.ndarray, a_B: np.ndarray, n: int, dt_ns: int) -> list[ImuSample]:
    return [ImuSample(t_ns=k * dt_ns, gyro_rad_s=w, accel_m_s2=a_B) for k in range(n)]


def test_constant_rate_and_thrust_give_the_closed_form_deltas() -> None:
    # at rest the accelerometer reads +g up: the prediction must stay put
    params = imu_params(ImuNoiseModel.euroc_adis16448())
    rest = _samples(np.zeros(3), np.array([0.0, 0.0, GRAVITY_M_S2]), 401, 5_000_000)
    pim = preintegrate(params, rest, 0, 2_000_000_000)
    assert pim.deltaTij() == pytest.approx(2.0)
    nav = pim.predict(gtsam.NavState(), gtsam.imuBias.ConstantBias())
    assert np.linalg.norm(nav.position()) < 1e-9
    # a constant yaw rate: the rotation after 2 s is 2 w about z
    spin = _samples(np.array([0.0, 0.0, 0.3]), np.array([0.0, 0.0, GRAVITY_M_S2]), 401, 5_000_000)
    R = preintegrate(params, spin, 0, 2_000_000_000).deltaRij()
    assert np.allclose(R.ypr()[0], 0.6, atol=1e-9)


def test_spans_cut_between_samples_add_up_to_the_whole() -> None:
    params = imu_params(ImuNoiseModel.euroc_adis16448())
    rng = np.random.default_rng(3)
    samples = [
        ImuSample(
            t_ns=k * 5_000_000, gyro_rad_s=rng.normal(0, 0.5, 3), accel_m_s2=rng.normal(0, 3, 3)
        )
        for k in range(200)
    ]
    whole = preintegrate(params, samples, 1_000_000, 900_000_000)
    a = preintegrate(params, samples, 1_000_000, 437_000_000)
    b = preintegrate(params, samples, 437_000_000, 900_000_000)
    assert a.deltaTij() + b.deltaTij() == pytest.approx(whole.deltaTij())
    R = a.deltaRij().compose(b.deltaRij())
    # GTSAM integrates on the tangent space: first-order close (dropping the 2 ms the cut
    # splits would be 1e-3 rad off)
    assert np.allclose(R.matrix(), whole.deltaRij().matrix(), atol=2e-5)


def test_a_changing_rate_is_integrated_without_lag() -> None:
    """Samples of a yaw rate and a thrust growing linearly (each the value at its time): the
    rotation and velocity after 1 s are the integrals, c T^2 / 2, exactly; holding each sample
    until the next (GTSAM's rule) lags half a sample, 2.5e-3 rad and m/s here."""
    params = imu_params(ImuNoiseModel.euroc_adis16448())
    dt_ns, c = 5_000_000, 1.0
    samples = [
        ImuSample(
            t_ns=k * dt_ns,
            gyro_rad_s=np.array([0.0, 0.0, c * k * dt_ns * 1e-9]),
            accel_m_s2=np.array([0.0, 0.0, GRAVITY_M_S2 + c * k * dt_ns * 1e-9]),
        )
        for k in range(300)
    ]
    pim = preintegrate(params, samples, 0, 1_000_000_000)
    assert pim.deltaRij().ypr()[0] == pytest.approx(0.5, abs=1e-9)
    # the velocity rotates with the yaw but stays along z: its norm is the thrust's integral
    v = pim.predict(gtsam.NavState(), gtsam.imuBias.ConstantBias()).velocity()
    assert float(np.linalg.norm(v)) == pytest.approx(0.5, abs=1e-9)
    # a span cut between samples: the same
    yaw = float(preintegrate(params, samples, 2_500_000, 1_002_500_000).deltaRij().ypr()[0])
    assert yaw == pytest.approx(0.5 * (1.0025**2 - 0.0025**2), abs=1e-9)


def test_a_span_the_imu_does_not_cover_is_refused() -> None:
    params = imu_params(ImuNoiseModel.euroc_adis16448())
    samples = _samples(np.zeros(3), np.array([0.0, 0.0, 9.8]), 10, 5_000_000)
    with pytest.raises(VioError, match="does not cover"):
        preintegrate(params, samples, 0, 500_000_000)
    with pytest.raises(VioError, match="g_norm"):
        imu_params(ImuNoiseModel.euroc_adis16448(), g_norm=1.0)
