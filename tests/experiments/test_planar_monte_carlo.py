"""The planar experiment's claims, judged over 20 seeded Monte Carlo runs (thesis parameters)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from quadnav.eval.planar import PlanarMetrics, PlanarSummary, SeedSpread
from quadnav.experiments import ExperimentName, PlanarConfig, run_planar
from quadnav.experiments.planar_study import (
    PlanarStudy,
    planar_metrics,
    planar_table,
    run_planar_study,
)

SEEDS = 20


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> PlanarStudy:
    config = PlanarConfig(seeds=SEEDS)
    return run_planar_study(config, runs_root=tmp_path_factory.mktemp("runs"), jobs=2)


@pytest.fixture(scope="module")
def kinematic_study(tmp_path_factory: pytest.TempPathFactory) -> PlanarStudy:
    config = PlanarConfig.model_validate(
        {"seeds": SEEDS, "experiments": ["handled"], "imu": {"accel_model": "kinematic"}}
    )
    return run_planar_study(config, runs_root=tmp_path_factory.mktemp("runs"), jobs=2)


def median(study: PlanarStudy, exp: ExperimentName, key: str) -> float:
    return float(getattr(study.summary[exp], key).median)


def test_delayed_gps_fused_as_current_degrades_the_estimate(study: PlanarStudy) -> None:
    assert median(study, "naive", "rmse_delayed_m") >= 1.0
    # ... worse even than no GPS at all, as thesis figure 2.4 shows.
    assert median(study, "naive", "rmse_delayed_m") > median(study, "no_update", "rmse_delayed_m")


def test_handled_delays_give_centimetre_accuracy_at_the_delayed_horizon(study: PlanarStudy) -> None:
    assert median(study, "handled", "rmse_delayed_m") <= 0.02
    assert study.summary["handled"].gps_rejected_gate_total == 0
    assert study.summary["handled"].gps_rejected_too_old_total == 0


def test_output_predictor_is_within_15_percent_of_its_floor(study: PlanarStudy) -> None:
    out = median(study, "handled", "rmse_output_m")
    floor = median(study, "handled", "rmse_floor_m")
    assert out <= 1.15 * floor
    assert median(study, "handled", "output_over_floor") <= 1.15


def test_delayed_filter_is_consistent(study: PlanarStudy) -> None:
    values = [m.nees_mean for m in study.per_seed["handled"]]
    assert 2.5 <= float(np.mean(values)) <= 10.0


@pytest.mark.slow  # a second study; the thesis simulator's own study runs in CI
def test_kinematic_accelerometer_beats_the_thesis_simulator(kinematic_study: PlanarStudy) -> None:
    """The thesis's own output filter reaches 0.057 m on this scenario."""
    out = median(kinematic_study, "handled", "rmse_output_m")
    assert out < 0.057
    assert out <= 1.15 * median(kinematic_study, "handled", "rmse_floor_m")


