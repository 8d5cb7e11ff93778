"""``quadnav link serial PORT``: stream an estimate to a flight controller as thesis 002's
``X<cm>Y<cm>Z<cm>F`` frames over a serial port (115200 8N1 by default)."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Annotated

import typer

from quadnav.cli.common import (
    CommandParams,
    check_range,
    command_help,
    console,
    handle_errors,
    optional_param,
    param,
    progress_bar,
)
from quadnav.errors import ConfigError, IoError
from quadnav.io.serial_frame import encode
from quadnav.io.trajectory_io import FORMATS, read_trajectory

__all__ = ["EXAMPLES", "check_example", "link_app"]

MIN_BAUD, MAX_BAUD = 50, 4_000_000  # what Linux UARTs take (B50 to B4000000)
MAX_RATE_HZ = 1000.0  # a 115200-baud link carries about 870 frames per second

link_app = typer.Typer(help="Links to a flight controller: serial frames.", no_args_is_help=True)


def open_serial(port: str, baud: int) -> object:
    import serial  # type: ignore[import-untyped]

    try:
        return serial.Serial(port, baudrate=baud, bytesize=8, parity="N", stopbits=1, timeout=0.1)
    except (serial.SerialException, OSError, ValueError) as exc:
        errno = getattr(exc, "errno", None)  # pyserial's own text repeats the errno and port
        why = os.strerror(errno) if isinstance(errno, int) else str(exc)
        raise IoError(f"serial port {port}: {why}") from None


def _check_options(baud: int, rate_hz: float, fmt: str | None) -> None:
    check_range(baud, "--baud", MIN_BAUD, MAX_BAUD, "bits per second")
    check_range(
        rate_hz, "--rate", 0.0, MAX_RATE_HZ, "frames per second (0: as fast as the link takes)"
    )
    if fmt is not None and fmt not in FORMATS:
        raise ConfigError(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}")


def check_example(params: CommandParams) -> None:
    """Validate an example's options as the command would, without opening the port."""
    _check_options(
        param(params, "baud", int),
        param(params, "rate_hz", float),
        optional_param(params, "fmt", str),
    )


#: The examples of ``quadnav link serial --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav link serial /dev/ttyTHS1 --from estimate.tum",
    "quadnav link serial /dev/ttyACM0 --from runs/flight/output.tum --baud 57600 --rate 20",
    "quadnav link serial /dev/ttyUSB0 --from slam_poses.csv --rate 0",
)


@link_app.command("serial")
@handle_errors
def serial_command(
    port: Annotated[str, typer.Argument(help="serial device, e.g. /dev/ttyTHS1")],
    source: Annotated[
        Path,
        typer.Option(
            "--from", help="trajectory to stream (TUM, EuRoC, KITTI, quadnav CSV, ULog, bag)"
        ),
    ],
    baud: Annotated[
        int, typer.Option("--baud", help=f"bits per second, {MIN_BAUD} to {MAX_BAUD}")
    ] = 115200,
    rate_hz: Annotated[
        float,
        typer.Option(
            "--rate",
            help=f"frames per second, at most {MAX_RATE_HZ:g} (0: as fast as the link takes)",
        ),
    ] = 10.0,
    fmt: Annotated[
        str | None,
        typer.Option("--format", help=f"format of --from: {', '.join(FORMATS)} [default: guessed]"),
    ] = None,
) -> None:
    _check_options(baud, rate_hz, fmt)
    try:
        traj = read_trajectory(source, fmt)
    except IoError as exc:
        raise IoError(f"--from: {exc}") from None
    link = open_serial(port, baud)
    period = 1.0 / rate_hz if rate_hz > 0 else 0.0
    sent = 0
    t_next = time.perf_counter()
    with progress_bar("link") as update:
        for k, p in enumerate(traj.p_W_B):
            link.write(encode(*map(float, p)))  # type: ignore[attr-defined]
            sent += 1
            if period:
                t_next += period
                time.sleep(max(0.0, t_next - time.perf_counter()))
            if k % 50 == 0:
                update(k + 1, len(traj), f"{sent} frames")
    link.flush()  # type: ignore[attr-defined]
    link.close()  # type: ignore[attr-defined]
    console.print(f"{sent} frames sent to {port} at {baud} baud", highlight=False)


serial_command.__doc__ = command_help(
    "Send each pose of a trajectory as thesis 002's X<cm>Y<cm>Z<cm>F serial frame, paced at "
    "--rate (the thesis used 10 Hz), 8N1.",
    examples=EXAMPLES,
)
