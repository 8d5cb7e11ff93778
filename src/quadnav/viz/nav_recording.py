"""The recording of a navigation run (``quadnav run``'s folder) for rerun's viewer, built from the
folder's files.

On the timeline ``t`` (seconds, the files' stamps): the truth, output and delayed trajectories
(each whole as a static line strip, and its current point), the vehicle's pose with its body axes
(the output predictor's), the setpoint, the delayed estimate's 3-sigma position ellipsoid, the
innovations and test ratios per source as time series, and the filter's events as a text log. A
blueprint lays out one 3-D view and the time series.

The size is bounded, whatever the flight's length: each stream keeps every n-th row, n chosen so
that at most ``MAX_POINTS`` poses (``MAX_SCALARS`` values of a time series, ``MAX_ELLIPSOIDS``
ellipsoids) remain.
"""

from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VizError
from quadnav.io.nav_run_files import NavRunFiles

if TYPE_CHECKING:
    import rerun as rr
    import rerun.blueprint as rrb

__all__ = [
    "MAX_ELLIPSOIDS",
    "MAX_POINTS",
    "MAX_SCALARS",
    "RECORDING_FILE",
    "RecordingInfo",
    "decimation",
    "require_rerun",
    "write_nav_recording",
]

#: The recording's name in a run folder.
RECORDING_FILE = "recording.rrd"
#: Poses (points, transforms) kept per trajectory: every n-th, at most this many.
MAX_POINTS = 2000
#: Values kept per time series (an innovation's component, a test ratio).
MAX_SCALARS = 4000
#: Position ellipsoids of the delayed estimate kept.
MAX_ELLIPSOIDS = 200
#: Sigmas an ellipsoid's half-axes span.
ELLIPSOID_SIGMAS = 3.0
#: The body axes' length drawn on the vehicle (m).
AXIS_LENGTH_M = 0.3

_COLOURS = {"truth": (40, 160, 40), "output": (30, 100, 230), "delayed": (230, 120, 20)}


@dataclass(frozen=True, slots=True, kw_only=True)
class RecordingInfo:
    """A recording written: its file, its size and the rows logged per entity over time (by
    rerun's entity path, ``/world/truth``)."""

    path: Path
    size_bytes: int
    rows: dict[str, int]


def require_rerun(option: str) -> None:
    """Refuse ``option`` (``--rerun``, ``quadnav view``) when rerun is not installed."""
    if importlib.util.find_spec("rerun") is None:
        raise VizError(f"{option} needs rerun: pip install 'quadnav[viz]'")


def decimation(n: int, cap: int) -> NDArray[np.intp]:
    """The indices of every k-th of ``n`` rows, k the smallest keeping at most ``cap``."""
    step = max(1, math.ceil(n / max(cap, 1)))
    return np.arange(0, n, step)


def _times(t_ns: NDArray[np.int64]) -> rr.TimeColumn:
    import rerun as rr

    return rr.TimeColumn("t", duration=np.asarray(t_ns, dtype=np.int64).astype("timedelta64[ns]"))


class _Log:
    """Columns sent to one recording, their rows counted per entity."""

    def __init__(self, rec: rr.RecordingStream) -> None:
        self.rec = rec
        self.rows: dict[str, int] = {}

    def columns(self, entity: str, t_ns: NDArray[np.int64], columns: object) -> None:
        import rerun as rr

        if len(t_ns) == 0:
            return
        rr.send_columns(entity, indexes=[_times(t_ns)], columns=columns, recording=self.rec)  # type: ignore[arg-type]
        self.rows[f"/{entity}"] = self.rows.get(f"/{entity}", 0) + len(t_ns)


def _trajectory(
    log: _Log, name: str, t_ns: NDArray[np.int64], p: NDArray[np.float64], cap: int
) -> None:
    import rerun as rr

    keep = decimation(len(t_ns), cap)
    colour = _COLOURS[name]
    strip = rr.LineStrips3D([p[keep]], colors=[colour], radii=[0.005])
    log.rec.log(f"world/trajectories/{name}", strip, static=True)
    points = rr.Points3D.columns(
        positions=p[keep], colors=[colour] * len(keep), radii=[0.02] * len(keep)
    )
    log.columns(f"world/{name}", t_ns[keep], points)


def _vehicle(log: _Log, files: NavRunFiles, cap: int) -> None:
    """The output predictor's pose, with the body's axes (x red, y green, z blue)."""
    import rerun as rr

    out = files.output
    keep = decimation(len(out.t_ns), cap)
    log.rec.log("world/vehicle", rr.TransformAxes3D(axis_length=AXIS_LENGTH_M), static=True)
    pose = rr.Transform3D.columns(translation=out.p_W_B[keep], quaternion=out.q_W_B_xyzw[keep])
    log.columns("world/vehicle", out.t_ns[keep], pose)


