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
from quadnav.io.config import load_config

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
    mavlink: Annotated[
        str | None,
        typer.Option(
            "--mavlink",
            help="run as a MAVLink vehicle in real time instead, e.g. udpin:127.0.0.1:14540",
        ),
    ] = None,
    signing_key: Annotated[
        str | None,
        typer.Option(
            "--signing-key", help="MAVLink 2 signing: 64 hex digits; unsigned messages are ignored"
        ),
    ] = None,
    duration: Annotated[
        float | None,
        typer.Option("--duration", help="with --mavlink: stop after this many seconds"),
    ] = None,
) -> None:
    """Fly a closed-loop scenario on the true state: thesis 002's PD and nested-saturation
    simulations, the rigid-body circle with the cascaded PID, thesis 003's take-off and
    obstacle experiments.

    Examples:

      quadnav sim --list

      quadnav sim thesis002_nested_tracking

      quadnav sim circle_gusts --set wind.gust_sigma_m_s=3
    """
    if mavlink is not None:
        _run_sitl(mavlink, signing_key, duration)
        return
    if list_:
        for name in BUILTIN:
            console.print(name, highlight=False)
        return
    overrides = list(set_ or [])
    if scenario in BUILTIN:
        config = load_config(FlightConfig, None, overrides, base=builtin_config(scenario))
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


def _run_sitl(url: str, signing_key: str | None, duration: float | None) -> None:
    """The simulated vehicle with its EKF, speaking MAVLink (loopback unless told otherwise)."""
    from quadnav.experiments.sitl import SitlVehicle

    key = None
    if signing_key is not None:
        try:
            key = bytes.fromhex(signing_key)
        except ValueError:
            raise ConfigError("--signing-key must be 64 hexadecimal digits") from None
        if len(key) != 32:
            raise ConfigError("--signing-key must be 64 hexadecimal digits (32 bytes)")
    vehicle = SitlVehicle(url=url, signing_key=key)
    console.print(
        f"SITL vehicle on {url}{' (signed)' if key else ''}; Ctrl-C stops it", highlight=False
    )
    try:
        vehicle.run(duration)
    except KeyboardInterrupt:
        pass
    finally:
        vehicle.stop()
    st = vehicle.link.stats
    console.print(f"sent {sum(st.sent.values())}, received {sum(st.received.values())}, refused unsigned "
                  f"{st.refused_unsigned}, bad packets {st.bad_packets}, vision estimates fused from the link "
                  f"{vehicle.est.stats('mavlink_vision').fused}", highlight=False)  # fmt: skip
