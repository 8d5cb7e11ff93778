"""The files of ``quadnav sim``, ``quadnav replay`` and ``quadnav markers`` run folders, and of a
dataset ``quadnav dataset make`` wrote, read back for whatever shows them again (``quadnav
view``, ``--rerun``): each kind recognised by its files, and read into a typed record.

A folder that is not one of these, or not complete (unless the run that writes it reads it:
``complete=False``), is a one-line :class:`IoError` naming it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from quadnav.errors import IoError
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.nav_run_files import CsvColumns, read_csv_columns, timed_events
from quadnav.io.run_folder import checked_run_folder, read_json
from quadnav.io.trajectory_io import read_tum

__all__ = [
    "FOLDER_FILES",
    "MarkersRunFiles",
    "PlanarRunFiles",
    "ReplayRunFiles",
    "SimRunFiles",
    "folder_kind_of",
    "read_markers_run",
    "read_planar_run",
    "read_replay_run",
    "read_sim_run",
]

#: The files that make a folder of each kind (with ``metrics.json``'s ``kind`` where it has one).
FOLDER_FILES = {
    "sim": ("metrics.json", "states.csv", "controls.csv", "trajectory.tum"),
    "replay": ("metrics.json", "quadnav.tum"),
    "markers": ("metrics.json", "stats.json", "poses.csv", "config.yaml"),
    "planar": ("metrics.json", "handled/truth.tum", "handled/output.tum", "handled/delayed.tum"),
    "dataset": ("dataset.json", "groundtruth.tum", "mav0"),
}
#: ``poses.csv``'s columns of text (the ids seen, the reason a frame has no pose).
POSE_TEXT_COLUMNS = ("ids", "reason")


@dataclass(frozen=True, slots=True, kw_only=True)
class SimRunFiles:
    """A ``quadnav sim`` folder: the flown trajectory, the states (with the reference) and the
    controller's commands, the events."""

    run_dir: Path
    trajectory: Trajectory
    states: CsvColumns
    controls: CsvColumns
    events: tuple[tuple[int, str], ...]


@dataclass(frozen=True, slots=True, kw_only=True)
class ReplayRunFiles:
    """A ``quadnav replay`` folder: quadnav's estimate, PX4's and the truth where the log has
    them, PX4's GNSS checks per fix, the notes and events."""

    run_dir: Path
    trajectories: dict[str, Trajectory]  # quadnav, px4, truth (those written)
    gnss_checks: CsvColumns | None
    events: tuple[tuple[int, str], ...]


@dataclass(frozen=True, slots=True, kw_only=True)
class MarkersRunFiles:
    """A ``quadnav markers`` folder: the pose of each frame (NaN without one), its statistics,
    the configuration file and the drawn frames (``images/``, else ``overlay.mp4``; None when
    the run wrote neither)."""

    run_dir: Path
    poses: CsvColumns  # numeric columns; ``ids`` and ``reason`` in ``poses.text``
    stats: dict[str, object]
    config: Path
    frames: Path | None


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanarRunFiles:
    """A ``quadnav run planar`` folder: per variant (``handled``, ``naive``, ``no_update``) the
    truth, delayed and output trajectories (in the x-z plane), the GPS fixes and the
    innovations; the notes of ``metrics.json``."""

    run_dir: Path
    trajectories: dict[str, dict[str, Trajectory]]  # variant -> truth, delayed, output
    gps: dict[str, CsvColumns]
    innovations: dict[str, CsvColumns]
    events: tuple[tuple[int, str], ...]


def _has(run_dir: Path, kind: str) -> bool:
    return all((run_dir / name).exists() for name in FOLDER_FILES[kind])


def folder_kind_of(run_dir: Path) -> str | None:
    """``sim``, ``replay``, ``markers``, ``planar`` or ``dataset`` when ``run_dir`` holds that
    kind's files."""
    run_dir = Path(run_dir)
    if _has(run_dir, "dataset"):
        return "dataset"
    if not (run_dir / "metrics.json").is_file():
        return None
    try:
        metrics = read_json(run_dir / "metrics.json")
    except IoError:
        return None
    kind = metrics.get("kind")
    if kind in ("sim", "markers", "planar") and _has(run_dir, str(kind)):
        return str(kind)
    if "quadnav_vs_px4" in metrics and _has(run_dir, "replay"):
        return "replay"
    return None


