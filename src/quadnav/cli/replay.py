"""``quadnav replay LOG.ulg``: our navigation EKF over a PX4 log's sensors, next to PX4's own
estimate and (SITL logs) the simulator's ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quadnav.cli.common import (
    CommandParams,
    RerunConnectOpt,
    RerunOpt,
    RerunSpawnOpt,
    command_help,
    console,
    err_console,
    finish_recording,
    handle_errors,
    progress_bar,
    rerun_param,
    rerun_request,
    start_recording,
    strings_param,
)
from quadnav.cli.planar import OutOpt, SetOpt
from quadnav.experiments.replay import config_from_px4
from quadnav.experiments.replay_run import replay_cell, replay_log, replay_overrides

__all__ = ["EXAMPLES", "check_example", "replay_command"]


def check_example(params: CommandParams) -> None:
    """Validate an example's --set keys and values (on EKF2's defaults, no log read)."""
    config_from_px4({}, replay_overrides(strings_param(params, "set_")))
    rerun_param(params)


#: The examples of ``quadnav replay --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav replay flight.ulg",
    "quadnav replay flight.ulg --set gps_delay_s=0.2 --set gate_sigma=5",
    "quadnav replay crash.ulg --set baro_noise_m=2 --out /tmp/runs",
    "quadnav replay flight.ulg --rerun",
)


@handle_errors
def replay_command(
    log: Annotated[Path, typer.Argument(help="PX4 ULog file")],
    set_: SetOpt = None,
    out: OutOpt = Path("runs"),
    rerun: RerunOpt = False,
    rerun_connect: RerunConnectOpt = None,
    rerun_spawn: RerunSpawnOpt = False,
) -> None:
    recorder = start_recording(rerun_request(rerun, rerun_connect, rerun_spawn))
    with progress_bar("replay") as update:
        m = replay_log(log, list(set_ or []), out, update)
    table = Table(
        title=f"replay of {log.name}: {m.duration_s:.1f} s in {m.replay_wall_s:.2f} s ({m.times_faster_than_flight:.0f}x)"
    )
    for c in ("pair", "horizontal RMS (m)", "vertical RMS (m)", "tilt RMS (deg)", "yaw RMS (deg)"):
        table.add_column(c, justify="right" if c != "pair" else "left")
    for k in ("quadnav_vs_px4", "quadnav_vs_truth", "px4_vs_truth"):
        if k in m.pairs:
            v = m.pairs[k]
            table.add_row(
                k.replace("_", " "),
                replay_cell(v.horizontal_rms_m, 3),
                replay_cell(v.vertical_rms_m, 3),
                replay_cell(v.tilt_rms_deg, 2),
                replay_cell(v.yaw_rms_deg, 2),
            )
    console.print(table)
    for n in m.notes:
        err_console.print(f"note: {n}", highlight=False)
    finish_recording(recorder, m.run_dir, "replay")
    console.print(str(m.run_dir), soft_wrap=True, highlight=False)


replay_command.__doc__ = command_help(
    "Replay a PX4 log's sensors through quadnav's navigation EKF and compare with PX4's estimate "
    "(and a SITL log's ground truth).",
    "The filter starts from the log's EKF2 parameters; --set overrides any of them by its "
    "setting name (gps_delay_s, gate_sigma, baro_noise_m...). PX4's GNSS checks decide when "
    "fixes are used; the comparison covers only where PX4 flagged its estimate valid.",
    examples=EXAMPLES,
)
