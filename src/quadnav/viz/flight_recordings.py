"""The recordings of a ``quadnav sim`` flight and of a ``quadnav replay`` of a PX4 log, built
from their folders' files (:mod:`quadnav.io.folder_files`), as a navigation run's is.

A simulated flight: the flown trajectory whole and as it goes, the vehicle's pose and body axes,
the setpoint, the controller's thrust, torques and rotor speeds and the velocity as time series,
the events. A replay: quadnav's estimate, PX4's and the truth (where the log has them), the
vehicle on quadnav's estimate, PX4's GNSS checks per fix as time series, the notes and events.
A planar study (``quadnav run planar``): the truth, and each variant's delayed and output
estimates (``handled``, ``naive``, ``no_update``) in the x-z plane, its GPS fixes, its
innovations and test ratios. A blueprint for each. Every stream keeps every n-th row, at most a
few thousand.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from quadnav.io.folder_files import PlanarRunFiles, ReplayRunFiles, SimRunFiles
from quadnav.viz.nav_recording import MAX_POINTS, MAX_SCALARS
from quadnav.viz.recording import (
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
)

__all__ = [
    "GNSS_SERIES",
    "PLANAR_COLOURS",
    "write_planar_recording",
    "write_replay_recording",
    "write_sim_recording",
]

#: The columns of ``gnss_checks.csv`` drawn as time series.
GNSS_SERIES = ("eph", "epv", "pdop", "satellites", "used")
_COLOURS = {"flown": (30, 100, 230), "quadnav": (30, 100, 230), "px4": (230, 120, 20),
            "truth": (40, 160, 40), "setpoint": (200, 0, 200)}  # fmt: skip
_CONTROLS = {"thrust": ("thrust_n",), "torques": ("tau_phi", "tau_theta", "tau_psi"),
             "rotors": tuple(f"rotor{k}_rad_s" for k in range(1, 5))}  # fmt: skip


def _setpoints(log: RecordingLog, t_ns: NDArray[np.int64], ref: NDArray[np.float64]) -> None:
    import rerun as rr

    keep = decimation(len(t_ns), MAX_POINTS)
    points = rr.Points3D.columns(
        positions=ref[keep], colors=[_COLOURS["setpoint"]] * len(keep), radii=[0.03] * len(keep)
    )
    log.columns("world/setpoint", t_ns[keep], points, every_of(keep))


def write_sim_recording(files: SimRunFiles, path: Path) -> RecordingInfo:
    """Write the recording of a ``quadnav sim`` flight to ``path`` (an ``.rrd``)."""
    traj, states, controls = files.trajectory, files.states, files.controls
    series = [(name, f"/controls/{name}") for name in _CONTROLS] + [("velocity", "/velocity")]
    blueprint = flight_blueprint("simulated flight", traj.p_W_B, series)
    with open_recording(path, files.run_dir.name, blueprint) as log:
        log_trajectory(log, "flown", traj.t_ns, traj.p_W_B, MAX_POINTS, _COLOURS["flown"])
        log_vehicle(log, traj.t_ns, traj.p_W_B, traj.q_W_B_xyzw, MAX_POINTS)
        _setpoints(log, states.t_ns, states.columns(("ref_x_m", "ref_y_m", "ref_z_m")))
        for group, names in _CONTROLS.items():
            for name in names:
                values = controls.column(name)
                if np.isfinite(values).any():  # (no rotor speeds from a torque-level model)
                    log_scalars(log, f"controls/{group}/{name}", controls.t_ns, values, MAX_SCALARS)
        for axis in "xyz":
            values = states.column(f"v{axis}_m_s")
            log_scalars(log, f"velocity/{axis}", states.t_ns, values, MAX_SCALARS)
        log_events(log, files.events, level="INFO")
    return finish_info(log, path)


def write_replay_recording(files: ReplayRunFiles, path: Path) -> RecordingInfo:
    """Write the recording of a ``quadnav replay`` to ``path`` (an ``.rrd``)."""
    est = files.trajectories["quadnav"]
    series = [("GNSS checks", "/gnss")] if files.gnss_checks is not None else []
    blueprint = flight_blueprint("replay", est.p_W_B, series)
    with open_recording(path, files.run_dir.name, blueprint) as log:
        for name, traj in files.trajectories.items():
            log_trajectory(log, name, traj.t_ns, traj.p_W_B, MAX_POINTS, _COLOURS[name])
        log_vehicle(log, est.t_ns, est.p_W_B, est.q_W_B_xyzw, MAX_POINTS)
        gnss = files.gnss_checks
        for name in GNSS_SERIES if gnss is not None else ():
            assert gnss is not None
            if name in gnss.names:
                log_scalars(log, f"gnss/{name}", gnss.t_ns, gnss.column(name), MAX_SCALARS)
        log_events(log, files.events, level="INFO")
    return finish_info(log, path)


#: Each planar variant's delayed and output colours.
PLANAR_COLOURS = {
    "handled": ((230, 120, 20), (30, 100, 230)),
    "naive": ((220, 40, 40), (150, 60, 200)),
    "no_update": ((140, 140, 140), (90, 90, 90)),
}


def _planar_fixes(log: RecordingLog, variant: str, gps: NDArray[np.float64] | None) -> None:
    import rerun as rr

    if gps is None or not len(gps):
        return
    t_ns, xz = gps[:, 0].astype(np.int64), gps[:, 1:]
    keep = decimation(len(t_ns), MAX_POINTS)
    p = np.column_stack([xz[keep, 0], np.zeros(len(keep)), xz[keep, 1]])
    points = rr.Points3D.columns(positions=p, colors=[(240, 200, 0)] * len(keep),
                                 radii=[0.02] * len(keep))  # fmt: skip
    log.columns(f"world/{variant}/gps", t_ns[keep], points, every_of(keep))


def write_planar_recording(files: PlanarRunFiles, path: Path) -> RecordingInfo:
    """Write the recording of a ``quadnav run planar`` study to ``path`` (an ``.rrd``)."""
    first = next(iter(files.trajectories.values()))
    truth = first["truth"]
    series = [("test ratios", "/test_ratio"), ("innovations", "/innovations")]
    blueprint = flight_blueprint("planar study (x-z plane)", truth.p_W_B, series)
    with open_recording(path, files.run_dir.name, blueprint) as log:
        log_trajectory(log, "truth", truth.t_ns, truth.p_W_B, MAX_POINTS, _COLOURS["truth"])
        for variant, trajs in files.trajectories.items():
            colours = PLANAR_COLOURS.get(variant, ((200, 200, 200), (120, 120, 120)))
            for name, colour in zip(("delayed", "output"), colours, strict=True):
                if name in trajs:
                    traj = trajs[name]
                    log_trajectory(log, name, traj.t_ns, traj.p_W_B, MAX_POINTS, colour,
                                   root=f"world/{variant}")  # fmt: skip
            gps = files.gps.get(variant)
            _planar_fixes(
                log, variant, None if gps is None else
                np.column_stack([gps.t_ns, gps.columns(("x_m", "z_m"))]),
            )  # fmt: skip
            inn = files.innovations.get(variant)
            if inn is not None:
                ratio = inn.column("test_ratio")
                log_scalars(log, f"test_ratio/{variant}", inn.t_ns, ratio, MAX_SCALARS)
                for axis in ("x", "z"):
                    values = inn.column(f"innov_{axis}_m")
                    log_scalars(log, f"innovations/{variant}/{axis}", inn.t_ns, values, MAX_SCALARS)
        log_events(log, files.events, level="INFO")
    return finish_info(log, path)
