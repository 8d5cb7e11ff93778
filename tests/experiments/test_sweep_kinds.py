"""The sweep's task kinds planar, sim, vio and slam (issue 26): a sweep's table has a row per task with
its grid values, a row's metrics are those of the same configuration and seed run directly,
a bad key names ``--grid KEY=...``; the kind comes from the scenario's name or ``--kind``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.errors import ConfigError
from quadnav.experiments.flight import FlightConfig, builtin_config, run_flight
from quadnav.experiments.flight_study import flight_metrics
from quadnav.experiments.odometry_run import OdometryRunOptions
from quadnav.experiments.planar import PlanarConfig, run_planar
from quadnav.experiments.planar_study import planar_metrics
from quadnav.experiments.slam_run import SlamRequest, run_slam_source
from quadnav.experiments.sweep import plan_sweep, run_sweep, sweep_spec
from quadnav.experiments.sweep_engines import SweepEngine
from quadnav.experiments.sweep_tasks import TASK_KINDS, TaskKind, sim_task_config
from quadnav.experiments.vio_run import VioRequest, run_vio_source
from quadnav.io.config import load_config
from quadnav.io.tables import read_parquet_columns

#: Two experiments of 2 s each.
PLANAR_SHORT = ["duration_s=2", "experiments=[naive,handled]"]
#: The circle in gusts for 1.5 s at a 2 ms step.
SIM_SHORT = ["duration_s=1.5", "dt_s=0.002", "tracking_start_s=0.5"]


def _row(t: dict[str, list[object]], key: str, value: object, seed: int) -> int:
    return list(zip(t[key], t["seed"], strict=True)).index((value, seed))


def test_a_planar_sweep_row_is_that_seed_of_each_experiment(tmp_path: Path) -> None:
    spec = sweep_spec(None, "planar", ["gps.delay_s=[0.1,0.3]"], "2", PLANAR_SHORT)
    assert (spec.kind, spec.scenario) == ("planar", "planar")
    res = run_sweep(plan_sweep(spec), tmp_path / "s", SweepEngine(jobs=1))
    assert (res.ok, res.failed) == (4, 0)
    t = read_parquet_columns(tmp_path / "s" / "results.parquet")
    assert sorted(zip(t["gps.delay_s"], t["seed"], strict=True)) == [
        (d, s) for d in (0.1, 0.3) for s in (0, 1)
    ]
    assert "no_update.rmse_output_m" not in t  # not configured
    row = _row(t, "gps.delay_s", 0.3, 1)
    config = load_config(PlanarConfig, None, [*PLANAR_SHORT, "gps.delay_s=0.3"])
    for exp in ("naive", "handled"):
        alone = planar_metrics(run_planar(config, exp, 1))
        assert t[f"{exp}.rmse_output_m"][row] == alone.rmse_output_m
        assert t[f"{exp}.nees_mean"][row] == alone.nees_mean
        assert t[f"{exp}.gps_fused"][row] == alone.gps_fused
    # handling the delay is the better output at every task
    handled = np.array(t["handled.rmse_output_m"], dtype=float)
    assert (handled < np.array(t["naive.rmse_output_m"], dtype=float)).all()


def test_a_sim_sweep_row_is_that_seeded_flight(tmp_path: Path) -> None:
    spec = sweep_spec(None, "circle_gusts", ["wind.gust_sigma_m_s=[1,3]"], "2", SIM_SHORT)
    assert spec.kind == "sim"
    res = run_sweep(plan_sweep(spec), tmp_path / "s", SweepEngine(jobs=2))
    assert (res.ok, res.failed) == (4, 0)
    t = read_parquet_columns(tmp_path / "s" / "results.parquet")
    assert sorted(zip(t["wind.gust_sigma_m_s"], t["seed"], strict=True)) == [
        (g, s) for g in (1, 3) for s in (0, 1)
    ]
    row = _row(t, "wind.gust_sigma_m_s", 3, 1)
    base = builtin_config("circle_gusts")
    config = load_config(FlightConfig, None, [*SIM_SHORT, "wind.gust_sigma_m_s=3", "seed=1"],
                         base=base)  # fmt: skip
    alone = flight_metrics(run_flight(config))
    assert alone.tracking is not None
    assert t["tracking_rmse_m"][row] == alone.tracking.tracking_rmse_m
    assert t["max_tilt_deg"][row] == alone.max_tilt_deg
    assert t["peak_thrust_n"][row] == alone.peak_thrust_n
    # the seed is the gusts': another seed, another flight
    other = _row(t, "wind.gust_sigma_m_s", 3, 0)
    assert t["tracking_rmse_m"][other] != t["tracking_rmse_m"][row]


def test_a_vio_sweep_row_is_quadnav_vio_on_that_seeds_sequence(tmp_path: Path) -> None:
    spec = sweep_spec(None, "room_easy", ["vio.tracker.max_features=[60,150]"], "1-1",
                      ["duration_s=3"])  # fmt: skip
    assert spec.kind == "vio"
    res = run_sweep(plan_sweep(spec), tmp_path / "s", SweepEngine(jobs=1))
    assert (res.ok, res.failed) == (2, 0)
    t = read_parquet_columns(tmp_path / "s" / "results.parquet")
    key = "vio.tracker.max_features"
    assert sorted(zip(t[key], t["seed"], strict=True)) == [(60, 1), (150, 1)]
    row = _row(t, key, 150, 1)
    request = VioRequest(sources=("room_easy",), overrides=("tracker.max_features=150",),
                         options=OdometryRunOptions(duration_s=3, video=False), seed=1,
                         out=tmp_path / "vio")  # fmt: skip
    alone = run_vio_source(request, "room_easy", 1, tmp_path / "vio").metrics
    assert not isinstance(alone.ape_4dof, str) and not isinstance(alone.nees_pose, str)
    assert t["ape_4dof.rmse_m"][row] == alone.ape_4dof.rmse_m
    assert t["nees_pose.mean_over_dof"][row] == alone.nees_pose.mean_over_dof
    assert t["frames_with_estimate"][row] == alone.frames_with_estimate
    assert t["final_error_m"][row] == alone.final_error_m
    # the key swept is the key run: fewer features, another estimate
    assert t["ape_4dof.rmse_m"][_row(t, key, 60, 1)] != t["ape_4dof.rmse_m"][row]


def test_a_slam_sweep_row_is_quadnav_slam_on_that_seeds_sequence(tmp_path: Path) -> None:
    spec = sweep_spec(None, "room_easy", ["n_features=[800,1200]"], "1-1",
                      ["duration_s=2", "loop=false"], "slam")  # fmt: skip
    res = run_sweep(plan_sweep(spec), tmp_path / "s", SweepEngine(jobs=1))
    assert (res.ok, res.failed) == (2, 0)
    t = read_parquet_columns(tmp_path / "s" / "results.parquet")
    assert sorted(zip(t["n_features"], t["seed"], strict=True)) == [(800, 1), (1200, 1)]
    row = _row(t, "n_features", 800, 1)
    request = SlamRequest(source="room_easy", seed=1, rig="euroc", out=tmp_path / "slam",
                          options=OdometryRunOptions(duration_s=2, video=False),
                          n_features=800, loop=False)  # fmt: skip
    alone = run_slam_source(request)
    assert not isinstance(alone.metrics.ape_se3, str) and alone.final is not None
    assert t["ape_se3.rmse_m"][row] == alone.metrics.ape_se3.rmse_m
    assert t["frames_with_estimate"][row] == alone.metrics.frames_with_estimate
    assert t["final_ape_se3.rmse_m"][row] == alone.final["ape_se3"]["rmse_m"]
    # the key swept is the key run: fewer features, another estimate
    assert t["ape_se3.rmse_m"][_row(t, "n_features", 1200, 1)] != t["ape_se3.rmse_m"][row]


@pytest.mark.parametrize(
    ("scenario", "grid", "named"),
    [
        ("planar", "gps.delay=[0.1]", "--grid gps.delay=0.1: "),
        ("planar", "gps.delay_s=[-1]", "--grid gps.delay_s=-1: "),
        ("circle", "wind.gust=[1]", "--grid wind.gust=1: "),
        ("circle", "vision.delay_s=[0.1]", "--grid vision.delay_s=0.1: "),  # a nav key
        ("room_easy", "window_keyframes=[8]", "--grid window_keyframes=8: "),  # vio.* it is
        ("room_easy", "sequence=[nope]", "--grid sequence=nope: "),
    ],
)
def test_a_bad_key_of_the_kind_names_the_grid(scenario: str, grid: str, named: str) -> None:
    with pytest.raises(ConfigError, match="^" + named.replace(".", r"\.")):
        plan_sweep(sweep_spec(None, scenario, [grid], "1", []))


def test_the_kind_comes_from_the_scenario_or_kind(monkeypatch: pytest.MonkeyPatch) -> None:
    def kind(scenario: str | None, kind: str | None = None) -> tuple[str, str]:
        spec = sweep_spec(None, scenario, ["x=1"], "1", [], kind)
        return spec.kind, spec.scenario

    assert kind("indoor_vision_pose") == ("nav", "indoor_vision_pose")
    assert kind("planar") == ("planar", "planar")
    assert kind("thesis003_obstacle") == ("sim", "thesis003_obstacle")
    assert kind(None) == ("nav", "indoor_vision")
    assert kind(None, "sim") == ("sim", "circle")
    assert kind(None, "planar") == ("planar", "planar")
    assert kind("room_easy") == ("vio", "room_easy")
    assert kind(None, "vio") == ("vio", "room_easy")
    with pytest.raises(ConfigError, match=r"^SCENARIO 'nope': .*\(nav, planar, sim, vio"):
        kind("nope")
    with pytest.raises(ConfigError, match=r"^--kind nope: .*nav, planar, sim, vio, slam"):
        kind("circle", "nope")
    assert kind("room_easy", "slam") == ("slam", "room_easy")  # vio's names: slam by --kind
    assert kind(None, "slam") == ("slam", "room_easy")
    with pytest.raises(ConfigError, match=r"^SCENARIO 'circle': neither .* the kind nav"):
        plan_sweep(sweep_spec(None, "circle", ["x=1"], "1", [], "nav"))
    twin = TaskKind(name="twin", description="", build=sim_task_config, run=lambda c, s: {},
                    scenarios=lambda: ("circle",))  # fmt: skip
    monkeypatch.setitem(TASK_KINDS, "twin", twin)
    with pytest.raises(ConfigError, match=r"^SCENARIO 'circle': .*sim, twin: give --kind"):
        kind("circle")
    assert kind("circle", "twin") == ("twin", "circle")


def test_the_command_refuses_an_unknown_scenario_in_one_line(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app, ["sweep", "nope", "--grid", "x=1", "--out", str(tmp_path / "s")]
    )
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: SCENARIO 'nope'"), result.stderr
    assert "nav, planar, sim, vio" in lines[0]


def test_a_flight_tasks_paused_collector_frees_its_cycles_after_it() -> None:
    """The collection after a flight with the collector paused is of the youngest generation
    only; what the flight left in cycles (made while paused, so still there) goes."""
    import gc
    import weakref

    from quadnav.experiments.sweep_tasks import _collector_paused

    class Node:
        other: object = None

    assert gc.isenabled()
    with _collector_paused():
        assert not gc.isenabled()
        a, b = Node(), Node()
        a.other, b.other = b, a
        gone = weakref.ref(a)
        del a, b
        assert gone() is not None  # (a cycle: reference counts do not free it)
    assert gc.isenabled()
    assert gone() is None
