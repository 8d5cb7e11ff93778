"""``quadnav view RUN_DIR``: the recording of an existing run folder, written headless (the
default) and, with ``spawn``, opened in rerun's viewer.

Navigation runs (``quadnav run``) and visual odometry runs (``quadnav vio``, ``quadnav slam``)
can be shown; any other folder is a one-line error naming it. Opening the viewer needs a display and rerun's viewer binary (``rerun``, which
``rerun-sdk`` installs); without them one line says so and the file is written all the same.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from quadnav.errors import IoError, VizError
from quadnav.io.nav_run_files import is_nav_run_folder, read_nav_run
from quadnav.io.odometry_run_files import is_odometry_run_folder, read_odometry_run
from quadnav.viz.nav_recording import write_nav_recording
from quadnav.viz.recording import RECORDING_FILE, RecordingInfo, require_rerun

__all__ = ["ViewResult", "check_view_out", "view_run", "viewer_problem"]


@dataclass(frozen=True, slots=True, kw_only=True)
class ViewResult:
    """The recording written, and whether a viewer was started (or why not)."""

    recording: RecordingInfo
    spawned: bool
    note: str = ""


def _viewer_binary() -> str | None:
    beside = Path(sys.executable).parent / "rerun"
    return str(beside) if beside.is_file() else shutil.which("rerun")


def viewer_problem() -> str | None:
    """Why rerun's viewer cannot be opened here (``None`` when it can)."""
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        return "no display (DISPLAY, WAYLAND_DISPLAY unset)"
    if _viewer_binary() is None:
        return "no rerun viewer binary on PATH"
    return None


def _spawn(path: Path) -> str | None:
    """Start the viewer on ``path`` in the background; why not, if it could not start."""
    if (problem := viewer_problem()) is not None:
        return problem
    binary = _viewer_binary()
    assert binary is not None
    try:
        subprocess.Popen(
            [binary, str(path)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
    except OSError as exc:
        return f"the viewer did not start ({exc})"
    return None


def check_view_out(out: Path | None) -> None:
    """Refuse an ``--out`` that is not an ``.rrd`` file."""
    if out is not None and Path(out).suffix != ".rrd":
        raise VizError(f"--out {out}: give a file ending in .rrd")


def view_run(run_dir: Path, *, out: Path | None = None, spawn: bool = False) -> ViewResult:
    """Build the recording of ``run_dir`` (to ``out``, default ``RUN_DIR/recording.rrd``) and,
    with ``spawn``, open it in the viewer."""
    run_dir = Path(run_dir)
    require_rerun("quadnav view")
    check_view_out(out)
    if not run_dir.is_dir():
        raise VizError(f"{run_dir}: no such folder")
    target = out if out is not None else run_dir / RECORDING_FILE
    try:
        if is_nav_run_folder(run_dir):
            info = write_nav_recording(read_nav_run(run_dir), target)
        elif is_odometry_run_folder(run_dir):
            from quadnav.viz.odometry_recording import write_odometry_recording

            info = write_odometry_recording(read_odometry_run(run_dir), target)
        else:
            raise VizError(
                f"{run_dir}: not a run folder quadnav view can show yet (quadnav run, vio and "
                "slam's)"
            )
    except IoError as exc:
        raise VizError(str(exc)) from None
    if not spawn:
        return ViewResult(recording=info, spawned=False)
    problem = _spawn(info.path)
    note = "" if problem is None else f"viewer not opened: {problem}; the recording is written"
    return ViewResult(recording=info, spawned=problem is None, note=note)
