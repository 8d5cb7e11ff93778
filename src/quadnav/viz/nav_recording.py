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

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from quadnav.io.nav_run_files import NavRunFiles
from quadnav.viz.recording import (
    RECORDING_FILE,
    RecordingInfo,
    RecordingLog,
    decimation,
    every_of,
    finish_info,
    flight_blueprint,
    log_events,
    log_scalars,
    log_trajectory,
    log_vehicle,
    open_recording,
    require_rerun,
)

if TYPE_CHECKING:
    import rerun.blueprint as rrb

__all__ = [
    "MAX_ELLIPSOIDS",
    "MAX_POINTS",
    "MAX_SCALARS",
    "RECORDING_FILE",
    "RecordingInfo",
    "nav_blueprint",
    "require_rerun",
    "write_nav_recording",
]

#: Poses (points, transforms) kept per trajectory: every n-th, at most this many.
MAX_POINTS = 2000
#: Values kept per time series (an innovation's component, a test ratio).
MAX_SCALARS = 4000
#: Position ellipsoids of the delayed estimate kept.
MAX_ELLIPSOIDS = 200
#: Sigmas an ellipsoid's half-axes span.
ELLIPSOID_SIGMAS = 3.0

FloatArray = NDArray[np.float64]
_COLOURS = {"truth": (40, 160, 40), "output": (30, 100, 230), "delayed": (230, 120, 20)}


def _setpoints(log: RecordingLog, files: NavRunFiles, cap: int) -> None:
    pos = files.positions
    keep = decimation(len(pos.t_ns), cap)
    ref = pos.columns(("ref_x_m", "ref_y_m", "ref_z_m"))[keep]
    import rerun as rr

    points = rr.Points3D.columns(
        positions=ref, colors=[(200, 0, 200)] * len(keep), radii=[0.03] * len(keep)
    )
    log.columns("world/setpoint", pos.t_ns[keep], points, every_of(keep))


def _ellipsoids(log: RecordingLog, files: NavRunFiles, cap: int) -> None:
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
    log.columns("world/delayed/sigma", d.t_ns[keep], shapes, every_of(keep))


def _innovations(log: RecordingLog, files: NavRunFiles, cap: int) -> None:
    """Per source: its test ratio and each component of its innovation."""
    for source, table in files.innovations.items():
        log_scalars(log, f"test_ratio/{source}", table.t_ns, table.column("test_ratio"), cap)
        for name in table.names:
            if name.startswith("innovation_"):
                entity = f"innovations/{source}/{name.removeprefix('innovation_')}"
                log_scalars(log, entity, table.t_ns, table.column(name), cap)


def nav_blueprint(positions: FloatArray | None = None) -> rrb.Blueprint:
    """One 3-D view of the flight (looking at ``positions``) beside the test ratios, the
    innovations and the events; opened at the flight's end."""
    series = (("test ratios", "/test_ratio"), ("innovations", "/innovations"))
    return flight_blueprint("flight", positions, series)


def write_nav_recording(
    files: NavRunFiles,
    path: Path,
    *,
    max_points: int = MAX_POINTS,
    max_scalars: int = MAX_SCALARS,
    max_ellipsoids: int = MAX_ELLIPSOIDS,
) -> RecordingInfo:
    """Write the recording of a navigation run to ``path`` (an ``.rrd``), replaced whole."""
    blueprint = nav_blueprint(files.truth.p_W_B)
    with open_recording(path, files.run_dir.name, blueprint) as log:
        for name, traj in (("truth", files.truth), ("output", files.output)):
            log_trajectory(log, name, traj.t_ns, traj.p_W_B, max_points, _COLOURS[name])
        d = files.delayed
        p_delayed = d.columns(("x_m", "y_m", "z_m"))
        log_trajectory(log, "delayed", d.t_ns, p_delayed, max_points, _COLOURS["delayed"])
        out = files.output
        log_vehicle(log, out.t_ns, out.p_W_B, out.q_W_B_xyzw, max_points)
        _setpoints(log, files, max_points)
        _ellipsoids(log, files, max_ellipsoids)
        _innovations(log, files, max_scalars)
        log_events(log, files.events)
    return finish_info(log, path)
