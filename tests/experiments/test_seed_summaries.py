"""Issue 21, item 12: every statistic over seeds is what its label says. The navigation study's
summary (printed "median over seeds") took the mean of the NEES and of the NIS shares; the
planar study's table "median over seeds" showed the NEES's mean. Seeds whose mean and median
differ (one bad seed) tell them apart."""

from __future__ import annotations

from quadnav.estimation.horizon import SourceStats
from quadnav.estimation.nav_filter import ImuCounts
from quadnav.eval.planar import PlanarMetrics, summarize_seeds
from quadnav.experiments.nav_study import NavMetrics, summarize_nav_seeds
from quadnav.experiments.planar_study import planar_table

# one bad seed: mean 11, median 2
NEES = (1.0, 2.0, 30.0)


def _nav(seed: int, nees: float, nis: dict[str, float], hold_m: float) -> NavMetrics:
    return NavMetrics(
        seed=seed,
        output_rmse_with_vision_m=0.01 * (seed + 1),
        output_rmse_m=0.02 * (seed + 1) ** 2,
        bias_error_fraction_60s={"gyro": 0.1 * (seed + 1) ** 2, "accel": 0.2},
        dropout_end_error_m=[],
        dropout_recovery_s=[],
        hold_max_horizontal_error_m=hold_m,
        delayed_rmse_m=0.03,
        attitude_rmse_deg=0.5,
        nees_mean=nees,
        nis_above_95pct_gate=nis,
        sources={"vision": SourceStats()},
        imu=ImuCounts(received=10, rejected_out_of_order=0, rejected_invalid=0),
        filter_events=[],
        landed_at_m=[0.0, 0.0, 0.0],
        end_horizontal_error_m=0.1,
        distance_flown_m=8.0,
        drift_percent=1.0 * (seed + 1) ** 3,
    )


def test_the_navigation_summary_gives_medians_and_worst_cases_as_labelled() -> None:
    per_seed = [
        _nav(0, NEES[0], {"vision": 0.10, "gps": 0.5}, 0.05),
        _nav(1, NEES[1], {"vision": 0.20}, 0.40),
        _nav(2, NEES[2], {"vision": 0.90, "gps": 0.7}, 0.10),
    ]
    s = summarize_nav_seeds(per_seed)
    assert s.nees_mean == 2.0  # the median of the seeds' NEES (their mean is 11)
    # the share of innovations beyond the gate: median over the seeds that fused the source
    assert s.nis_above_95pct_gate == {"vision": 0.20, "gps": 0.6}
    assert s.output_rmse_m == 0.08  # median of 0.02, 0.08, 0.18 (mean 0.093)
    assert s.drift_percent == 8.0  # median of 1, 8, 27 (mean 12)
    assert s.gyro_bias_error_fraction_median == 0.4
    assert s.hold_max_horizontal_error_m == 0.40  # "worst": the maximum


def test_the_planar_table_headed_median_gives_the_nees_median() -> None:
    def planar(seed: int, nees: float) -> PlanarMetrics:
        return PlanarMetrics(
            seed=seed, rmse_delayed_m=0.1, rmse_output_m=0.1, rmse_floor_m=0.1,
            output_over_floor=1.0, nees_mean=nees, nees_steps=10, gps_received=5,
            gps_fused=5, gps_rejected_gate=0, gps_rejected_too_old=0,
            gps_pending_at_end=0, imu_buffer_length=4,
        )  # fmt: skip

    summary = {"handled": summarize_seeds([planar(k, x) for k, x in enumerate(NEES)])}
    (row,) = planar_table(summary)  # the table of metrics.json and of "median over seeds"
    assert row["NEES mean"] == 2.0
