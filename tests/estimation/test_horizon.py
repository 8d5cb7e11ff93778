from __future__ import annotations

import numpy as np
import pytest

from quadnav.errors import EstimationError
from quadnav.estimation import HorizonConfig, PlanarEkf, imu_buffer_length, reintegration_floor
from quadnav.messages import ImuSample, PositionSample

from .conftest import DT_NS, Flight, fly, make_estimator


def test_buffer_length_follows_the_px4_rule() -> None:
    # Thesis 000 figure 2.1: a 30 ms delay on a 5 ms IMU needs 7 cells.
    assert imu_buffer_length(max_delay_ns=30_000_000, imu_period_ns=5_000_000) == 7
    assert imu_buffer_length(max_delay_ns=1_000_000_000, imu_period_ns=DT_NS) == 101
    assert imu_buffer_length(max_delay_ns=0, imu_period_ns=DT_NS) == 1
    # A delay between two ticks is rounded up so it still fits.
    assert imu_buffer_length(max_delay_ns=255_000_000, imu_period_ns=DT_NS) == 27
    with pytest.raises(EstimationError):
        imu_buffer_length(max_delay_ns=-1, imu_period_ns=DT_NS)
    with pytest.raises(EstimationError):
        HorizonConfig(imu_period_ns=DT_NS, max_delay_ns=0, tau_vel_s=0.0)


def run_with_fixes(est, flight: Flight, arrivals: dict[int, list[PositionSample]]):
    """Push IMU samples; before IMU sample i, push the fixes arriving at step i."""
    delayed, output = [], []
    for i, imu in enumerate(flight.imu, start=1):
        for fix in arrivals.get(i, []):
            est.push(fix)
        est.push(imu)
        delayed.append((est.t_delayed_ns, est.filter.x.copy()))
        output.append(est.output_nav())
    return delayed, output


