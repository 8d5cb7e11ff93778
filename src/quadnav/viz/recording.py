"""What every recording shares: the check that rerun is installed, the decimation that bounds a
stream, the timeline ``t`` (seconds, the files' stamps), columns sent and counted per entity,
trajectories as line strips and points, and the file written whole (``recording.rrd`` and
``recording.json``, which says what was kept of each stream: its rows and every how many)."""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VizError
from quadnav.io.run_folder import write_json

if TYPE_CHECKING:
    import rerun as rr
    import rerun.blueprint as rrb

__all__ = [
    "RECORDING_FILE",
    "RECORDING_JSON",
    "RecordingInfo",
    "RecordingLog",
    "decimation",
    "eye_on",
    "finish_info",
    "log_trajectory",
    "open_recording",
    "require_rerun",
    "time_column",
]

#: The recording's name in a run folder.
RECORDING_FILE = "recording.rrd"
#: Beside it: what was kept of each stream (rows, every how many), its size.
RECORDING_JSON = "recording.json"

RGB = tuple[int, int, int]


@dataclass(frozen=True, slots=True, kw_only=True)
class RecordingInfo:
    """A recording written: its file, its size, the rows logged per entity over time (by
    rerun's entity path, ``/world/truth``) and every how many of its source's rows each keeps."""

    path: Path
    size_bytes: int
    rows: dict[str, int]
    every: dict[str, int] = field(default_factory=dict)


def require_rerun(option: str) -> None:
    """Refuse ``option`` (``--rerun``, ``quadnav view``) when rerun is not installed."""
    if importlib.util.find_spec("rerun") is None:
        raise VizError(f"{option} needs rerun: pip install 'quadnav[viz]'")


def decimation(n: int, cap: int) -> NDArray[np.intp]:
    """The indices of every k-th of ``n`` rows, k the smallest keeping at most ``cap``."""
    step = max(1, math.ceil(n / max(cap, 1)))
    return np.arange(0, n, step)


def time_column(t_ns: NDArray[np.int64]) -> rr.TimeColumn:
    """Stamps (ns) as the timeline ``t``."""
    import rerun as rr

    return rr.TimeColumn("t", duration=np.asarray(t_ns, dtype=np.int64).astype("timedelta64[ns]"))


class RecordingLog:
    """Columns sent to one recording, their rows counted per entity (and every how many of its
    source's rows they keep); stamps on the timeline from ``t0_ns``."""

    def __init__(self, rec: rr.RecordingStream, t0_ns: int = 0) -> None:
        self.rec = rec
        self.t0_ns = t0_ns
        self.rows: dict[str, int] = {}
        self.every: dict[str, int] = {}

    def columns(
        self, entity: str, t_ns: NDArray[np.int64], columns: object, every: int = 1
    ) -> None:
        import rerun as rr

        if len(t_ns) == 0:
            return
        index = time_column(np.asarray(t_ns, np.int64) - self.t0_ns)
        rr.send_columns(entity, indexes=[index], columns=columns, recording=self.rec)  # type: ignore[arg-type]
        self.rows[f"/{entity}"] = self.rows.get(f"/{entity}", 0) + len(t_ns)
        self.every[f"/{entity}"] = every

    def at(self, t_ns: int) -> None:
        """The time of what is logged next with ``rec.log``."""
        self.rec.set_time("t", duration=np.timedelta64(int(t_ns) - self.t0_ns, "ns"))


def log_trajectory(
    log: RecordingLog,
    name: str,
    t_ns: NDArray[np.int64],
    p: NDArray[np.float64],
    cap: int,
    colour: RGB,
    *,
    root: str = "world",
) -> None:
    """A trajectory whole as a static line strip (``ROOT/trajectories/NAME``) and its current
    point over time (``ROOT/NAME``), every k-th pose, at most ``cap``."""
    import rerun as rr

    keep = decimation(len(t_ns), cap)
    if len(keep) == 0:
        return
    strip = rr.LineStrips3D([p[keep]], colors=[colour], radii=[0.005])
    log.rec.log(f"{root}/trajectories/{name}", strip, static=True)
    points = rr.Points3D.columns(
        positions=p[keep], colors=[colour] * len(keep), radii=[0.02] * len(keep)
    )
    every = int(keep[1] - keep[0]) if len(keep) > 1 else 1
    log.columns(f"{root}/{name}", t_ns[keep], points, every)


def eye_on(p: NDArray[np.float64]) -> rrb.EyeControls3D | None:
    """Looking down on the positions ``p`` from behind their start, all of them in view."""
    import rerun.blueprint as rrb

    if len(p) == 0 or not np.isfinite(p).all():
        return None
    lo, hi = p.min(axis=0), p.max(axis=0)
    centre, size = (lo + hi) / 2, max(float(np.max(hi - lo)), 1.0)
    return rrb.EyeControls3D(
        position=centre + size * np.array([-0.9, -1.4, 1.2]), look_target=centre,
        eye_up=[0.0, 0.0, 1.0],
    )  # fmt: skip


@contextmanager
def open_recording(
    path: Path, recording_id: str, blueprint: rrb.Blueprint, *, t0_ns: int = 0
) -> Iterator[RecordingLog]:
    """A recording to ``path`` (an ``.rrd``, replaced whole when the block ends without an
    error), its world ENU, z up, its timeline from ``t0_ns``."""
    import rerun as rr

    path = Path(path)
    partial = path.with_name(path.name + ".partial")
    rec = rr.RecordingStream("quadnav", recording_id=recording_id)
    rec.save(partial, default_blueprint=blueprint)
    log = RecordingLog(rec, t0_ns)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    try:
        yield log
    finally:
        rec.flush()
        rec.disconnect()
    partial.replace(path)


def finish_info(log: RecordingLog, path: Path) -> RecordingInfo:
    """The recording written, said in ``recording.json`` beside it."""
    path = Path(path)
    info = RecordingInfo(
        path=path, size_bytes=path.stat().st_size, rows=dict(log.rows), every=dict(log.every)
    )
    write_json(
        path.with_name(RECORDING_JSON)
        if path.name == RECORDING_FILE
        else path.with_suffix(".json"),
        {"file": path.name, "size_bytes": info.size_bytes, "rows": info.rows, "every": info.every},
    )
    return info
