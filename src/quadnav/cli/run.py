"""``quadnav run``: the main job, with a built-in default scenario."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, TypeVar

import typer
from rich.table import Table

from quadnav.cli.common import (
    CommandParams,
    RerunConnectOpt,
    RerunOpt,
    RerunSpawnOpt,
    command_help,
    console,
    handle_errors,
    optional_param,
    print_recording,
    progress_bar,
    rerun_param,
    rerun_request,
    strings_param,
)
from quadnav.cli.planar import (
    AllowRemoteOpt,
    JobsOpt,
    OutOpt,
    SeedsOpt,
    SetOpt,
    run_planar_config,
)
from quadnav.errors import ConfigError
from quadnav.eval.na import fmt_metric
from quadnav.experiments.nav import NavScenario
from quadnav.experiments.nav_study import NavStudy, NavSummary, reports_in_flight, run_nav_study
from quadnav.experiments.planar import PlanarConfig
from quadnav.experiments.scenarios import NAV_SCENARIOS, nav_builtin
from quadnav.io.config import load_config
from quadnav.io.mavlink import check_bind

__all__ = ["EXAMPLES", "check_example", "resolve_run_config", "run_command"]

T = TypeVar("T")


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
    config = resolve_run_config(
        optional_param(params, "scenario", str),
        [*strings_param(params, "set_"), *_seed_override(_given(params, "seed", int))],
        optional_param(params, "seeds", int),
    )
    rerun_param(params)
    mavlink = _given(params, "mavlink", str)
    if mavlink is not None:
        _check_mavlink(config, mavlink, allow_remote=bool(params.get("allow_remote")))


def _given(params: CommandParams, name: str, kind: type[T]) -> T | None:
    """An optional parameter an example may leave out altogether."""
    return optional_param(params, name, kind) if name in params else None


def _check_mavlink(config: NavScenario | PlanarConfig, url: str, *, allow_remote: bool) -> None:
    """``--mavlink`` sends a VIO's odometry: a scenario with one, a URL that may be bound."""
    if not isinstance(config, NavScenario) or not config.vio.enabled:
        raise ConfigError(
            "--mavlink sends the VIO's odometry: choose a scenario with vio.enabled=true "
            "(indoor_vio, indoor_vio_odometry)"
        )
    check_bind(url, allow_remote=allow_remote)


#: The examples of ``quadnav run --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav run",
    "quadnav run --seeds 20",
    "quadnav run indoor_vision_pose --set vision.delay_s=0.1 --set plan.square_m=4",
    "quadnav run outdoor_gps --set gps.outages_s=[[20,25]]",
    "quadnav run planar --seeds 20",
    "quadnav run indoor_vio --seed 3",
    "quadnav run indoor_vio_odometry --mavlink udpout:127.0.0.1:14540",
    "quadnav run --rerun",
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
    seed: Annotated[
        int | None, typer.Option("--seed", help="the first seed (as --set seed=N)")
    ] = None,
    mavlink: Annotated[
        str | None,
        typer.Option(
            "--mavlink",
            help="send the VIO's odometry (ODOMETRY, as a companion computer) to an autopilot, "
            "e.g. udpout:127.0.0.1:14540; the first seed's",
        ),
    ] = None,
    allow_remote: AllowRemoteOpt = False,
    rerun: RerunOpt = False,
    rerun_connect: RerunConnectOpt = None,
    rerun_spawn: RerunSpawnOpt = False,
) -> None:
    config = resolve_run_config(scenario, [*(set_ or []), *_seed_override(seed)], seeds)
    recording = rerun_request(rerun, rerun_connect, rerun_spawn)
    if isinstance(config, PlanarConfig):
        run_planar_config(config, out, jobs, recording)
        return
    if mavlink is not None:
        _check_mavlink(config, mavlink, allow_remote=allow_remote)
    # piped: a line per seed, or per quarter of a flight on the VIO (a few a run at most)
    step = 0.25 if reports_in_flight(config) else 0
    with progress_bar(config.name, line_step=step) as update:
        study = run_nav_study(
            config,
            runs_root=out,
            progress=update,
            jobs=jobs or os.cpu_count() or 1,
            mavlink=mavlink,
            allow_remote=allow_remote,
            rerun=recording,
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
        ("NEES (15 states), mean over a flight", s.nees_mean),
        ("the visual odometry's own ATE, 4-DoF (m)", s.vio_ate_m),
        ("the visual odometry alone, from its first state (m)", s.vio_alone_m),
        ("VIO + GPS, random-walk filter tuned after the fact (m)", s.vio_gps_reference_m),
        ("horizontal error at the end, landed (m)", s.end_horizontal_error_m),
        ("position error at the end (3-D) (m)", s.end_position_error_m),
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
    _print_refusals(s)
    _print_end(study, mavlink)


def _print_end(study: NavStudy, mavlink: str | None) -> None:
    """What went to the autopilot, the recording, the run folder."""
    if mavlink is not None:
        by_name = ", ".join(f"{n} {k}" for k, n in study.mavlink_sent.items()) or "nothing"
        console.print(f"MAVLink to {mavlink}: {by_name}; {study.mavlink_traffic}", highlight=False)
    print_recording(run_dir=study.run_dir)
    console.print(str(study.run_dir), soft_wrap=True, highlight=False)


#: The filter's events printed at most (all of them are in metrics.json and report.html).
MAX_EVENT_LINES = 10


def _print_refusals(s: NavSummary) -> None:
    """The samples refused and the filter's resets, totals over the seeds, and its events."""
    if not s.refused:
        console.print("Refused samples: none; filter resets: none.", highlight=False)
        return
    table = Table(title=f"Refused and reset: total over {s.seeds} seed(s)")
    table.add_column("what")
    table.add_column("count", justify="right")
    for what, n in s.refused.items():
        table.add_row(what, str(n))
    console.print(table)
    for line in s.filter_events[:MAX_EVENT_LINES]:
        console.print(f"  {line}", highlight=False, soft_wrap=True)
    if (more := len(s.filter_events) - MAX_EVENT_LINES) > 0:
        console.print(f"  ... and {more} more (report.html, metrics.json)", highlight=False)


def _seed_override(seed: int | None) -> list[str]:
    return [] if seed is None else [f"seed={seed}"]


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
