"""``quadnav markers SOURCE``: thesis 000's marker program on a folder of images, a video or a
camera: poses with covariance to CSV, an overlay video, per-stage timing and the fraction of
frames with a pose."""

from __future__ import annotations

import math
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
    progress_bar,
    rerun_param,
    rerun_request,
    start_recording,
    strings_param,
)
from quadnav.cli.planar import AllowRemoteOpt, OutOpt, SetOpt
from quadnav.errors import IoError
from quadnav.experiments.markers_run import (
    MarkersStats,
    load_markers_config,
    run_markers,
    window_or_not,
)
from quadnav.io.mavlink import check_bind, describe_traffic
from quadnav.vision.config import MarkersConfig

__all__ = [
    "EXAMPLES",
    "check_example",
    "markers_command",
]


@handle_errors
def markers_command(
    source: Annotated[str, typer.Argument(help="image folder, video file or camera index (0)")],
    params: Annotated[
        Path | None,
        typer.Option("--params", help="parameters: our YAML or the thesis's vision_params.yml"),
    ] = None,
    camera: Annotated[
        Path | None, typer.Option("--camera", help="calibration, OpenCV YAML")
    ] = None,
    set_: SetOpt = None,
    out: OutOpt = Path("runs"),
    mavlink: Annotated[
        str | None,
        typer.Option(
            "--mavlink", help="send the poses to an autopilot, e.g. udpout:127.0.0.1:14540"
        ),
    ] = None,
    allow_remote: AllowRemoteOpt = False,
    setpoints: Annotated[
        Path | None,
        typer.Option(
            "--setpoints", help="with --mavlink: a trajectory to send as position setpoints"
        ),
    ] = None,
    fps: Annotated[
        float | None,
        typer.Option(
            "--fps",
            help="frame rate of images or a stream without timestamps (raw .h264); asked of a camera",
        ),
    ] = None,
    show: Annotated[
        bool | None,
        typer.Option(
            "--show/--no-show",
            help="show the overlay in a window (q or Esc stops); default: the parameters' "
            "show (the thesis's open_window), left off where there is no display",
        ),
    ] = None,
    max_images_mb: Annotated[
        float | None,
        typer.Option(
            "--max-images-mb",
            help="with write_images (the thesis's): stop writing images past this many MB "
            "(default 200)",
        ),
    ] = None,
    rerun: RerunOpt = False,
    rerun_connect: RerunConnectOpt = None,
    rerun_spawn: RerunSpawnOpt = False,
) -> None:
    cfg, notes = _resolve(mavlink, allow_remote, set_, camera, fps, show, params, max_images_mb)
    recorder = start_recording(rerun_request(rerun, rerun_connect, rerun_spawn))
    for note in notes:
        _note(note)
    with progress_bar("markers") as update:
        stats = run_markers(
            cfg,
            source,
            out,
            progress=update,
            mavlink=mavlink,
            allow_remote=allow_remote,
            setpoints=setpoints,
            notify=_note,
        )
    for note in stats.notes:
        err_console.print(f"note: {note}", highlight=False, soft_wrap=True)
    _print_summary(stats)
    finish_recording(recorder, stats.run_dir, "markers")


def _note(text: str) -> None:
    err_console.print(f"note: {text}", highlight=False, soft_wrap=True)


def _resolve(
    mavlink: str | None,
    allow_remote: bool,
    set_: list[str] | None,
    camera: Path | None,
    fps: float | None,
    show: bool | None,
    params: Path | None,
    max_images_mb: float | None = None,
) -> tuple[MarkersConfig, list[str]]:
    """The validated configuration of the command's options, and notes for the user (the
    thesis keys not used, a window the parameters ask for where none can open)."""
    if mavlink is not None:
        check_bind(mavlink, allow_remote=allow_remote)  # before anything is read or written
    overrides = list(set_ or [])
    if camera is not None:
        if not camera.is_file():
            why = "is a folder, not a calibration file" if camera.is_dir() else "no such file"
            raise IoError(f"--camera {camera}: {why}")
        overrides.append(f"camera_file={camera}")
    overrides += [f"fps={fps}"] if fps is not None else []
    if max_images_mb is not None:
        check_range(max_images_mb, "--max-images-mb", 0.0, 1e7, "MB", low_open=True)
        overrides.append(f"max_images_mb={max_images_mb}")
    overrides += [f"show={str(show).lower()}"] if show is not None else []
    cfg, ignored = load_markers_config(params, overrides)
    asked = any(o.replace(" ", "").startswith("show=") for o in overrides)
    cfg, window_note = window_or_not(cfg, asked=asked)
    notes = [f"parameters not used here: {', '.join(ignored)}"] if ignored else []
    return cfg, notes + ([window_note] if window_note else [])