def test_run_folder_has_what_the_design_promises(study: PlanarStudy) -> None:
    d: Path = study.run_dir
    assert (d / "config.yaml").is_file() and (d / "metrics.json").is_file()
    html = (d / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 4  # three experiments and the Monte Carlo plot
    assert "RMSE output (m)" in html
    for exp in ("no_update", "naive", "handled"):
        assert (d / "plots" / f"{exp}.png").stat().st_size > 10_000
        for name in ("truth", "delayed", "output", "floor", "gps", "innovations"):
            header = (d / exp / f"{name}.csv").read_text().splitlines()[0]
            assert header.split(",")[0] == "t_ns"
    assert (d / "plots" / "monte_carlo.png").is_file()
    rows = (d / "handled" / "delayed.csv").read_text().splitlines()
    # header + t0 + the 900 steps after the 1 s buffer filled
    assert "var_x" in rows[0] and len(rows) == 1 + 1 + 900


def test_results_do_not_depend_on_the_number_of_processes(study: PlanarStudy) -> None:
    config = PlanarConfig(seeds=2, experiments=["handled"])
    again = [planar_metrics(run_planar(config, "handled", s)) for s in (0, 1)]
    for a, b in zip(again, study.per_seed["handled"][:2], strict=True):
        assert a == b


@pytest.mark.parametrize(
    "overrides",
    [
        {"gps": {"delay_s": 0.255}},  # not a whole number of IMU periods
        {"gps": {"delay_s": 0.5, "jitter_s": 0.45}},  # later fixes overtake earlier ones
    ],
)
def test_awkward_delays_are_handled(overrides: dict[str, object]) -> None:
    config = PlanarConfig.model_validate({"experiments": ["handled"], **overrides})
    for seed in range(3):
        run = run_planar(config, "handled", seed)
        m = planar_metrics(run)
        assert m.gps_received > 20
        assert m.gps_fused + m.gps_pending_at_end == m.gps_received
        assert m.gps_pending_at_end <= 2  # arrived but still ahead of the delayed horizon
        assert m.rmse_delayed_m <= 0.02
        # Every fix was fused at the tick nearest its time of validity.
        assert np.all(np.abs(run.fusion_t_fused_ns - run.fusion_t_obs_ns) <= 5_000_000)
    if "jitter_s" in overrides["gps"]:  # type: ignore[operator]
        assert np.any(np.diff(run.gps_t_valid_ns) < 0), "jitter should reorder arrivals"


def test_a_buffer_shorter_than_the_delay_rejects_every_fix() -> None:
    config = PlanarConfig.model_validate(
        {"experiments": ["handled"], "estimator": {"max_delay_s": 0.5}}
    )
    m = planar_metrics(run_planar(config, "handled", 0))
    assert m.gps_received > 20
    assert m.gps_rejected_too_old == m.gps_received
    assert m.gps_fused == 0
    assert m.imu_buffer_length == 51


def test_eval_of_the_run_csvs_agrees_with_the_study(study: PlanarStudy) -> None:
    """The run folder's CSVs read back through quadnav eval give the study's numbers."""
    from quadnav.eval import EvalOptions, evaluate_pair
    from quadnav.io import read_trajectory

    d = study.run_dir / "handled"
    truth = read_trajectory(d / "truth.csv")
    seed0 = study.per_seed["handled"][0]
    out = evaluate_pair(truth, read_trajectory(d / "output.csv"), EvalOptions())
    assert out.metrics.ape_trans_m.rmse == pytest.approx(seed0.rmse_output_m, rel=1e-3)
    delayed = evaluate_pair(truth, read_trajectory(d / "delayed.csv"), EvalOptions())
    # delayed.csv also holds the initial state at t0, which the study leaves out.
    assert delayed.metrics.ape_trans_m.rmse == pytest.approx(seed0.rmse_delayed_m, rel=0.05)
    nees = delayed.metrics.nees_pos
    assert nees is not None and 0.5 < nees.mean < 5.0  # 2 position axes carry variance


def test_metrics_json_holds_the_typed_results_field_for_field(study: PlanarStudy) -> None:
    """metrics.json and seeds.jsonl read back into the dataclasses give the study's results: a
    field missing, misspelt or added on either side fails here."""
    saved = json.loads((study.run_dir / "metrics.json").read_text())
    lines = [json.loads(x) for x in (study.run_dir / "seeds.jsonl").read_text().splitlines()]
    for exp in ("no_update", "naive", "handled"):
        per_seed = study.per_seed[exp]
        assert [m.seed for m in per_seed] == list(range(SEEDS))
        assert [PlanarMetrics(**row) for row in saved["per_seed"][exp]] == list(per_seed)
        mine = [
            {k: v for k, v in x.items() if k != "experiment"}
            for x in lines
            if x["experiment"] == exp
        ]
        rows = sorted(mine, key=lambda x: x["seed"])
        assert [PlanarMetrics(**row) for row in rows] == list(per_seed)
        spreads = {
            k: SeedSpread(**v) if isinstance(v, dict) else v
            for k, v in saved["summary"][exp].items()
        }
        assert PlanarSummary(**spreads) == study.summary[exp]


SPREAD_FIELDS = (
    "rmse_delayed_m",
    "rmse_output_m",
    "rmse_floor_m",
    "output_over_floor",
    "nees_mean",
)


def test_each_summary_field_comes_from_its_own_per_seed_metric(study: PlanarStudy) -> None:
    for exp in ("no_update", "naive", "handled"):
        s, per_seed = study.summary[exp], study.per_seed[exp]
        assert s.seeds == SEEDS
        for name in SPREAD_FIELDS:
            values = np.array([getattr(m, name) for m in per_seed], dtype=np.float64)
            spread = getattr(s, name)
            assert spread.median == pytest.approx(np.median(values), rel=1e-12), name
            assert spread.mean == pytest.approx(np.mean(values), rel=1e-12), name
            assert spread.p10 <= spread.median <= spread.p90, name
        assert s.gps_fused_total == sum(m.gps_fused for m in per_seed)
        assert s.gps_received_total == sum(m.gps_received for m in per_seed)
    handled = study.summary["handled"]
    # The three RMSEs differ on the handled experiment, so a column fed by the wrong field shows.
    assert (
        len(
            {
                handled.rmse_delayed_m.median,
                handled.rmse_output_m.median,
                handled.rmse_floor_m.median,
            }
        )
        == 3
    )
    row = next(r for r in planar_table(study.summary) if r["experiment"] == "handled")
    assert row["RMSE delayed (m)"] == handled.rmse_delayed_m.median
    assert row["RMSE output (m)"] == handled.rmse_output_m.median
    assert row["floor (m)"] == handled.rmse_floor_m.median
    assert row["output/floor"] == handled.output_over_floor.median
    assert row["NEES mean"] == handled.nees_mean.median  # (the table is "median over seeds")
    assert (row["GPS fused"], row["GPS gated"], row["GPS too old"]) == (
        handled.gps_fused_total,
        handled.gps_rejected_gate_total,
        handled.gps_rejected_too_old_total,
    )
