"""``quadnav sim``: fly a scenario (built-in or YAML) and write a run folder."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quadnav.cli.common import (
    CommandParams,
    RerunConnectOpt,
    RerunOpt,
    RerunSpawnOpt,
    check_range,
    command_help,
    console,
    err_console,
    finish_recording,
    handle_errors,
    optional_param,
    param,
    rerun_param,
    rerun_request,
    start_recording,
    strings_param,
)
from quadnav.errors import ConfigError
from quadnav.eval.na import fmt_metric
from quadnav.experiments.flight import (
    BUILTIN,
    BUILTIN_DESCRIPTIONS,
    FlightConfig,
    builtin_config,
    run_flight,
)
from quadnav.experiments.flight_study import FlightMetrics, write_flight_run
from quadnav.io.config import load_config
from quadnav.io.mavlink import (
    SIGNING_KEY_ENV,
    check_bind,
    read_signing_key,
    signing_key_file_warning,
)

__all__ = ["EXAMPLES", "check_example", "sim_command"]

MAX_SITL_S = 86_400.0  # --duration: a day at most


#: The examples of ``quadnav sim --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav sim --list",
    "quadnav sim thesis002_nested_tracking",
    "quadnav sim thesis002_slam_square_pd",
    "quadnav sim thesis002_slam_sigmoid_nested --set position_source=serial_truth",
    "quadnav sim circle_gusts --set wind.gust_sigma_m_s=3",
    "quadnav sim thesis003_obstacle --set duration_s=40",
    "quadnav sim thesis003_waypoints --set thesis003.kp_lin=0.3",
    "quadnav sim thesis002_pd_stabilization --set el_pd_gains=table_5_1",
    "quadnav sim --mavlink udpin:127.0.0.1:14540 --signing-key-file key.hex --duration 60",
    "quadnav sim circle --rerun",
    "quadnav sim circle --rerun-connect 127.0.0.1:9876",
)


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
            "--signing-key",
            help="MAVLink 2 signing key, 64 hex digits (visible in ps: prefer --signing-key-file "
            f"or {SIGNING_KEY_ENV}); unsigned messages are ignored",
        ),
    ] = None,
    signing_key_file: Annotated[
        Path | None,
        typer.Option(
            "--signing-key-file",
            help=f"with --mavlink: a file holding the signing key, 64 hex digits (or set {SIGNING_KEY_ENV})",
        ),
    ] = None,
    allow_remote: Annotated[
        bool,
        typer.Option(
            "--allow-remote", help="with --mavlink: let udpin/tcpin bind a non-loopback address"
        ),
    ] = False,
    duration: Annotated[
        float | None,
        typer.Option(
            "--duration",
            help=f"with --mavlink: stop after this many seconds (at most {MAX_SITL_S:g})",
        ),
    ] = None,
    rerun: RerunOpt = False,
    rerun_connect: RerunConnectOpt = None,
    rerun_spawn: RerunSpawnOpt = False,
) -> None:
    link_options = (mavlink, signing_key, signing_key_file, duration)
    recording = rerun_request(rerun, rerun_connect, rerun_spawn)
    if recording is not None and (mavlink is not None or list_):
        raise ConfigError("--rerun: records a scenario's flight (not --mavlink or --list)")
    if allow_remote or any(v is not None for v in link_options):
        _run_sitl(mavlink, signing_key, signing_key_file, duration, allow_remote=allow_remote)
        return
    if list_:
        for name in BUILTIN:
            console.print(f"{name}: {BUILTIN_DESCRIPTIONS[name]}", highlight=False, soft_wrap=True)
        return
    config = _load_scenario(scenario, list(set_ or []))
    recorder = start_recording(recording)
    with console.status(f"flying {config.name} ({config.duration_s:g} s)..."):
        run = run_flight(config)
        run_dir, m = write_flight_run(run, runs_root=out)
    _print_flight(config.name, m, run_dir)
    finish_recording(recorder, run_dir, "sim")


def check_example(params: CommandParams) -> None:
    """Validate an example's arguments as the command would, without flying or binding."""
    mavlink = optional_param(params, "mavlink", str)
    if mavlink is not None:
        check_bind(mavlink, allow_remote=param(params, "allow_remote", bool))
        duration = optional_param(params, "duration", float)
        if duration is not None:
            check_range(duration, "--duration", 0.0, MAX_SITL_S, "seconds", low_open=True)
    elif not param(params, "list_", bool):
        _load_scenario(param(params, "scenario", str), strings_param(params, "set_"))
    rerun_param(params)