def _setpoints(log: _Log, files: NavRunFiles, cap: int) -> None:
    pos = files.positions
    keep = decimation(len(pos.t_ns), cap)
    ref = pos.columns(("ref_x_m", "ref_y_m", "ref_z_m"))[keep]
    import rerun as rr

    points = rr.Points3D.columns(
        positions=ref, colors=[(200, 0, 200)] * len(keep), radii=[0.03] * len(keep)
    )
    log.columns("world/setpoint", pos.t_ns[keep], points)


def _ellipsoids(log: _Log, files: NavRunFiles, cap: int) -> None:
    """The delayed estimate's position, ``ELLIPSOID_SIGMAS`` sigmas about it (axis-aligned:
    the run folder keeps the variances, not the whole covariance)."""
    import rerun as rr

    d = files.delayed
    keep = decimation(len(d.t_ns), cap)
    centres = d.columns(("x_m", "y_m", "z_m"))[keep]
    var = np.clip(d.columns(("var_x", "var_y", "var_z"))[keep], 0.0, None)
    half = ELLIPSOID_SIGMAS * np.sqrt(var)
    shapes = rr.Ellipsoids3D.columns(
        centers=centres, half_sizes=half, colors=[_COLOURS["delayed"]] * len(keep)
    )
    log.columns("world/delayed/sigma", d.t_ns[keep], shapes)


def _innovations(log: _Log, files: NavRunFiles, cap: int) -> None:
    """Per source: its test ratio and each component of its innovation."""
    import rerun as rr

    for source, table in files.innovations.items():
        keep = decimation(len(table.t_ns), cap)
        t = table.t_ns[keep]
        log.columns(
            f"test_ratio/{source}", t, rr.Scalars.columns(scalars=table.column("test_ratio")[keep])
        )
        for name in table.names:
            if name.startswith("innovation_"):
                values = rr.Scalars.columns(scalars=table.column(name)[keep])
                log.columns(f"innovations/{source}/{name.removeprefix('innovation_')}", t, values)


def _events(log: _Log, files: NavRunFiles) -> None:
    import rerun as rr

    for t_ns, text in files.events:
        log.rec.set_time("t", duration=np.timedelta64(t_ns, "ns"))
        log.rec.log("events", rr.TextLog(text, level="WARN"))
    log.rows["/events"] = len(files.events)


def nav_blueprint() -> rrb.Blueprint:
    """One 3-D view of the flight beside the test ratios, the innovations and the events."""
    import rerun.blueprint as rrb

    series = rrb.Vertical(
        rrb.TimeSeriesView(name="test ratios", origin="/test_ratio"),
        rrb.TimeSeriesView(name="innovations", origin="/innovations"),
        rrb.TextLogView(name="events", origin="/events"),
    )
    layout = rrb.Horizontal(
        rrb.Spatial3DView(name="flight", origin="/world"), series, column_shares=[3, 2]
    )
    return rrb.Blueprint(layout, collapse_panels=True)


def write_nav_recording(
    files: NavRunFiles,
    path: Path,
    *,
    max_points: int = MAX_POINTS,
    max_scalars: int = MAX_SCALARS,
    max_ellipsoids: int = MAX_ELLIPSOIDS,
) -> RecordingInfo:
    """Write the recording of a navigation run to ``path`` (an ``.rrd``), replaced whole."""
    import rerun as rr

    path = Path(path)
    partial = path.with_name(path.name + ".partial")
    rec = rr.RecordingStream("quadnav", recording_id=files.run_dir.name)
    rec.save(partial, default_blueprint=nav_blueprint())
    log = _Log(rec)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)  # ENU
    for name, traj in (("truth", files.truth), ("output", files.output)):
        _trajectory(log, name, traj.t_ns, traj.p_W_B, max_points)
    delayed = files.delayed
    _trajectory(log, "delayed", delayed.t_ns, delayed.columns(("x_m", "y_m", "z_m")), max_points)
    _vehicle(log, files, max_points)
    _setpoints(log, files, max_points)
    _ellipsoids(log, files, max_ellipsoids)
    _innovations(log, files, max_scalars)
    _events(log, files)
    rec.flush()
    rec.disconnect()
    partial.replace(path)
    return RecordingInfo(path=path, size_bytes=path.stat().st_size, rows=dict(log.rows))