def check_example(p: CommandParams) -> None:
    """Validate an example's options and configuration as the command would, reading no frame."""
    _resolve(
        optional_param(p, "mavlink", str),
        param(p, "allow_remote", bool),
        strings_param(p, "set_"),
        optional_param(p, "camera", Path),
        optional_param(p, "fps", float),
        optional_param(p, "show", bool),
        optional_param(p, "params", Path),
        optional_param(p, "max_images_mb", float),
    )
    rerun_param(p)


#: The examples of ``quadnav markers --help`` (each parsed and validated by the tests, from the
#: project's folder, with the shared data beside it).
EXAMPLES = (
    "quadnav markers ../shared/data/thesis_rig/board12_17.mp4 --params ../shared/data/thesis_rig/vision_params.yml --camera ../shared/data/thesis_rig/cal.yml",
    "quadnav markers ../shared/data/aruco --camera ../shared/data/aruco/tutorial_camera_charuco.yml --set dictionary=DICT_6X6_250 --set marker_length_m=0.05",
    "quadnav markers 0 --params ../shared/data/thesis_rig/vision_params.yml --camera ../shared/data/thesis_rig/cal.yml --show",
    "quadnav markers frames.h264 --camera ../shared/data/thesis_rig/cal.yml --fps 40 --set target=charuco",
    "quadnav markers 0 --camera ../shared/data/thesis_rig/cal.yml --mavlink udpout:127.0.0.1:14540",
)


def _value(x: float, spec: str, why: str) -> str:
    """A number of the summary, or ``n/a`` and why it has none."""
    return format(x, spec) if math.isfinite(x) else f"n/a ({why})"


def _print_summary(stats: MarkersStats) -> None:
    table = Table(title=f"markers: {stats.source}")
    table.add_column("measure")
    table.add_column("value", justify="right")
    table.add_row("frames", str(stats.frames))
    table.add_row("time base", stats.time_base)
    for p in stats.camera_properties:
        verdict = "accepted" if p.accepted else "not accepted"
        table.add_row(f"camera {p.name}", f"asked {p.requested:g}, got {p.got:g} ({verdict})")
    table.add_row("frames skipped (unreadable, other size)", str(stats.frames_skipped))
    table.add_row(
        "frames with a pose", f"{stats.frames_with_pose} ({stats.fraction_with_pose:.1%})"
    )
    if stats.frames_marker_fallback:
        table.add_row("  of them from a board's marker corners", str(stats.frames_marker_fallback))
    table.add_row("frames rejected (degenerate view, bad fit)", str(stats.frames_rejected))
    jitter = (
        f"{stats.jitter_rms_mm:.2f} / {stats.jitter_median_mm:.2f}"
        if math.isfinite(stats.jitter_rms_mm)
        else "n/a (no 3 consecutive frames with a pose)"
    )
    table.add_row("frame-to-frame jitter, RMS / median (mm)", jitter)
    table.add_row(
        "detection, median (ms)", _value(stats.detect_ms_median, ".2f", "no frame processed")
    )
    table.add_row("pose, median (ms)", _value(stats.pose_ms_median, ".2f", "no pose"))
    table.add_row("reprojection error, median (px)", _value(stats.rms_px_median, ".3f", "no pose"))
    if stats.images_written or stats.images_not_written:
        images = f"{stats.images_written} ({stats.images_mb:.1f} MB)"
        if stats.images_not_written:
            images += f"; {stats.images_not_written} not written (past --max-images-mb)"
        table.add_row("overlay images in images/", images)
    if stats.mavlink is not None:
        m = stats.mavlink
        by_name = ", ".join(f"{k} {v}" for k, v in m.sent.items())
        table.add_row("MAVLink messages sent", f"{by_name}; {describe_traffic(m.sent, m.received)}")
    console.print(table)
    console.print(str(stats.run_dir), soft_wrap=True, highlight=False)


markers_command.__doc__ = command_help(
    "Detect markers and estimate the vehicle's pose in every frame of SOURCE.",
    "SOURCE is an image folder, a video (a raw .h264 is timed at --fps) or a camera index. "
    "Targets: single ArUco/AprilTag markers, ChArUco boards and diamonds, marker maps; the pose "
    "goes through the camera mount to the vehicle, with its covariance. --params takes our "
    "YAML or the thesis's vision_params.yml; --mavlink sends each pose to an autopilot.",
    examples=EXAMPLES,
)