def test_noise_free_flight_is_reproduced_at_both_horizons(clean_flight: Flight) -> None:
    """With exact IMU data and an exact start, both horizons sit on the truth at their own time."""
    est = make_estimator(clean_flight, max_delay_ns=1_000_000_000)
    delay_steps = 100
    arrivals = {i + delay_steps: [clean_flight.fix(i)] for i in range(0, 300, 30)}
    delayed, output = run_with_fixes(est, clean_flight, arrivals)
    assert est.buffer_length == 101
    for step, (t_d, x) in enumerate(delayed, start=1):
        expected_t_d = max(step - delay_steps, 0) * DT_NS
        assert t_d == expected_t_d
        np.testing.assert_allclose(x, clean_flight.truth_x(t_d // DT_NS), atol=1e-9)
    for step, nav in enumerate(output, start=1):
        assert nav.t_ns == step * DT_NS
        np.testing.assert_allclose(nav.pos, clean_flight.states[step].p_xz, atol=1e-9)
        np.testing.assert_allclose(nav.att[0], clean_flight.states[step].theta_rad, atol=1e-12)
    assert est.stats("gps").fused == 10


def test_fixes_are_fused_at_their_time_of_validity_with_a_non_integer_delay(
    clean_flight: Flight,
) -> None:
    """A 255 ms delay (25.5 IMU periods): fixes arrive between ticks and are still fused on time."""
    est = make_estimator(clean_flight, max_delay_ns=255_000_000)
    delay_ns = 255_000_000
    arrivals: dict[int, list[PositionSample]] = {}
    for i in range(0, 300, 7):
        arrival_ns = i * DT_NS + delay_ns
        step = -(-arrival_ns // DT_NS)  # first tick at or after the arrival
        arrivals.setdefault(step, []).append(clean_flight.fix(i))
    run_with_fixes(est, clean_flight, arrivals)
    assert est.stats("gps").rejected_too_old == 0
    assert len(est.fusion_log) == len(range(0, 300, 7))
    for rec in est.fusion_log:
        assert rec.t_fused_ns == rec.t_obs_ns
        assert rec.result.accepted


def test_time_of_validity_between_ticks_is_fused_at_the_nearest_tick(clean_flight: Flight) -> None:
    est = make_estimator(clean_flight, max_delay_ns=200_000_000)
    fixes = []
    for i, extra in ((10, 3_000_000), (20, 5_000_000), (30, 6_000_000)):
        f = clean_flight.fix(i)
        fixes.append(PositionSample(t_ns=f.t_ns + extra, p_W_B=f.p_W_B, sigma_m=f.sigma_m))
    run_with_fixes(est, clean_flight, {28: fixes})  # the horizon is at 80 ms then
    fused = {r.t_obs_ns: r.t_fused_ns for r in est.fusion_log}
    assert fused == {
        10 * DT_NS + 3_000_000: 10 * DT_NS,
        20 * DT_NS + 5_000_000: 20 * DT_NS,  # exactly half way: the earlier tick
        30 * DT_NS + 6_000_000: 31 * DT_NS,
    }


def test_out_of_order_arrival_gives_the_same_estimate() -> None:
    flight = fly(300, accel_sigma=0.2, gyro_sigma=0.02, seed=4)
    rng = np.random.default_rng(0)
    fixes = {
        i: PositionSample(
            t_ns=i * DT_NS,
            p_W_B=np.array([flight.states[i].p_xz[0], 0, flight.states[i].p_xz[1]])
            + rng.normal(0, 0.01, 3),
            sigma_m=0.01,
        )
        for i in range(0, 200, 10)
    }
    in_order = {i + 50: [fixes[i]] for i in fixes}
    # The same fixes, arriving in bunches in reverse order (all within the 0.8 s buffer).
    shuffled: dict[int, list[PositionSample]] = {}
    for i in fixes:
        shuffled.setdefault(60 + 60 * (i // 60), []).append(fixes[i])
    for v in shuffled.values():
        v.reverse()
    a = make_estimator(flight, max_delay_ns=800_000_000)
    b = make_estimator(flight, max_delay_ns=800_000_000)
    run_with_fixes(a, flight, in_order)
    run_with_fixes(b, flight, shuffled)
    assert [r.t_obs_ns for r in b.fusion_log] == sorted(fixes[i].t_ns for i in fixes)
    np.testing.assert_allclose(b.filter.x, a.filter.x, atol=1e-12)
    np.testing.assert_allclose(b.filter.P, a.filter.P, atol=1e-15)
    assert b.stats("gps").fused == a.stats("gps").fused == len(fixes)


def test_a_delay_larger_than_the_buffer_is_rejected_and_counted() -> None:
    flight = fly(300, accel_sigma=0.2, gyro_sigma=0.02, seed=5)
    late = make_estimator(flight, max_delay_ns=500_000_000)  # sized for 0.5 s
    imu_only = make_estimator(flight, max_delay_ns=500_000_000)
    arrivals = {i + 100: [flight.fix(i)] for i in range(0, 190, 30)}  # 1 s late
    run_with_fixes(late, flight, arrivals)
    run_with_fixes(imu_only, flight, {})
    stats = late.stats("gps")
    assert stats.received == 7
    assert stats.rejected_too_old == 7
    assert stats.fused == 0
    np.testing.assert_array_equal(late.filter.x, imu_only.filter.x)


def test_imu_samples_out_of_order_are_rejected_and_counted(clean_flight: Flight) -> None:
    est = make_estimator(clean_flight, max_delay_ns=100_000_000)
    ref = make_estimator(clean_flight, max_delay_ns=100_000_000)
    for k, imu in enumerate(clean_flight.imu[:100]):
        est.push(imu)
        ref.push(imu)
        if k % 10 == 5:
            est.push(imu)  # duplicate stamp
            est.push(
                ImuSample(t_ns=imu.t_ns - 5 * DT_NS, gyro_rad_s=[9, 9, 9], accel_m_s2=[9, 9, 9])
            )
    assert est.imu_rejected_out_of_order == 20
    np.testing.assert_array_equal(est.filter.x, ref.filter.x)
    np.testing.assert_array_equal(est.output_nav().pos, ref.output_nav().pos)


def test_output_predictor_is_pulled_onto_the_filter(clean_flight: Flight) -> None:
    """Start 0.5 m off; fixes correct the filter; the correction carries the output along."""
    offset = np.array([0.5, -0.3, 0.0, 0.0, 0.0])
    arrivals = {i + 20: [clean_flight.fix(i)] for i in range(0, 380, 5)}
    results = {}
    for correction in (True, False):
        est = make_estimator(
            clean_flight,
            max_delay_ns=200_000_000,
            x0_offset=offset,
            P0_sigma=1.0,
            output_correction=correction,
        )
        _, output = run_with_fixes(est, clean_flight, arrivals)
        err = np.array(
            [np.linalg.norm(o.pos - clean_flight.states[k].p_xz) for k, o in enumerate(output, 1)]
        )
        results[correction] = err
    # PX4's integral term leaves a slowly decaying tail after a step of 0.5 m.
    assert np.all(results[True][-50:] < 0.03)
    assert np.all(np.diff(results[True][-100:]) < 0)
    assert np.all(results[False][-50:] > 0.3)


def test_gate_rejects_an_outlier_and_counts_it(clean_flight: Flight) -> None:
    est = make_estimator(clean_flight, max_delay_ns=100_000_000)
    arrivals = {
        i + 10: [clean_flight.fix(i, sigma=0.01, offset=5.0 if i == 100 else 0.0)]
        for i in range(0, 300, 20)
    }
    delayed, _ = run_with_fixes(est, clean_flight, arrivals)
    stats = est.stats("gps")
    assert stats.rejected_gate == 1
    assert stats.fused == 14
    rejected = [r for r in est.fusion_log if not r.result.accepted]
    assert rejected[0].t_obs_ns == 100 * DT_NS and rejected[0].result.test_ratio > 1.0
    # The estimate was not dragged towards the outlier.
    for t_d, x in delayed:
        np.testing.assert_allclose(x[0], clean_flight.truth_x(t_d // DT_NS)[0], atol=1e-6)


def test_observation_overflow_keeps_the_newest(clean_flight: Flight) -> None:
    est = make_estimator(clean_flight, max_delay_ns=1_000_000_000, max_observations_per_source=3)
    for i in range(10):
        est.push(clean_flight.fix(i))
    assert est.stats("gps").dropped_overflow == 7
    run_with_fixes(est, clean_flight, {})
    assert [r.t_obs_ns for r in est.fusion_log] == [7 * DT_NS, 8 * DT_NS, 9 * DT_NS]


def test_floor_of_exact_states_is_the_truth(clean_flight: Flight) -> None:
    """Re-integrating true delayed states through exact IMU samples lands on the truth now."""
    n = len(clean_flight.imu) + 1
    x = np.array([clean_flight.truth_x(i) for i in range(n)])
    gyro = np.vstack([np.zeros(3), [s.gyro_rad_s for s in clean_flight.imu]])
    accel = np.vstack([np.zeros(3), [s.accel_m_s2 for s in clean_flight.imu]])
    start = np.maximum(np.arange(n) - 37, 0)
    est = make_estimator(clean_flight, max_delay_ns=0)
    pos, vel, att = reintegration_floor(
        est.kin,
        pos_d=x[start, 0:2],
        vel_d=x[start, 2:4],
        att_d=x[start, 4:5],
        start_idx=start,
        end_idx=np.arange(n),
        gyro=gyro,
        accel=accel,
        dt_s=np.full(n, 0.01),
    )
    np.testing.assert_allclose(pos, x[:, 0:2], atol=1e-9)
    np.testing.assert_allclose(vel, x[:, 2:4], atol=1e-9)
    np.testing.assert_allclose(att[:, 0], x[:, 4], atol=1e-12)
    with pytest.raises(EstimationError):
        reintegration_floor(
            est.kin,
            pos_d=x[:, 0:2],
            vel_d=x[:, 2:4],
            att_d=x[:, 4:5],
            start_idx=np.arange(n) + 1,
            end_idx=np.arange(n),
            gyro=gyro,
            accel=accel,
            dt_s=np.full(n, 0.01),
        )


def test_no_delay_means_one_horizon(clean_flight: Flight) -> None:
    est = make_estimator(clean_flight, max_delay_ns=0)
    for imu in clean_flight.imu[:50]:
        est.push(imu)
        assert est.t_delayed_ns == est.t_now_ns == imu.t_ns
    np.testing.assert_array_equal(est.output().p_W_B, est.delayed().p_W_B)
    assert est.output().P is None and est.delayed().P is not None


def test_samples_the_filter_cannot_use_are_counted_not_fatal(clean_flight: Flight) -> None:
    class GpsOnly(PlanarEkf):
        def can_fuse(self, obs: object) -> bool:
            return isinstance(obs, PositionSample) and obs.source == "gps"

    est = make_estimator(clean_flight, max_delay_ns=100_000_000)
    est.filter.__class__ = GpsOnly
    est.push(PositionSample(t_ns=0, p_W_B=[0, 0, 0], sigma_m=0.01, source="vision"))
    run_with_fixes(est, clean_flight, {5: [clean_flight.fix(0)]})
    assert est.stats("vision").rejected_unsupported == 1
    assert est.stats("vision").fused == 0
    assert est.stats("gps").fused == 1
    with pytest.raises(EstimationError, match="takes samples"):
        est.push({"t_ns": 0})  # type: ignore[arg-type]
