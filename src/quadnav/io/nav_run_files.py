"""A navigation run folder read back (``quadnav run``'s files): the first seed's trajectories,
the delayed horizon with its position variance, the setpoints, the innovations per source and
the filter's events, for whatever shows them again (``quadnav view``).

A folder that is not a complete ``quadnav run`` folder is a one-line :class:`IoError` naming it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import IoError
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.run_folder import checked_run_folder, read_json
from quadnav.io.trajectory_io import read_tum
from quadnav.units import s_to_ns

__all__ = [
    "CsvColumns",
    "NavRunFiles",
    "is_nav_run_folder",
    "read_csv_columns",
    "read_nav_run",
    "timed_events",
]

#: The files without which a folder is no ``quadnav run`` folder.
NAV_REQUIRED = ("metrics.json", "truth.tum", "output.tum", "delayed.csv", "positions.csv")


@dataclass(frozen=True, slots=True)
class CsvColumns:
    """A numeric CSV of a run folder: its header and its rows (N, len(names)); ``t_ns`` exact;
    the columns read as text (not in ``names``) by name."""

    names: tuple[str, ...]
    t_ns: NDArray[np.int64]
    values: NDArray[np.float64]
    text: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def column(self, name: str) -> NDArray[np.float64]:
        return self.values[:, self.names.index(name)]

    def columns(self, names: tuple[str, ...]) -> NDArray[np.float64]:
        return self.values[:, [self.names.index(n) for n in names]]


@dataclass(frozen=True, slots=True, kw_only=True)
class NavRunFiles:
    """The first seed's series of a ``quadnav run`` folder."""

    run_dir: Path
    truth: Trajectory
    output: Trajectory
    delayed: CsvColumns  # t_ns, x_m.. , qx.., var_x, var_y, var_z
    positions: CsvColumns  # truth, output and ref (setpoint) positions
    innovations: dict[str, CsvColumns]  # by source: nis, test_ratio, accepted, innovation_k
    events: tuple[tuple[int, str], ...]  # (t_ns, text): the filter's and the odometry's


def read_csv_columns(path: Path, *, text: tuple[str, ...] = ()) -> CsvColumns:
    """A CSV of numbers with a header whose first column is ``t_ns``; the columns ``text``
    (where the header has them) are kept as text."""
    try:
        with Path(path).open(encoding="utf-8") as f:
            names = tuple(f.readline().strip().split(","))
            rows = [line.strip().split(",") for line in f if line.strip()]
    except (OSError, UnicodeDecodeError) as exc:
        raise IoError(f"cannot read {path}: {exc}") from None
    if not names or names[0] != "t_ns" or any(len(r) != len(names) for r in rows):
        raise IoError(f"{path}: not a run folder's table (t_ns first, one value per column)")
    as_text = [k for k, n in enumerate(names) if n in text]
    numbers = [k for k in range(len(names)) if k not in as_text]
    try:
        t_ns = np.array([int(r[0]) for r in rows], dtype=np.int64)
        values = np.array([[r[k] for k in numbers] for r in rows], dtype=np.float64)
    except ValueError as exc:
        raise IoError(f"{path}: {exc}") from None
    return CsvColumns(
        names=tuple(names[k] for k in numbers), t_ns=t_ns,
        values=values.reshape(len(rows), len(numbers)),
        text={names[k]: tuple(r[k] for r in rows) for k in as_text},
    )  # fmt: skip


def is_nav_run_folder(run_dir: Path) -> bool:
    """True when ``run_dir`` holds a ``quadnav run`` folder's series."""
    run_dir = Path(run_dir)
    if not all((run_dir / name).is_file() for name in NAV_REQUIRED):
        return False
    try:
        return read_json(run_dir / "metrics.json").get("kind") == "nav"
    except IoError:
        return False


def timed_events(lines: list[str]) -> list[tuple[int, str]]:
    """Events written as ``"12.345 s: what"`` as ``(t_ns, what)``; one without a time at 0."""
    out: list[tuple[int, str]] = []
    for line in lines:
        stamp, sep, text = str(line).partition(" s: ")
        try:
            out.append((s_to_ns(float(stamp)), text) if sep else (0, str(line)))
        except ValueError:
            out.append((0, str(line)))
    return out


def _events(metrics: dict[str, object]) -> tuple[tuple[int, str], ...]:
    """The first seed's events, written as ``"12.345 s: what"``."""
    per_seed = metrics.get("per_seed")
    first = per_seed[0] if isinstance(per_seed, list) and per_seed else {}
    out: list[tuple[int, str]] = []
    for key in ("filter_events", "vio_events"):
        lines = first.get(key, []) if isinstance(first, dict) else []
        out += timed_events([str(x) for x in lines] if isinstance(lines, list) else [])
    return tuple(sorted(out))


def read_nav_run(run_dir: Path, *, complete: bool = True) -> NavRunFiles:
    """The series of a complete ``quadnav run`` folder (an error naming it otherwise);
    ``complete=False``: the run that writes it reads its series before it is marked complete."""
    run_dir = checked_run_folder(
        run_dir,
        "quadnav run",
        NAV_REQUIRED,
        is_nav_run_folder,
        complete=complete,
        not_kind="not a nav run's",
    )
    innovations = {
        p.stem.removeprefix("innovations_"): read_csv_columns(p)
        for p in sorted(run_dir.glob("innovations_*.csv"))
    }
    return NavRunFiles(
        run_dir=run_dir,
        truth=read_tum(run_dir / "truth.tum"),
        output=read_tum(run_dir / "output.tum"),
        delayed=read_csv_columns(run_dir / "delayed.csv"),
        positions=read_csv_columns(run_dir / "positions.csv"),
        innovations=innovations,
        events=_events(read_json(run_dir / "metrics.json")),
    )
