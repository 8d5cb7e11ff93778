"""``quadnav view RUN_DIR``: the recording of an existing run folder, written headless (the
default) and, with ``spawn``, opened in rerun's viewer.

The folders of ``quadnav run``, ``sim``, ``markers``, ``replay``, ``vio`` and ``slam`` and a
dataset of ``quadnav dataset make`` can be shown (:mod:`quadnav.viz.folders`); any other folder
is a one-line error naming it. Opening the viewer needs a display and rerun's viewer binary (``rerun``, which
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
from quadnav.viz.folders import folder_kind, record_folder
from quadnav.viz.recording import RECORDING_FILE, RecordingInfo, require_rerun
from quadnav.viz.stream import rerun_url

__all__ = ["ViewResult", "check_view_out", "open_viewer", "view_run", "viewer_problem"]


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


def open_viewer(path: Path) -> str | None:
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


def view_run(
    run_dir: Path, *, out: Path | None = None, spawn: bool = False, connect: str | None = None
) -> ViewResult:
    """Build the recording of ``run_dir`` (to ``out``, default ``RUN_DIR/recording.rrd``),
    stream it to ``connect`` (``HOST:PORT`` or a rerun URL, loopback) and, with ``spawn``, open
    it in the viewer."""
    run_dir = Path(run_dir)
    require_rerun("quadnav view")
    check_view_out(out)
    url = None if connect is None else rerun_url(connect, "--connect")
    if not run_dir.is_dir():
        raise VizError(f"{run_dir}: no such folder")
    target = out if out is not None else run_dir / RECORDING_FILE
    kind = folder_kind(run_dir)
    if kind is None:
        raise VizError(
            f"{run_dir}: not a folder quadnav view can show (quadnav run, sim, markers, replay, "
            "vio or slam's, or a dataset quadnav dataset make wrote)"
        )
    try:
        info = record_folder(kind, run_dir, target, connect=url)
    except IoError as exc:
        raise VizError(str(exc)) from None
    if not spawn:
        return ViewResult(recording=info, spawned=False, note=info.note)
    problem = open_viewer(info.path)
    note = "" if problem is None else f"viewer not opened: {problem}; the recording is written"
    note = "; ".join(x for x in (info.note, note) if x)
    return ViewResult(recording=info, spawned=problem is None, note=note)