def _load_scenario(scenario: str, overrides: list[str]) -> FlightConfig:
    if scenario in BUILTIN:
        return load_config(FlightConfig, None, overrides, base=builtin_config(scenario))
    else:
        path = Path(scenario)
        if not path.exists():
            raise ConfigError(
                f"{scenario!r} is neither a built-in scenario ({', '.join(BUILTIN)}) nor a file"
            )
        return load_config(FlightConfig, path, overrides)


def _print_flight(name: str, m: FlightMetrics, run_dir: Path) -> None:
    table = Table(title=f"{name}")
    table.add_column("metric")
    table.add_column("value", justify="right")
    shown = (
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
    )
    values = dict(m.rows())
    for key in shown:
        if key in values:
            v = values[key]
            if isinstance(v, dict):
                v = ", ".join(f"{k} {x:.3g}" for k, x in v.items()) or "-"
            table.add_row(key, fmt_metric(v))
    for key, v in m.events.items():
        if isinstance(v, tuple):
            v = ", ".join(f"{x:.3g}" for x in v)
        table.add_row(key, str(v))
    console.print(table)
    console.print(str(run_dir), soft_wrap=True, highlight=False)


def _run_sitl(
    url: str | None,
    key_hex: str | None,
    key_file: Path | None,
    duration: float | None,
    *,
    allow_remote: bool,
) -> None:
    """The simulated vehicle with its EKF, speaking MAVLink (loopback unless --allow-remote)."""
    from quadnav.experiments.sitl import SitlVehicle

    if url is None:
        given = [
            name
            for name, v in (
                ("--signing-key", key_hex),
                ("--signing-key-file", key_file),
                ("--allow-remote", allow_remote or None),
                ("--duration", duration),
            )
            if v is not None
        ]
        raise ConfigError(
            f"{', '.join(given)}: only with --mavlink (a scenario's length is --set duration_s=...)"
        )
    if duration is not None:
        check_range(duration, "--duration", 0.0, MAX_SITL_S, "seconds", low_open=True)
    key = read_signing_key(key_hex=key_hex, key_file=key_file, environ=os.environ)
    unprotected = signing_key_file_warning(key_file) if key_file is not None else None
    if unprotected:
        err_console.print(unprotected, highlight=False, soft_wrap=True)
    if key_hex is not None:
        err_console.print(
            f"warning: --signing-key shows the key to every user of this machine (ps); use --signing-key-file or {SIGNING_KEY_ENV}",
            highlight=False,
            soft_wrap=True,
        )
    vehicle = SitlVehicle(url=url, signing_key=key, allow_remote=allow_remote)
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
    console.print(
        f"{vehicle.link.describe()}, refused unsigned "
        f"{st.refused_unsigned}, bad packets {st.bad_packets}, vision estimates fused from the link "
        f"{vehicle.est.stats('mavlink_vision').fused}",
        highlight=False,
    )


sim_command.__doc__ = command_help(
    "Fly a closed-loop scenario on the true state, or be a MAVLink vehicle (--mavlink).",
    "Thesis 002's PD and nested-saturation simulations, the rigid-body circle with the cascaded "
    "PID, thesis 003's take-off, waypoint and obstacle experiments with its gains (thesis003.*). "
    "With --mavlink, the simulated vehicle "
    "with its EKF speaks MAVLink in real time (loopback unless --allow-remote).",
    lists=[("Built-in scenarios", BUILTIN_DESCRIPTIONS)],
    examples=EXAMPLES,
)
