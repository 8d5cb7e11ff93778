"""The IMU's white noise measured in flight (``vio/imu_noise.py``) and its use by the VIO."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.rig import rig_named
from quadnav.units import NS_PER_S
from quadnav.vio import VioEstimator
from quadnav.vio.config import VioConfig
from quadnav.vio.imu_noise import ImuNoiseMonitor, MeasuredNoise
from quadnav.vio.preintegration import imu_params
from tests.shared_data import SHARED, needs

RATE = 200.0
STEP_NS = 5_000_000
EUROC_IMU = SHARED / "euroc_micro" / "mav0" / "imu0" / "data.csv"


def _feed(m: ImuNoiseMonitor, gyro: np.ndarray, accel: np.ndarray, t0_ns: int = 0) -> None:
    for k in range(len(gyro)):
        m.push(t0_ns + k * STEP_NS, gyro[k], accel[k])


def _white(rng: np.random.Generator, n: int, gyro_d: float, accel_d: float) -> tuple:
    s = np.sqrt(RATE)
    return gyro_d * s * rng.standard_normal((n, 3)), accel_d * s * rng.standard_normal((n, 3))


def test_white_noise_density_is_recovered_over_seeds() -> None:
    """EuRoC's in-flight levels (2.8e-3, 0.062), 2 s windows, 20 seeds: every estimate within
    15 % of the truth per axis, their mean within 3 %."""
    gyro_d, accel_d = 2.8e-3, 0.062
    ests = []
    for seed in range(20):
        m = ImuNoiseMonitor(window_s=2.0, rate_hz=RATE)
        g, a = _white(np.random.default_rng(seed), 1000, gyro_d, accel_d)
        _feed(m, g, a)
        n = m.noise()
        assert n is not None and n.samples == 400
        ests.append(np.concatenate([n.gyro / gyro_d, n.accel / accel_d]))
    r = np.array(ests)
    assert np.all(np.abs(r - 1.0) < 0.15), r
    assert np.all(np.abs(r.mean(axis=0) - 1.0) < 0.03), r.mean(axis=0)


def test_fast_motion_does_not_read_as_noise() -> None:
    """A hard manoeuvre (3 rad/s at 2 Hz, 8 m/s^2 at 3 Hz) under the noise: the estimate moves
    by under 2 %; without noise it reads under 10 % of EuRoC's in-flight level (under 1 %
    added in quadrature)."""
    t = np.arange(2000) / RATE
    gyro_m = 3.0 * np.sin(2 * np.pi * 2.0 * t)[:, None] * np.ones(3)
    accel_m = 8.0 * np.sin(2 * np.pi * 3.0 * t)[:, None] * np.ones(3) + [0, 0, 9.81]
    g, a = _white(np.random.default_rng(3), 2000, 2.8e-3, 0.062)
    quiet, moving, motion_only = (ImuNoiseMonitor(10.0, RATE) for _ in range(3))
    _feed(quiet, g, a)
    _feed(moving, g + gyro_m, a + accel_m)
    _feed(motion_only, gyro_m, accel_m)
    q, mv, mo = quiet.noise(), moving.noise(), motion_only.noise()
    assert q is not None and mv is not None and mo is not None
    assert np.allclose(mv.gyro, q.gyro, rtol=0.02) and np.allclose(mv.accel, q.accel, rtol=0.02)
    assert np.all(mo.gyro < 0.1 * 2.8e-3) and np.all(mo.accel < 0.1 * 0.062)


def test_a_touchdown_shock_is_not_read_as_noise() -> None:
    """A touchdown at 2 m/s (one accelerometer reading of 290 m/s^2 and a gyro kick, as
    ``outdoor_vio_gps_realistic``'s simulated vehicle reads it) in a 2 s window of EuRoC's
    in-flight noise, 20 seeds: every estimate within 25 % of the noise, the mean within 15 %
    (the shock touches three differences, each capped at 16 times the typical: about +6 % in
    density on 400; the mean of the squares made it about 300 times)."""
    gyro_d, accel_d = 2.8e-3, 0.062
    shock = []
    for seed in range(20):
        g, a = _white(np.random.default_rng(seed), 800, gyro_d, accel_d)
        a[700, 2] += 290.0
        a[701, 2] -= 20.0
        g[700] += 2.0
        m = ImuNoiseMonitor(window_s=2.0, rate_hz=RATE)
        _feed(m, g, a)
        n = m.noise()
        assert n is not None
        shock.append(np.concatenate([n.gyro / gyro_d, n.accel / accel_d]))
    r = np.array(shock)
    assert np.all(np.abs(r - 1.0) < 0.25), r.max(axis=0)
    assert np.all(np.abs(r.mean(axis=0) - 1.0) < 0.15), r.mean(axis=0)


@pytest.mark.parametrize("flying_s", [0.2, 0.5, 1.0])
def test_the_noise_s_rise_at_take_off_is_not_capped(flying_s: float) -> None:
    """A take-off: the datasheet's noise on the ground, then EuRoC's rotors (16x the gyro's,
    31x the accelerometer's) over the window's last ``flying_s``, 20 seeds: the mean estimate
    within 10 % of the window's RMS noise. A cap that followed the whole window's median alone
    read 2.6x and 2.8x (a quarter of the window in flight) for about a second."""
    gyro_d, accel_d = 1.8e-4, 2.0e-3  # EuRoC's ADIS16448 datasheet
    k = 800 - round(flying_s * RATE)
    share = flying_s / 2.0
    truth = np.array([gyro_d * np.sqrt(1 - share + share * 16**2)] * 3
                     + [accel_d * np.sqrt(1 - share + share * 31**2)] * 3)  # fmt: skip
    est = []
    for seed in range(20):
        g, a = _white(np.random.default_rng(seed), 800, gyro_d, accel_d)
        g[k:] *= 16.0
        a[k:] *= 31.0
        m = ImuNoiseMonitor(window_s=2.0, rate_hz=RATE)
        _feed(m, g, a)
        n = m.noise()
        assert n is not None
        est.append(np.concatenate([n.gyro, n.accel]) / truth)
    assert np.all(np.abs(np.mean(est, axis=0) - 1.0) < 0.1), np.mean(est, axis=0)


def test_readings_quantised_to_one_value_are_not_capped_to_nothing() -> None:
    """An axis whose readings mostly repeat (a quantised, quiet sensor: most second
    differences exactly zero) is read from the rest, not capped to zero."""
    rng = np.random.default_rng(4)
    g = np.zeros((800, 3))
    a = np.zeros((800, 3))
    a[rng.random(800) < 0.1, 0] = 0.01  # a one-LSB flicker on x, a tenth of the time
    m = ImuNoiseMonitor(window_s=2.0, rate_hz=RATE)
    _feed(m, g, a)
    n = m.noise()
    assert n is not None and n.accel[0] > 0.0 and n.accel[1] == 0.0


def test_gaps_bad_samples_and_too_few_readings() -> None:
    """A jump across a 1 s gap, a NaN and a repeated stamp do not enter the differences; fewer
    than the minimum readings give no estimate."""
    rng = np.random.default_rng(5)
    m = ImuNoiseMonitor(window_s=5.0, rate_hz=RATE)
    g, a = _white(rng, 50, 2.8e-3, 0.062)
    _feed(m, g, a)
    assert m.noise() is None  # 48 differences
    m.push(49 * STEP_NS, np.full(3, np.nan), np.zeros(3))
    m.push(49 * STEP_NS, np.full(3, 100.0), np.zeros(3))  # a repeated stamp
    g2, a2 = _white(rng, 400, 2.8e-3, 0.062)
    _feed(m, g2 + 5.0, a2 - 30.0, t0_ns=50 * STEP_NS + 1_000_000_000)  # after a gap, offset
    n = m.noise()
    assert n is not None and n.samples == 48 + 398
    assert np.all(np.abs(n.gyro / 2.8e-3 - 1) < 0.15) and np.all(np.abs(n.accel / 0.062 - 1) < 0.15)


@pytest.mark.parametrize("kw", [{"window_s": 0.0}, {"rate_hz": float("nan")}])
def test_bad_settings_are_refused(kw: dict[str, float]) -> None:
    with pytest.raises(ValueError, match=next(iter(kw))):
        ImuNoiseMonitor(**kw)


@needs(EUROC_IMU)
def test_euroc_real_imu_in_flight_and_on_the_ground() -> None:
    """EuRoC V1_01's real ADIS16448: in flight (10-140 s) the estimate is of the order VINS-Mono's
    EuRoC configuration was tuned to (gyr_n 0.004, acc_n 0.08: within a factor 1.5), 10x over
    the datasheet's; standing before take-off (1.5-3.5 s) over 3x quieter than in flight."""
    d = np.loadtxt(EUROC_IMU, delimiter=",", comments="#")
    t = (d[:, 0] - d[0, 0]) / NS_PER_S

    def measured(t0: float, t1: float) -> MeasuredNoise:
        m = ImuNoiseMonitor(window_s=t1 - t0, rate_hz=RATE)
        for r in d[(t >= t0) & (t < t1)]:
            m.push(int(r[0]), r[1:4], r[4:7])
        n = m.noise()
        assert n is not None
        return n

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x**2)))

    flight, ground = measured(10.0, 140.0), measured(1.5, 3.5)
    assert 0.004 / 1.5 < rms(flight.gyro) < 0.004 * 1.5
    assert 0.08 / 1.5 < rms(flight.accel) < 0.08 * 1.5
    assert rms(flight.gyro) > 10 * 1.6968e-4 and rms(flight.accel) > 10 * 2.0e-3
    assert rms(flight.gyro) > 3 * rms(ground.gyro) and rms(flight.accel) > 3 * rms(ground.accel)


def test_the_preintegration_takes_the_larger_noise_per_axis() -> None:
    """Measured noise above the stated one on some axes: those axes take it, the others keep
    the stated one; the VIO's setting switches the measurement off."""
    rig = rig_named("euroc_mono")
    assert rig.imu is not None
    n = rig.imu.noise
    measured = MeasuredNoise(
        gyro=np.array([10 * n.gyro_noise_density, 0.5 * n.gyro_noise_density, 0.0]),
        accel=np.array([0.0, 30 * n.accel_noise_density, 0.0]),
        samples=400,
    )
    p = imu_params(n, measured=measured)
    g, a = np.diag(p.getGyroscopeCovariance()), np.diag(p.getAccelerometerCovariance())
    assert np.allclose(np.sqrt(g), [10 * n.gyro_noise_density] + [n.gyro_noise_density] * 2)
    assert np.allclose(np.sqrt(a), n.accel_noise_density * np.array([1.0, 30.0, 1.0]))
    assert VioEstimator(rig).noise_monitor is not None
    assert VioEstimator(rig, VioConfig(imu_noise_online=False)).noise_monitor is None
