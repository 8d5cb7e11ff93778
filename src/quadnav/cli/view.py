"""``quadnav view``: the rerun recording of an existing run folder, written or opened."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from quadnav.cli.common import CommandParams, command_help, console, handle_errors, optional_param
from quadnav.viz.stream import rerun_url
from quadnav.viz.view import check_view_out, view_run

__all__ = ["EXAMPLES", "check_example", "view_command"]

#: The examples of ``quadnav view --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav view runs/2026-01-05_10-00-00_indoor_vision",
    "quadnav view runs/2026-01-05_10-00-00_indoor_vision --out flight.rrd",
    "quadnav view runs/2026-01-05_10-00-00_indoor_vision --spawn",
    "quadnav view runs/2026-01-05_10-00-00_indoor_vision --connect 127.0.0.1:9876",
)


def check_example(params: CommandParams) -> None:
    """Validate an example's arguments as the command would, without reading the folder."""
    check_view_out(optional_param(params, "out", Path))
    connect = optional_param(params, "connect", str) if "connect" in params else None
    if connect is not None:
        rerun_url(connect, "--connect")


@handle_errors
def view_command(
    run_dir: Annotated[
        Path,
        typer.Argument(
            help="a run folder (quadnav run, sim, markers, replay, vio, slam) or dataset"
        ),
    ],
    out: Annotated[
        Path | None,
        typer.Option("--out", help="the recording to write (default RUN_DIR/recording.rrd)"),
    ] = None,
    spawn: Annotated[
        bool, typer.Option("--spawn", help="open the recording in rerun's viewer too")
    ] = False,
    connect: Annotated[
        str | None,
        typer.Option(
            "--connect",
            help="stream it to a rerun viewer listening at ADDR too (HOST:PORT, loopback)",
            metavar="ADDR",
        ),
    ] = None,
) -> None:
    result = view_run(run_dir, out=out, spawn=spawn, connect=connect)
    rec = result.recording
    console.print(f"{rec.path} ({rec.size_bytes / 1e6:.2f} MB)", soft_wrap=True, highlight=False)
    if result.note:
        console.print(result.note, soft_wrap=True, highlight=False)


view_command.__doc__ = command_help(
    "Build the rerun recording of a run folder from its files, and write or open it.",
    "The recording (an .rrd, quadnav\\[viz]) shows, on a timeline t in seconds, a flight's "
    "truth, output and delayed trajectories, the vehicle's pose and body axes, the setpoint, "
    "the delayed estimate's 3-sigma ellipsoids, the innovations and test ratios per source and "
    "the filter's events; a VIO or SLAM run's estimate and truth, keyframes, loops, events and, "
    "if it ran with --rerun, the camera's image with its features, the landmarks and the "
    "covariances; a simulated flight's controls, a replay's three trajectories and GNSS checks, "
    "a marker run's targets, poses, camera and drawn frames, a dataset's truth, images and IMU. "
    "Written headless by default; --spawn opens rerun's viewer on it (without a display or the "
    "viewer, one line says so and the file is still written); --connect streams it to a viewer "
    "already running.",
    examples=EXAMPLES,
)
