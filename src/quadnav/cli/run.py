"""``quadnav run``: the main job, with a built-in default scenario."""

from __future__ import annotations

import os
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
    progress_bar,
    strings_param,
)
from quadnav.cli.planar import JobsOpt, OutOpt, SeedsOpt, SetOpt, run_planar_config
from quadnav.errors import ConfigError
from quadnav.eval.na import fmt_metric
from quadnav.experiments.nav import NavScenario
from quadnav.experiments.nav_study import run_nav_study
from quadnav.experiments.planar import PlanarConfig
from quadnav.experiments.scenarios import NAV_SCENARIOS, nav_builtin
from quadnav.io.config import load_config

__all__ = ["EXAMPLES", "check_example", "resolve_run_config", "run_command"]


def resolve_run_config(
    scenario: str | None, set_: list[str] | None, seeds: int | None
) -> NavScenario | PlanarConfig:
    """The validated configuration a ``quadnav run`` would fly (no work, no folder)."""
    overrides = [*(set_ or []), *([f"seeds={seeds}"] if seeds is not None else [])]
    if scenario == "planar":
        return load_config(PlanarConfig, None, overrides)
    if scenario is None or scenario in NAV_SCENARIOS:
        return nav_builtin(scenario or "indoor_vision", overrides)
    path = Path(scenario)
    if not path.exists():
        raise ConfigError(
            f"{scenario!r} is neither a built-in scenario ({', '.join([*NAV_SCENARIOS, 'planar'])}) nor a file"
        )
    return load_config(NavScenario, path, overrides)


def check_example(params: CommandParams) -> None:
    """Validate an example's arguments as the command would, without running it."""
    resolve_run_config(
        optional_param(params, "scenario", str),
        strings_param(params, "set_"),
        optional_param(params, "seeds", int),
    )


#: The examples of ``quadnav run --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav run",
    "quadnav run --seeds 20",
    "quadnav run indoor_vision_pose --set vision.delay_s=0.1 --set plan.square_m=4",
    "quadnav run outdoor_gps --set gps.outages_s=[[20,25]]",
    "quadnav run planar --seeds 20",
)


@handle_errors
def run_command(
    scenario: Annotated[
        str | None,
        typer.Argument(help="a built-in scenario (listed above) or a YAML file"),
    ] = None,
    set_: SetOpt = None,
    seeds: SeedsOpt = None,
    out: OutOpt = Path("runs"),
    jobs: JobsOpt = None,
) -> None:
    config = resolve_run_config(scenario, set_, seeds)
    if isinstance(config, PlanarConfig):
        run_planar_config(config, out, jobs)
        return
    with progress_bar(config.name, line_step=0) as update:
        study = run_nav_study(
            config, runs_root=out, progress=update, jobs=jobs or os.cpu_count() or 1
        )
    s = study.summary
    table = Table(title=f"{config.name}: {s.seeds} seed(s) (median; worst case where marked)")
    table.add_column("metric")
    table.add_column("value", justify="right")
    rows = [
        ("output position RMSE in the air (m)", s.output_rmse_m),
        ("output position RMSE with vision (m)", s.output_rmse_with_vision_m),
        ("error at the end of a dropout, worst (m)", s.dropout_end_error_max_m),
        ("back under 3 cm after a dropout, worst (s)", s.dropout_recovery_max_s),
        ("hover horizontal error, worst (m)", s.hold_max_horizontal_error_m),
        ("delayed estimate RMSE (m)", s.delayed_rmse_m),
        ("attitude RMSE (deg)", s.attitude_rmse_deg),
        ("NEES, mean (15 states)", s.nees_mean),
        ("horizontal error at the end, landed (m)", s.end_horizontal_error_m),
        ("  = drift in % of the distance flown", s.drift_percent),
        (
            "gyro bias error / true bias, 60 s after alignment or at the end",
            s.gyro_bias_error_fraction_median,
        ),
        (
            "accel bias error / true bias, 60 s after alignment or at the end",
            s.accel_bias_error_fraction_median,
        ),
    ]
    for k, v in rows:
        table.add_row(k, fmt_metric(v))
    for src, frac in s.nis_above_95pct_gate.items():
        table.add_row(f"{src}: innovations beyond the 95 % gate", f"{frac:.1%}")
    console.print(table)
    console.print(str(study.run_dir), soft_wrap=True, highlight=False)


run_command.__doc__ = command_help(
    "Run the main job. With no arguments: thesis 000's indoor flight over printed markers.",
    "A quadrotor aligns on the ground, takes off to 1.5 m, holds, flies a 2 m square, holds and "
    "lands, flown by a cascaded PID on the navigation EKF's output predictor. The default "
    "renders a downward camera's images of a 6x6 marker field, detects the markers and solves "
    "the pose (30 Hz, 250 ms late, two 2 s dropouts). SCENARIO is a built-in name or a YAML "
    "file; --set overrides any field of it.",
    lists=[
        (
            "Built-in scenarios",
            {
                **{name: e.description for name, e in NAV_SCENARIOS.items()},
                "planar": "thesis 000's planar delayed-GPS study (as quadnav planar)",
            },
        )
    ],
    examples=EXAMPLES,
)