def _checked(run_dir: Path, kind: str, command: str, *, complete: bool) -> Path:
    return checked_run_folder(
        run_dir,
        command,
        FOLDER_FILES[kind],
        lambda d: folder_kind_of(d) == kind,
        complete=complete,
    )


def _events(run_dir: Path) -> tuple[tuple[int, str], ...]:
    """The events (``"12.345 s: what"``) and notes (at the start) of ``metrics.json``."""
    metrics = read_json(run_dir / "metrics.json")
    events, notes = metrics.get("events"), metrics.get("notes")
    lines = [str(x) for x in events] if isinstance(events, list) else []
    said = [(0, str(n)) for n in notes] if isinstance(notes, list) else []
    for key, value in events.items() if isinstance(events, dict) else ():
        times = value if isinstance(value, list) else [value]
        if key.endswith("_at_s") and all(isinstance(t, int | float) for t in times):
            what = key.removesuffix("_at_s").replace("_", " ")
            lines += [f"{t} s: {what}" + (f" {k + 1}" if len(times) > 1 else "")
                      for k, t in enumerate(times)]  # fmt: skip
        else:
            said.append((0, f"{key}: {value}"))
    return tuple(sorted([*said, *timed_events(lines)]))


def read_sim_run(run_dir: Path, *, complete: bool = True) -> SimRunFiles:
    """The series of a complete ``quadnav sim`` folder."""
    run_dir = _checked(run_dir, "sim", "quadnav sim", complete=complete)
    return SimRunFiles(
        run_dir=run_dir,
        trajectory=read_tum(run_dir / "trajectory.tum"),
        states=read_csv_columns(run_dir / "states.csv"),
        controls=read_csv_columns(run_dir / "controls.csv"),
        events=_events(run_dir),
    )


def read_replay_run(run_dir: Path, *, complete: bool = True) -> ReplayRunFiles:
    """The series of a complete ``quadnav replay`` folder."""
    run_dir = _checked(run_dir, "replay", "quadnav replay", complete=complete)
    trajectories = {
        name: read_tum(run_dir / f"{name}.tum")
        for name in ("quadnav", "px4", "truth")
        if (run_dir / f"{name}.tum").is_file()
    }
    gnss = run_dir / "gnss_checks.csv"
    return ReplayRunFiles(
        run_dir=run_dir,
        trajectories=trajectories,
        gnss_checks=read_csv_columns(gnss) if gnss.is_file() else None,
        events=_events(run_dir),
    )


def read_markers_run(run_dir: Path, *, complete: bool = True) -> MarkersRunFiles:
    """The poses and statistics of a complete ``quadnav markers`` folder."""
    run_dir = _checked(run_dir, "markers", "quadnav markers", complete=complete)
    images, video = run_dir / "images", run_dir / "overlay.mp4"
    frames = images if any(images.glob("frame_*.png")) else video if video.is_file() else None
    return MarkersRunFiles(
        run_dir=run_dir,
        poses=read_csv_columns(run_dir / "poses.csv", text=POSE_TEXT_COLUMNS),
        stats=read_json(run_dir / "stats.json"),
        config=run_dir / "config.yaml",
        frames=frames,
    )


def read_planar_run(run_dir: Path, *, complete: bool = True) -> PlanarRunFiles:
    """The series of a complete ``quadnav run planar`` folder (each variant it wrote)."""
    run_dir = _checked(run_dir, "planar", "quadnav run planar", complete=complete)
    variants = sorted(d.name for d in run_dir.iterdir() if (d / "truth.tum").is_file())
    trajectories, gps, innovations = {}, {}, {}
    for v in variants:
        d = run_dir / v
        trajectories[v] = {
            name: read_tum(d / f"{name}.tum")
            for name in ("truth", "delayed", "output")
            if (d / f"{name}.tum").is_file()
        }
        if (d / "gps.csv").is_file():
            gps[v] = read_csv_columns(d / "gps.csv")
        if (d / "innovations.csv").is_file():
            innovations[v] = read_csv_columns(d / "innovations.csv")
    return PlanarRunFiles(
        run_dir=run_dir,
        trajectories=trajectories,
        gps=gps,
        innovations=innovations,
        events=_events(run_dir),
    )
