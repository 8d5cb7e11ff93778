"""The sweep engine: the table has a row per task with its grid values, a failing task is
recorded and the others finish, a sweep stopped half way resumes without redoing a task, and
Dask gives the local pool's table."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from quadnav.errors import ConfigError
from quadnav.eval.na import Metric
from quadnav.experiments.nav import run_nav
from quadnav.experiments.nav_study import nav_metrics
from quadnav.experiments.scenarios import nav_builtin
from quadnav.experiments.sweep import SweepPlan, plan_sweep, run_sweep, sweep_spec
from quadnav.experiments.sweep_engines import SweepEngine
from quadnav.experiments.sweep_tasks import TaskKind, nav_task_config, register_task_kind
from quadnav.io.tables import read_parquet_columns

#: A flight of some 4 s: aligned, up to 1 m, 1 m forward (a third of a second to fly).
SHORT = ["plan.kind=takeoff_forward", "plan.takeoff_s=0.5", "plan.duration_s=3",
         "plan.height_m=1", "plan.forward_m=1"]  # fmt: skip
DELAYS = [0.05, 0.3]


def _nav_plan(seeds: str = "2") -> SweepPlan:
    grid = [f"vision.delay_s=[{DELAYS[0]},{DELAYS[1]}]"]
    return plan_sweep(sweep_spec(None, "indoor_vision_pose", grid, seeds, SHORT))


def _status(folder: Path) -> str:
    return str(json.loads((folder / "status.json").read_text())["status"])


@pytest.fixture(scope="module")
def pool_sweep(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[object]]:
    """2 delays x 2 seeds on a pool of 2 processes."""
    folder = tmp_path_factory.mktemp("pool") / "sweep"
    res = run_sweep(_nav_plan(), folder, SweepEngine(jobs=2))
    assert (res.ran, res.ok, res.failed, res.status) == (4, 4, 0, "complete")
    assert _status(folder) == "complete"
    return read_parquet_columns(folder / "results.parquet")


def test_the_table_has_a_row_per_task_with_its_grid_values(
    pool_sweep: dict[str, list[object]],
) -> None:
    t = pool_sweep
    assert t["task"] == [0, 1, 2, 3]
    assert sorted(zip(t["vision.delay_s"], t["seed"], strict=True)) == [
        (d, s) for d in DELAYS for s in (0, 1)
    ]
    assert set(t["status"]) == {"ok"} and set(t["error"]) == {""}
    assert all(isinstance(w, float) and w > 0 for w in t["wall_s"])
    # the row of (0.3 s, seed 1) holds that flight's numbers, flown here on its own
    row = list(zip(t["vision.delay_s"], t["seed"], strict=True)).index((0.3, 1))
    alone = nav_metrics(
        run_nav(nav_builtin("indoor_vision_pose", [*SHORT, "vision.delay_s=0.3"]), 1)
    )
    assert t["output_rmse_m"][row] == alone.output_rmse_m
    assert t["attitude_rmse_deg"][row] == alone.attitude_rmse_deg
    # a later vision is a worse output: the delay swept is the delay flown
    rmse = np.array(t["output_rmse_m"], dtype=float)
    delay = np.array(t["vision.delay_s"])
    assert rmse[delay == 0.3].min() > rmse[delay == 0.05].max()


def test_dask_local_cluster_gives_the_pools_table(
    pool_sweep: dict[str, list[object]], tmp_path: Path
) -> None:
    pytest.importorskip("distributed")
    folder = tmp_path / "dask"
    res = run_sweep(_nav_plan(), folder, SweepEngine(local_cluster=2))
    assert (res.ok, res.failed) == (4, 0)
    dask = read_parquet_columns(folder / "results.parquet")
    assert set(dask) == set(pool_sweep)
    for name, values in pool_sweep.items():
        if name != "wall_s":
            assert dask[name] == values, name


#: Calls of the test kinds in this process: (delay, seed), in order.
CALLS: list[tuple[float, int]] = []
#: The call (1-based) at which the interrupting kind raises KeyboardInterrupt (0: never).
STOP_AT = [0]


def _counted(config: Any, seed: int) -> Mapping[str, Metric]:
    """A task without a flight: its metrics follow from its configuration and seed."""
    CALLS.append((config.vision.delay_s, seed))
    if STOP_AT[0] and len(CALLS) == STOP_AT[0]:
        raise KeyboardInterrupt
    if config.vision.delay_s > 0.5:
        raise RuntimeError("vision too late\nsecond line of the message")
    return {"delay_x_seed": config.vision.delay_s * seed, "note": "n/a: nothing"}


register_task_kind(TaskKind(name="test_counted", description="counts its calls",
                            build=nav_task_config, run=_counted, headline=("delay_x_seed",)))  # fmt: skip


def _counted_plan(delays: Sequence[float], seeds: str = "3") -> SweepPlan:
    spec = sweep_spec(None, "indoor_vision_pose", [f"vision.delay_s={list(delays)}"], seeds, [])
    return plan_sweep(dataclasses.replace(spec, kind="test_counted"))


def test_a_failing_task_is_recorded_and_the_others_finish(tmp_path: Path) -> None:
    CALLS.clear()
    STOP_AT[0] = 0
    plan = _counted_plan([0.1, 0.9, 0.2], seeds="2")
    res = run_sweep(plan, tmp_path / "s", SweepEngine(jobs=1))
    assert (res.ok, res.failed, res.status, len(CALLS)) == (4, 2, "complete", 6)
    t = read_parquet_columns(tmp_path / "s" / "results.parquet")
    for delay, seed, status, error, value in zip(t["vision.delay_s"], t["seed"], t["status"],
                                                 t["error"], t["delay_x_seed"], strict=True):  # fmt: skip
        if delay == 0.9:
            assert status == "failed" and error == "RuntimeError: vision too late"
            assert value is None
        else:
            assert status == "ok" and error == "" and value == pytest.approx(delay * seed)
    assert t["note"] == [None] * 6  # an n/a metric is a null cell (the journal has the why)
    assert "vision too late" in (tmp_path / "s" / "report.html").read_text()


def test_an_interrupted_sweep_resumes_without_redoing_a_task(tmp_path: Path) -> None:
    CALLS.clear()
    STOP_AT[0] = 4  # the fourth task is Ctrl-C: three finished
    plan = _counted_plan([0.1, 0.2, 0.3], seeds="3")
    folder = tmp_path / "s"
    with pytest.raises(KeyboardInterrupt):
        run_sweep(plan, folder, SweepEngine(jobs=1))
    assert _status(folder) == "interrupted"
    first = list(CALLS[:3])
    assert len(read_parquet_columns(folder / "results.parquet")["task"]) == 3
    assert (folder / "tasks.jsonl").read_text().count("\n") == 3
    # the plots and report of what finished, saying so
    assert "Interrupted (Ctrl-C) after 3 of 9 task(s)" in (folder / "report.html").read_text()
    assert list((folder / "plots").glob("*.png"))
    with (folder / "tasks.jsonl").open("a") as f:
        f.write('{"task": 8, "point": 2, "se')  # a line cut by a kill
    CALLS.clear()
    STOP_AT[0] = 0
    res = run_sweep(plan, folder, SweepEngine(jobs=1))
    assert (res.done_before, res.ran, res.ok) == (3, 6, 9)
    assert not set(first) & set(CALLS) and len(set(CALLS)) == 6
    t = read_parquet_columns(folder / "results.parquet")
    assert t["task"] == list(range(9)) and _status(folder) == "complete"
    assert "Interrupted" not in (folder / "report.html").read_text()
    assert sorted(zip(t["vision.delay_s"], t["seed"], strict=True)) == sorted(first + CALLS)
    # journal lines lost: those tasks alone run again
    lines = (folder / "tasks.jsonl").read_text().splitlines()
    lost = [json.loads(x)["task"] for x in lines[2:4]]
    (folder / "tasks.jsonl").write_text("\n".join(lines[:2] + lines[4:]) + "\n")
    CALLS.clear()
    res = run_sweep(plan, folder, SweepEngine(jobs=1))
    assert res.ran == 2 and sorted(plan.task(k)[1] for k in lost) == sorted(s for _, s in CALLS)


def test_another_sweep_into_the_folder_is_refused_and_failed_tasks_retried(tmp_path: Path) -> None:
    STOP_AT[0] = 0
    folder = tmp_path / "s"
    run_sweep(_counted_plan([0.1, 0.9], seeds="1"), folder, SweepEngine(jobs=1))
    with pytest.raises(ConfigError, match=r"^--out .*: holds another sweep"):
        run_sweep(_counted_plan([0.1, 0.8], seeds="1"), folder, SweepEngine(jobs=1))
    CALLS.clear()
    res = run_sweep(_counted_plan([0.1, 0.9], seeds="1"), folder, SweepEngine(jobs=1))
    assert res.ran == 0 and not CALLS
    res = run_sweep(_counted_plan([0.1, 0.9], seeds="1"), folder, SweepEngine(jobs=1),
                    retry_failed=True)  # fmt: skip
    assert res.ran == 1 and CALLS == [(0.9, 0)]
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "x.txt").write_text("x")
    with pytest.raises(ConfigError, match=r"not a sweep folder"):
        run_sweep(_counted_plan([0.1], seeds="1"), tmp_path / "other", SweepEngine(jobs=1))


def test_a_scheduler_by_address_runs_the_sweep_and_ctrl_c_keeps_what_finished(
    tmp_path: Path,
) -> None:
    """``--scheduler tcp://...`` (a scheduler this test starts on loopback, its worker's threads
    in this process) and a Ctrl-C in the middle: the folder is marked interrupted with the
    finished tasks in its journal and table, the client lets the scheduler be, and the same
    sweep on the same scheduler finishes only the rest."""
    dd = pytest.importorskip("distributed")
    CALLS.clear()
    STOP_AT[0] = 0
    plan = _counted_plan([0.1, 0.2, 0.3], seeds="3")
    folder = tmp_path / "s"

    def ctrl_c_at_the_third(done: int, total: int, what: str) -> None:
        if done == 3:
            raise KeyboardInterrupt

    with dd.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, protocol="tcp://",
                         host="127.0.0.1", dashboard_address=None) as cluster:  # fmt: skip
        address = cluster.scheduler_address
        assert address.startswith("tcp://127.0.0.1:")
        engine = SweepEngine(scheduler=address)
        with pytest.raises(KeyboardInterrupt):
            run_sweep(plan, folder, engine, progress=ctrl_c_at_the_third)
        assert _status(folder) == "interrupted"
        assert (folder / "tasks.jsonl").read_text().count("\n") == 3
        assert len(read_parquet_columns(folder / "results.parquet")["task"]) == 3
        res = run_sweep(plan, folder, engine)
    assert (res.done_before, res.ran, res.ok, res.status) == (3, 6, 9, "complete")
    t = read_parquet_columns(folder / "results.parquet")
    assert t["task"] == list(range(9))
    for delay, seed, value in zip(t["vision.delay_s"], t["seed"], t["delay_x_seed"], strict=True):
        assert value == pytest.approx(delay * seed)
