"""Metrics a short or degenerate run cannot give say why, with no numpy warning and no NaN
in the table (issue 12, item 19)."""

from __future__ import annotations

import dataclasses
import warnings

import pytest

from quadnav.errors import ConfigError
from quadnav.eval.na import fmt_metric, is_na, median_or_na, na, rms_or_na
from quadnav.eval.planar import summarize_seeds
from quadnav.experiments import PlanarConfig, run_planar
from quadnav.experiments.flight import FlightConfig, builtin_config, run_flight
from quadnav.experiments.flight_study import flight_metrics
from quadnav.experiments.nav import NavScenario, run_nav
from quadnav.experiments.nav_study import nav_metrics
from quadnav.experiments.planar_study import planar_metrics
from quadnav.io import load_config


def test_na_helpers() -> None:
    assert rms_or_na([3.0, 4.0], "x") == pytest.approx((12.5) ** 0.5)
    assert rms_or_na([], "no samples in the air") == "n/a: no samples in the air"
    assert median_or_na([na("a"), 2.0, 4.0]) == 3.0
    assert median_or_na([na("a"), 2.0, 4.0], worst=True) == 4.0
    assert median_or_na([na("no hold"), na("other")]) == "n/a: no hold"
    assert fmt_metric(na("why")) == "n/a: why" and fmt_metric(0.12345) == "0.1235"
    assert fmt_metric(float("nan")) == "n/a"


def test_a_two_second_sim_says_why_it_has_no_tracking_rmse() -> None:
    cfg = load_config(FlightConfig, None, ["duration_s=2"], base=builtin_config("circle"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # "Mean of empty slice" would fail here
        m = flight_metrics(run_flight(cfg))
    assert m.tracking is not None
    rmse = m.tracking.tracking_rmse_m
    assert isinstance(rmse, str) and is_na(rmse) and "tracking_start_s" in rmse
    assert isinstance(m.tracking.tracking_rmse_whole_run_m, float)


def test_a_dropout_over_the_whole_flight_says_why() -> None:
    sc = load_config(
        NavScenario,
        None,
        [
            "vision.source=pose",
            "vision.dropouts_s=[[0,100]]",
            "plan.hold_s=0.5",
            "plan.square_m=0.5",
        ],
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = nav_metrics(run_nav(sc, 0))
    assert m.output_rmse_with_vision_m == "n/a: no samples in the air with vision"
    assert m.dropout_end_error_m == [] and m.dropout_recovery_s == []
    assert is_na(m.hold_max_horizontal_error_m)  # 0.5 s holds: none lasts over 1 s
    assert isinstance(m.output_rmse_m, float)  # what can be measured still is


def test_a_planar_run_shorter_than_the_delay_is_refused_naming_the_keys() -> None:
    # it used to fail after the work ("statistics need a non-empty 1-D error array")
    with pytest.raises(ConfigError, match=r"gps\.delay_s.*duration_s \(0\.5 s\) must be longer"):
        load_config(PlanarConfig, None, ["duration_s=0.5"])  # GPS delay 1 s


def test_planar_summaries_carry_the_reason_when_no_seed_has_a_number() -> None:
    cfg = load_config(PlanarConfig, None, ["duration_s=2"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        per_seed = [planar_metrics(run_planar(cfg, "handled", s)) for s in (0, 1)]
    why = na("no delayed estimate after the first fused fix")
    summary = summarize_seeds([dataclasses.replace(m, nees_mean=why) for m in per_seed])
    assert summary.nees_mean.median == why
    assert isinstance(summary.rmse_output_m.median, float)
