"""Which kind of folder a recording is built from, and the one place each kind's recording is
built (for ``quadnav view`` and the child process of ``--rerun``).

Kinds: ``nav`` (``quadnav run``), ``odometry`` (``quadnav vio``, ``quadnav slam``), ``sim``,
``replay``, ``markers``, ``planar`` (``quadnav run planar``) and ``dataset`` (``quadnav dataset
make``'s folder).
"""

from __future__ import annotations

from pathlib import Path

from quadnav.io.folder_files import folder_kind_of
from quadnav.io.nav_run_files import is_nav_run_folder
from quadnav.io.odometry_run_files import is_odometry_run_folder
from quadnav.viz.recording import RECORDING_FILE, RecordingInfo, streaming_to, with_note
from quadnav.viz.stream import listening_problem

__all__ = ["KINDS", "folder_kind", "record_folder"]

#: The kinds of folder a recording is built from.
KINDS = ("nav", "odometry", "sim", "replay", "markers", "planar", "dataset")


def folder_kind(run_dir: Path) -> str | None:
    """The kind of ``run_dir`` (one of ``KINDS``), None when it is none of them."""
    if is_nav_run_folder(run_dir):
        return "nav"
    if is_odometry_run_folder(run_dir):
        return "odometry"
    return folder_kind_of(run_dir)


def record_folder(
    kind: str, run_dir: Path, out: Path | None = None, *, complete: bool = True,
    connect: str | None = None,
) -> RecordingInfo:  # fmt: skip
    """The recording of the finished ``run_dir`` of ``kind``, written to ``out`` (default
    ``RUN_DIR/recording.rrd``) and streamed to ``connect`` (a rerun URL) when something listens
    there (else its note says so); ``complete``: refuse a folder not yet marked complete (a
    run's own recording reads it before; a navigation run's is complete by then)."""
    problem = None if connect is None else listening_problem(connect)
    with streaming_to(None if problem else connect):
        info = _record(kind, Path(run_dir), out, complete=complete)
    return with_note(info, f"{problem}; the recording is in the file" if problem else "")


def _record(kind: str, run_dir: Path, out: Path | None, *, complete: bool) -> RecordingInfo:
    target = out if out is not None else run_dir / RECORDING_FILE
    if kind == "nav":
        from quadnav.io.nav_run_files import read_nav_run
        from quadnav.viz.nav_recording import write_nav_recording

        return write_nav_recording(read_nav_run(run_dir, complete=complete), target)
    if kind == "odometry":
        from quadnav.io.odometry_run_files import read_odometry_run
        from quadnav.viz.odometry_recording import write_odometry_recording

        return write_odometry_recording(read_odometry_run(run_dir, complete=complete), target)
    from quadnav.io import folder_files as ff
    from quadnav.viz import camera_recordings as cam
    from quadnav.viz import flight_recordings as fl

    if kind == "sim":
        return fl.write_sim_recording(ff.read_sim_run(run_dir, complete=complete), target)
    if kind == "replay":
        return fl.write_replay_recording(ff.read_replay_run(run_dir, complete=complete), target)
    if kind == "planar":
        return fl.write_planar_recording(ff.read_planar_run(run_dir, complete=complete), target)
    if kind == "markers":
        return cam.write_markers_recording(ff.read_markers_run(run_dir, complete=complete), target)
    if kind == "dataset":
        return cam.write_dataset_recording(run_dir, target)
    raise ValueError(f"no recording of a {kind!r} folder")
