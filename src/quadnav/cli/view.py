"""``quadnav view``: the rerun recording of an existing run folder, written or opened."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from quadnav.cli.common import CommandParams, command_help, console, handle_errors, optional_param
from quadnav.viz.view import check_view_out, view_run

__all__ = ["EXAMPLES", "check_example", "view_command"]

#: The examples of ``quadnav view --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav view runs/2026-01-05_10-00-00_indoor_vision",
    "quadnav view runs/2026-01-05_10-00-00_indoor_vision --out flight.rrd",
    "quadnav view runs/2026-01-05_10-00-00_indoor_vision --spawn",
)


def check_example(params: CommandParams) -> None:
    """Validate an example's arguments as the command would, without reading the folder."""
    check_view_out(optional_param(params, "out", Path))


@handle_errors
def view_command(
    run_dir: Annotated[Path, typer.Argument(help="a run folder (quadnav run, vio or slam's)")],
    out: Annotated[
        Path | None,
        typer.Option("--out", help="the recording to write (default RUN_DIR/recording.rrd)"),
    ] = None,
    spawn: Annotated[
        bool, typer.Option("--spawn", help="open the recording in rerun's viewer too")
    ] = False,
) -> None:
    result = view_run(run_dir, out=out, spawn=spawn)
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
    "covariances. Written headless by default; --spawn opens rerun's viewer on it (without a "
    "display or the viewer, one line says so and the file is still written). quadnav run, vio "
    "and slam's folders can be shown so far.",
    examples=EXAMPLES,
)
