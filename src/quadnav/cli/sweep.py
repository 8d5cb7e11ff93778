"""``quadnav sweep``: a grid of configuration values x seeds of a scenario of ``quadnav run``,
``quadnav planar`` or ``quadnav sim`` (the task kinds ``nav``, ``planar``, ``sim``)."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quadnav.cli.common import (
    CommandParams,
    command_help,
    console,
    handle_errors,
    optional_param,
    param,
    progress_bar,
    strings_param,
)
from quadnav.cli.planar import SetOpt
from quadnav.experiments.sweep import (
    SweepPlan,
    default_folder,
    load_sweep_file,
    plan_sweep,
    run_sweep,
    sweep_spec,
)
from quadnav.experiments.sweep_engines import SweepEngine, check_engine
from quadnav.experiments.sweep_tasks import TASK_KINDS

__all__ = ["EXAMPLES", "check_example", "sweep_command"]

#: The examples of ``quadnav sweep --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav sweep indoor_vision_pose --grid vision.delay_s=0.05:0.5:10 --seeds 20",
    "quadnav sweep indoor_vision_pose --grid vision.delay_s=[0.1,0.25] "
    "--grid vision.sigma_m=[0.01,0.03] --seeds 0-9 --set vision.dropouts_s=[]",
    "quadnav sweep outdoor_gps --grid gps.delay_s=0:0.4:5 --seeds 50 --local-cluster 2",
    "quadnav sweep planar --grid gps.delay_s=0.05:0.5:4 --seeds 10",
    "quadnav sweep circle_gusts --grid wind.gust_sigma_m_s=0:3:4 --seeds 5",
    "quadnav sweep --kind planar --grid estimator.tau_vel_s=[0.1,0.25] --seeds 5",
    "quadnav sweep thesis003_obstacle --grid thesis003.kp_lin=[0.2,0.3,0.4]",
    "quadnav sweep room_medium --grid vio.window_keyframes=[6,8,10] --seeds 5 --set duration_s=30",
    "quadnav sweep room_easy --kind slam --grid th_depth_baselines=[22,40] --seeds 3 --set duration_s=10",
)

GridOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--grid",
        help="KEY=SPEC, a configuration key and its values: start:stop:count (count values, "
        "both ends included), a list [a,b,c] or one value (repeatable: the grid is every "
        "combination)",
    ),
]
KindOpt = Annotated[
    str | None,
    typer.Option(
        "--kind",
        help="what a task runs: nav (quadnav run), planar (quadnav planar), sim (quadnav sim), "
        "vio (quadnav vio on a built-in sequence), slam (quadnav slam on one: always given, "
        "its sequences are vio's); without it, the built-in SCENARIO's kind, and nav for a "
        "YAML file",
    ),
]


def _plan(
    scenario: str | None,
    grid: list[str],
    grid_file: Path | None,
    seeds: str | None,
    set_: list[str],
    kind: str | None,
) -> SweepPlan:
    file = load_sweep_file(grid_file) if grid_file is not None else None
    return plan_sweep(sweep_spec(file, scenario, grid, seeds, set_, kind))


def _engine(jobs: int | None, scheduler: str | None, local_cluster: int | None) -> SweepEngine:
    engine = SweepEngine(
        jobs=jobs or os.cpu_count() or 1, scheduler=scheduler, local_cluster=local_cluster
    )
    check_engine(engine)
    return engine


def check_example(params: CommandParams) -> None:
    """Validate an example's arguments as the command would, without running it."""
    _engine(
        optional_param(params, "jobs", int),
        optional_param(params, "scheduler", str),
        optional_param(params, "local_cluster", int),
    )
    grid_file = optional_param(params, "grid_file", Path)
    _plan(
        optional_param(params, "scenario", str),
        strings_param(params, "grid"),
        grid_file,
        optional_param(params, "seeds", str),
        strings_param(params, "set_"),
        optional_param(params, "kind", str),
    )
    param(params, "retry_failed", bool)


