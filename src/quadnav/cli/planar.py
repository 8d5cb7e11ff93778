"""``quadnav planar``: thesis 000's three delayed-measurement experiments on the planar quadrotor."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quadnav.cli.common import console, handle_errors, progress_bar
from quadnav.eval.planar import PlanarStudy, run_planar_study
from quadnav.experiments.planar import PlanarConfig
from quadnav.io.config import load_config

__all__ = ["planar_command", "print_planar_summary", "run_planar_from_cli"]

ConfigArg = Annotated[
    Path | None, typer.Argument(help="YAML config; every key is optional (defaults: the thesis's)")
]
SetOpt = Annotated[
    list[str] | None,
    typer.Option("--set", help="override one field, e.g. --set gps.delay_s=0.5 (repeatable)"),
]
SeedsOpt = Annotated[
    int | None, typer.Option("--seeds", min=1, help="Monte Carlo runs per experiment (seeds seed..seed+N-1)")
]
OutOpt = Annotated[Path, typer.Option("--out", help="folder that receives the run folder")]


def print_planar_summary(study: PlanarStudy) -> None:
    table = Table(title="Planar delayed-measurement experiments (median over seeds)")
    for col in ("experiment", "seeds", "RMSE delayed (m)", "RMSE output (m)", "floor (m)",
                "output/floor", "NEES (5 states)", "GPS fused/rejected/too old"):
        table.add_column(col, justify="right" if col != "experiment" else "left")
    for exp, s in study.summary.items():
        table.add_row(
            exp,
            str(s["seeds"]),
            f"{s['rmse_delayed_m']['median']:.4f}",
            f"{s['rmse_output_m']['median']:.4f}",
            f"{s['rmse_floor_m']['median']:.4f}",
            f"{s['output_over_floor']['median']:.3f}",
            f"{s['nees_mean']['mean']:.2f}",
            f"{s['gps_fused_total']}/{s['gps_rejected_gate_total']}/{s['gps_rejected_too_old_total']}",
        )
    console.print(table)
    console.print(
        "delayed: against the truth at the delayed horizon; output and floor: against the truth now; "
        "NEES: mean over seeds and steps after the first fix"
    )


def run_planar_from_cli(config_path: Path | None, overrides: list[str] | None, seeds: int | None, out: Path) -> None:
    all_overrides = list(overrides or [])
    if seeds is not None:
        all_overrides.append(f"seeds={seeds}")
    config = load_config(PlanarConfig, config_path, all_overrides)
    with progress_bar("planar") as update:
        study = run_planar_study(config, runs_root=out, progress=update)
    print_planar_summary(study)
    console.print(str(study.run_dir), soft_wrap=True, highlight=False)


@handle_errors
def planar_command(
    config: ConfigArg = None,
    set_: SetOpt = None,
    seeds: SeedsOpt = None,
    out: OutOpt = Path("runs"),
) -> None:
    """Thesis 000's planar experiments: no update, delayed GPS fused as if current, delays handled.

    Examples:

      quadnav planar                          # the thesis's parameters, one seed

      quadnav planar --seeds 20               # Monte Carlo over 20 seeds

      quadnav planar --set gps.delay_s=0.255 --set imu.accel_model=kinematic
    """
    run_planar_from_cli(config, set_, seeds, out)
