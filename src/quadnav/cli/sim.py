"""``quadnav sim``: fly a scenario (built-in or YAML) and write a run folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quadnav.cli.common import console, handle_errors
from quadnav.errors import ConfigError
from quadnav.eval.flight import write_flight_run
from quadnav.experiments.flight import BUILTIN, FlightConfig, builtin_config, run_flight
from quadnav.io.config import apply_override, load_config

__all__ = ["sim_command"]


@handle_errors
def sim_command(
    scenario: Annotated[
        str, typer.Argument(help="a built-in scenario name or a YAML file")
    ] = "circle",
    set_: Annotated[
        list[str] | None, typer.Option("--set", help="override one field, e.g. --set duration_s=10")
    ] = None,
    out: Annotated[Path, typer.Option("--out", help="folder that receives the run folder")] = Path(
        "runs"
    ),
    list_: Annotated[bool, typer.Option("--list", help="list the built-in scenarios")] = False,
) -> None:
    """Fly a closed-loop scenario on the true state: thesis 002's PD and nested-saturation
    simulations, the rigid-body circle with the cascaded PID, thesis 003's take-off and
    obstacle experiments.

    Examples:

      quadnav sim --list

      quadnav sim thesis002_nested_tracking

      quadnav sim circle_gusts --set wind.gust_sigma_m_s=3
    """
    if list_:
        for name in BUILTIN:
            console.print(name, highlight=False)
        return
    overrides = list(set_ or [])
    if scenario in BUILTIN:
        data = builtin_config(scenario)
        for o in overrides:
            apply_override(data, o)
        from pydantic import ValidationError

        try:
            config = FlightConfig.model_validate(data)
        except ValidationError as exc:
            err = exc.errors()[0]
            loc = ".".join(str(p) for p in err["loc"])
            raise ConfigError(
                f"invalid scenario: {loc + ': ' if loc else ''}{err['msg']}"
            ) from None
    else:
        path = Path(scenario)
        if not path.exists():
            raise ConfigError(
                f"{scenario!r} is neither a built-in scenario ({', '.join(BUILTIN)}) nor a file"
            )
        config = load_config(FlightConfig, path, overrides)
    with console.status(f"flying {config.name} ({config.duration_s:g} s)..."):
        run = run_flight(config)
        run_dir, m = write_flight_run(run, runs_root=out)
    table = Table(title=f"{config.name}")
    table.add_column("metric")
    table.add_column("value", justify="right")
    for key in (
        "tracking_rmse_m",
        "tracking_rmse_whole_run_m",
        "settling_time_s",
        "overshoot_pct",
        "peak_thrust_n",
        "peak_torque",
        "saturation_time_s",
        "max_tilt_deg",
        "min_obstacle_distance_m",
        "sim_seconds_per_wall_second",
    ):
        if key in m and m[key] is not None:
            v = m[key]
            if isinstance(v, dict):
                v = ", ".join(f"{k} {x:.3g}" for k, x in v.items()) or "-"
            table.add_row(key, f"{v:.4g}" if isinstance(v, float) else str(v))
    for key, v in m["events"].items():
        table.add_row(key, str(v))
    console.print(table)
    console.print(str(run_dir), soft_wrap=True, highlight=False)