@handle_errors
def sweep_command(
    scenario: Annotated[
        str | None,
        typer.Argument(help="a built-in scenario of quadnav run, planar, one of quadnav sim "
                       "--list, a built-in sequence (vio), or a YAML file; without it, the "
                       "kind's first: indoor_vision, planar, circle, room_easy"),
    ] = None,
    grid: GridOpt = None,
    kind: KindOpt = None,
    grid_file: Annotated[
        Path | None,
        typer.Option("--grid-file", help="the sweep in YAML: kind, scenario, grid, seeds, set"),
    ] = None,
    seeds: Annotated[
        str | None,
        typer.Option("--seeds", help="a count N (seeds seed..seed+N-1) or seeds 0-9, 0,2,7 [default: 1]"),
    ] = None,
    set_: SetOpt = None,
    jobs: Annotated[
        int | None, typer.Option("--jobs", min=1, help="processes of the local pool [default: CPU count]")
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option("--scheduler", help="run on a Dask scheduler, tcp://HOST:8786 (quadnav\\[sweep])"),
    ] = None,
    local_cluster: Annotated[
        int | None,
        typer.Option("--local-cluster", help="run on a Dask LocalCluster of N workers on 127.0.0.1 (quadnav\\[sweep])"),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="the sweep folder; run again into it, it runs only the tasks "
                     "not finished [default: runs/sweep_<scenario>_<fingerprint>]"),
    ] = None,
    retry_failed: Annotated[
        bool, typer.Option("--retry-failed", help="run the failed tasks of the folder again")
    ] = False,
) -> None:  # fmt: skip
    engine = _engine(jobs, scheduler, local_cluster)
    plan = _plan(scenario, grid or [], grid_file, seeds, set_ or [], kind)
    folder = out if out is not None else default_folder(plan, Path("runs"))
    print(f"sweep folder: {folder} ({plan.n_tasks} tasks)", file=sys.stderr, flush=True)
    with progress_bar(f"sweep {plan.spec.scenario}", eta=True) as update:
        res = run_sweep(plan, folder, engine, progress=update, retry_failed=retry_failed)
    console.print(f"sweep of {plan.spec.scenario} on {engine.describe()}", highlight=False)
    table = Table()
    table.add_column("tasks")
    table.add_column("count", justify="right")
    for what, n in (("in the sweep", res.tasks), ("done before (skipped)", res.done_before),
                    ("run now", res.ran), ("ok", res.ok), ("failed", res.failed)):  # fmt: skip
        table.add_row(what, str(n))
    console.print(table)
    console.print(str(res.folder), soft_wrap=True, highlight=False)


sweep_command.__doc__ = command_help(
    "Sweep a grid of configuration values x seeds of a run, planar, sim, vio or slam scenario into one table.",
    "Each (grid point, seed) is one task of the scenario's kind: nav, one seeded flight as "
    "quadnav run flies it; planar, one seed of each experiment of quadnav planar (metrics "
    "<experiment>.<metric>); sim, one seeded flight of quadnav sim; vio, quadnav vio on a "
    "built-in sequence made for the seed (keys vio.*, sequence, rig, duration_s); slam, quadnav "
    "slam on one with a stereo or RGB-D rig (keys n_features, th_depth_baselines, loop, rig, "
    "duration_s; always --kind slam, as its sequences are vio's). Otherwise the built-in "
    "names of the kinds are disjoint: a name gives its kind, a YAML file is nav unless --kind. "
    "Every grid point's configuration is validated before anything runs. Tasks run "
    "on a local process pool (--jobs) or Dask (--scheduler, --local-cluster); each finished "
    "task is a line of tasks.jsonl and a row of results.parquet (task, the grid's keys, seed, "
    "status, error, wall_s, one column per metric). Run the same sweep into the same --out "
    "again and only the unfinished tasks run; Ctrl-C keeps what finished. At the end: a plot "
    "per metric against each key (median, 10-90 % band) and report.html.",
    lists=[("Task kinds", {k.name: k.description for k in TASK_KINDS.values()})],
    examples=EXAMPLES,
)
