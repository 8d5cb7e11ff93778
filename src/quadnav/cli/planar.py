"""``quadnav planar``: thesis 000's three delayed-measurement experiments on the planar quadrotor."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from quadnav.cli.common import (
    CommandParams,
    RerunConnectOpt,
    RerunOpt,
    RerunSpawnOpt,
    command_help,
    console,
    finish_recording,
    handle_errors,
    optional_param,
    progress_bar,
    rerun_request,
    start_recording,
    strings_param,
)
from quadnav.eval.na import fmt_metric
from quadnav.experiments.planar import PlanarConfig
from quadnav.experiments.planar_study import PlanarStudy, planar_table, run_planar_study
from quadnav.io.config import load_config

if TYPE_CHECKING:
    from quadnav.viz.stream import RerunOptions

__all__ = [
    "EXAMPLES",
    "check_example",
    "planar_command",
    "print_planar_summary",
    "resolve_planar_config",
    "run_planar_config",
]

ConfigArg = Annotated[
    Path | None, typer.Argument(help="YAML config; every key is optional (defaults: the thesis's)")
]
SetOpt = Annotated[
    list[str] | None,
    typer.Option("--set", help="override one field of the configuration: key=value (repeatable)"),
]
SeedsOpt = Annotated[
    int | None,
    typer.Option("--seeds", min=1, help="Monte Carlo runs per experiment (seeds seed..seed+N-1)"),
]
OutOpt = Annotated[Path, typer.Option("--out", help="folder that receives the run folder")]
JobsOpt = Annotated[
    int | None,
    typer.Option("--jobs", min=1, help="processes for Monte Carlo runs [default: CPU count]"),
]
AllowRemoteOpt = Annotated[
    bool,
    typer.Option("--allow-remote", help="with --mavlink: let udpin bind a non-loopback address"),
]


def print_planar_summary(study: PlanarStudy) -> None:
    """The terminal summary: medians over seeds of each experiment's metrics."""
    n = next(iter(study.summary.values())).seeds
    table = Table(title=f"Planar experiments: position RMSE (m), median over {n} seed(s)")
    table.add_column("experiment")
    # The study's own table (metrics.json, the report): the same statistic under each header
    columns = {
        "delayed": ("RMSE delayed (m)", ".4f"),
        "output": ("RMSE output (m)", ".4f"),
        "floor": ("floor (m)", ".4f"),
        "out/floor": ("output/floor", ".3f"),
        "NEES": ("NEES mean", ".3g"),
        "GPS fused": ("GPS fused", ""),
        "gated": ("GPS gated", ""),
        "too old": ("GPS too old", ""),
    }
    for col in columns:
        table.add_column(col, justify="right")
    for row in planar_table(study.summary):
        cells = (fmt_metric(row[key], spec) for key, spec in columns.values())
        table.add_row(str(row["experiment"]), *cells)
    console.print(table)
    console.print(
        "delayed: vs truth at the delayed horizon; output, floor: vs truth now; "
        "floor: delayed estimate re-integrated through the buffered IMU; "
        "NEES: 5 states, mean after the first fix (ideal 5)",
        highlight=False,
    )


def resolve_planar_config(
    config_path: Path | None, overrides: list[str] | None, seeds: int | None
) -> PlanarConfig:
    """The validated configuration a ``quadnav planar`` would run (no work, no folder)."""
    all_overrides = [*(overrides or []), *([f"seeds={seeds}"] if seeds is not None else [])]
    return load_config(PlanarConfig, config_path, all_overrides)


def check_example(params: CommandParams) -> None:
    """Validate an example's arguments as the command would, without running it."""
    resolve_planar_config(
        optional_param(params, "config", Path),
        strings_param(params, "set_"),
        optional_param(params, "seeds", int),
    )


def run_planar_config(
    config: PlanarConfig,
    out: Path,
    jobs: int | None = None,
    recording: RerunOptions | None = None,
) -> None:
    """Run the planar study; with ``recording`` (``--rerun``), its folder's rerun recording."""
    recorder = start_recording(recording)  # (rerun imported while the study runs)
    with progress_bar("planar", line_step=0) as update:
        study = run_planar_study(
            config, runs_root=out, progress=update, jobs=jobs or os.cpu_count() or 1
        )
    print_planar_summary(study)
    finish_recording(recorder, study.run_dir, "planar")
    console.print(str(study.run_dir), soft_wrap=True, highlight=False)


#: The examples of ``quadnav planar --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav planar",
    "quadnav planar --seeds 20",
    "quadnav planar --set gps.delay_s=0.255 --set imu.accel_model=kinematic",
    "quadnav planar --set estimator.propagate_velocity_correction=false --set estimator.tau_vel_s=0.25",
)


@handle_errors
def planar_command(
    config: ConfigArg = None,
    set_: SetOpt = None,
    seeds: SeedsOpt = None,
    out: OutOpt = Path("runs"),
    jobs: JobsOpt = None,
    rerun: RerunOpt = False,
    rerun_connect: RerunConnectOpt = None,
    rerun_spawn: RerunSpawnOpt = False,
) -> None:
    recording = rerun_request(rerun, rerun_connect, rerun_spawn)
    run_planar_config(resolve_planar_config(config, set_, seeds), out, jobs, recording)


planar_command.__doc__ = command_help(
    "Thesis 000's planar experiments: no update, delayed GPS fused as if current, delays handled.",
    "The same delayed-measurement problem in two dimensions (thesis figures 2.3-2.5), with the "
    "thesis's parameters by default; --seeds runs a Monte Carlo study.",
    examples=EXAMPLES,
)
