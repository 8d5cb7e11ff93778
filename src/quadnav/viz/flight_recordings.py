"""The recordings of a ``quadnav sim`` flight and of a ``quadnav replay`` of a PX4 log, built
from their folders' files (:mod:`quadnav.io.folder_files`), as a navigation run's is.

A simulated flight: the flown trajectory whole and as it goes, the vehicle's pose and body axes,
the setpoint, the controller's thrust, torques and rotor speeds and the velocity as time series,
the events. A replay: quadnav's estimate, PX4's and the truth (where the log has them), the
vehicle on quadnav's estimate, PX4's GNSS checks per fix as time series, the notes and events.
A blueprint for each. Every stream keeps every n-th row, at most a few thousand.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from quadnav.io.folder_files import ReplayRunFiles, SimRunFiles
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

__all__ = ["GNSS_SERIES", "write_replay_recording", "write_sim_recording"]

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
