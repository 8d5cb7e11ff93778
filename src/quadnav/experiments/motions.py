"""Where the motions of synthetic datasets come from: a trajectory file (TUM, EuRoC ground
truth...), a flight of ``quadnav sim`` or ``quadnav run``, or one of the real motion profiles
of EuRoC and TUM-VI sequences (a folder the user names). Each becomes a
:class:`~quadnav.sim.motion.SplineMotion`."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.errors import ExperimentError, SimError
from quadnav.experiments.flight import BUILTIN, FlightConfig, builtin_config, run_flight
from quadnav.experiments.nav import run_nav
from quadnav.experiments.scenarios import NAV_SCENARIOS, nav_builtin
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.config import load_config
from quadnav.io.trajectory_io import read_trajectory
from quadnav.sim.motion import SplineMotion
from quadnav.units import s_to_ns

__all__ = [
    "MAX_GAP_S",
    "REAL_MOTIONS",
    "SCENARIO_KNOT_SPACING_S",
    "MotionProfile",
    "bridge_gaps",
    "motion_from_file",
    "motion_from_profile",
    "motion_from_scenario",
    "motion_scenarios",
    "scenario_trajectory",
]

#: Knot spacing for the simulator's own truth, which is noise-free: finer than for real data.
SCENARIO_KNOT_SPACING_S = 0.05
#: The rate ``quadnav sim`` flights are logged at to fit their motion (their default is 100 Hz).
FLIGHT_LOG_RATE_HZ = 250.0


@dataclass(frozen=True, slots=True, kw_only=True)
class MotionProfile:
    """A real 6-DoF motion (ground truth of a real sequence, TUM format) in the motions folder."""

    name: str
    filename: str
    rate_hz: float
    length_m: float
    description: str


_PROFILES = (
    MotionProfile(
        name="euroc_MH_01_easy",
        filename="euroc_MH_01_easy.txt",
        rate_hz=200.0,
        length_m=80.6,
        description="EuRoC MAV Machine Hall 01 (easy), Vicon/Leica ground truth, 182 s",
    ),
    MotionProfile(
        name="euroc_V1_02_medium",
        filename="euroc_V1_02_medium.txt",
        rate_hz=200.0,
        length_m=75.9,
        description="EuRoC MAV Vicon Room 1 02 (medium): faster, more rotation, 84 s",
    ),
    MotionProfile(
        name="tumvi_corridor1",
        filename="tumvi_corridor1.txt",
        rate_hz=20.0,
        length_m=298.2,
        description="TUM-VI corridor1, hand-held through corridors, 299 s",
    ),
)
#: The real motion profiles by name (the files live in a folder the user gives).
REAL_MOTIONS: dict[str, MotionProfile] = {m.name: m for m in _PROFILES}


def _fit(traj: Trajectory, where: str, knot_spacing_s: float | None) -> SplineMotion:
    try:
        return SplineMotion.fit(traj, knot_spacing_s=knot_spacing_s)
    except SimError as exc:
        raise ExperimentError(f"{where}: {exc}") from None


#: The longest gap in a motion file's poses that is bridged by default (s): a hand-held
#: recording's tracking drop-outs (TUM-VI's corridors leave the motion-capture room).
MAX_GAP_S = 1.0


def bridge_gaps(traj: Trajectory, max_gap_s: float, where: str) -> tuple[Trajectory, int]:
    """``traj`` with every interval over twice its median pose period filled by poses at that
    period (positions linear, rotations slerped), and how many were filled; a gap over
    ``max_gap_s`` is an error naming ``--set max_gap_s``."""
    t = np.asarray(traj.t_ns, dtype=np.int64)
    if len(t) < 3:
        return traj, 0
    dt = np.diff(t)
    period = int(np.median(dt))
    gaps = np.flatnonzero(dt > 2 * period)
    if not gaps.size:
        return traj, 0
    worst = int(gaps[np.argmax(dt[gaps])])
    if dt[worst] > s_to_ns(max_gap_s):
        raise ExperimentError(
            f"{where}: no pose for {dt[worst] / 1e9:.2f} s after {(t[worst] - t[0]) / 1e9:.2f} s, "
            f"longer than max_gap_s = {max_gap_s:g} s that is bridged (--set max_gap_s=S)"
        )
    fill = [np.arange(t[k] + period, t[k + 1] - period // 2, period, dtype=np.int64) for k in gaps]
    t_all = np.union1d(t, np.concatenate(fill))
    bridged = traj.interpolate(t_all)
    return replace(bridged, name=traj.name), int(gaps.size)


def motion_from_file(
    path: Path,
    fmt: str | None = None,
    *,
    knot_spacing_s: float | None = None,
    max_gap_s: float = MAX_GAP_S,
) -> SplineMotion:
    """The smooth motion through a trajectory file's poses (format guessed when ``fmt`` is
    None: TUM, EuRoC ground truth, KITTI, quadnav CSV...), its gaps up to ``max_gap_s``
    bridged (:func:`bridge_gaps`)."""
    traj, _ = bridge_gaps(read_trajectory(Path(path), fmt), max_gap_s, str(path))
    return _fit(traj, str(path), knot_spacing_s)


def motion_from_profile(
    name: str, motions_dir: Path, *, knot_spacing_s: float | None = None
) -> SplineMotion:
    """One of :data:`REAL_MOTIONS`, read from ``motions_dir``."""
    if name not in REAL_MOTIONS:
        raise ExperimentError(f"no motion profile {name!r}; choose from {', '.join(REAL_MOTIONS)}")
    path = Path(motions_dir) / REAL_MOTIONS[name].filename
    if not path.is_file():
        raise ExperimentError(f"motion profile {name!r}: {path} not found")
    return motion_from_file(path, "tum", knot_spacing_s=knot_spacing_s)


def _nav_trajectory(name: str, seed: int, overrides: Sequence[str]) -> Trajectory:
    """A ``quadnav run`` scenario's truth: the body pose at every IMU step after alignment."""
    r = run_nav(nav_builtin(name, overrides), seed)
    return Trajectory(t_ns=r.t_ns, p_W_B=r.truth_p, q_W_B_xyzw=r.truth_q, name=name)


def _flight_trajectory(name: str, seed: int, overrides: Sequence[str]) -> Trajectory:
    """A ``quadnav sim`` flight's logged state, at :data:`FLIGHT_LOG_RATE_HZ` unless told."""
    sets = [f"seed={seed}", f"log_rate_hz={FLIGHT_LOG_RATE_HZ:g}", *overrides]
    run = run_flight(load_config(FlightConfig, None, sets, base=builtin_config(name)))
    t_ns = np.array([s_to_ns(t) for t in run.t_s], dtype=np.int64)
    q = Rotation.from_euler("ZYX", run.euler_rpy[:, ::-1]).as_quat()
    return Trajectory(t_ns=t_ns, p_W_B=run.p, q_W_B_xyzw=q, name=name)


def motion_scenarios() -> list[str]:
    """The names :func:`motion_from_scenario` knows: ``quadnav run``'s, then ``quadnav sim``'s."""
    return [*NAV_SCENARIOS, *BUILTIN]


def scenario_trajectory(name: str, seed: int, overrides: Sequence[str] = ()) -> Trajectory:
    """The true trajectory of a built-in flight of ``quadnav run`` or ``quadnav sim`` (with
    ``overrides`` of its configuration keys, ``key=value``)."""
    if name in NAV_SCENARIOS:
        return _nav_trajectory(name, seed, overrides)
    if name in BUILTIN:
        return _flight_trajectory(name, seed, overrides)
    raise ExperimentError(
        f"no scenario {name!r} to take a motion from; choose from {', '.join(motion_scenarios())}"
    )


def motion_from_scenario(
    name: str,
    seed: int,
    *,
    overrides: Sequence[str] = (),
    knot_spacing_s: float = SCENARIO_KNOT_SPACING_S,
) -> SplineMotion:
    """Fly a built-in scenario (``quadnav run``'s or ``quadnav sim``'s) with ``seed`` and fit
    the smooth motion through its truth."""
    traj = scenario_trajectory(name, seed, overrides)
    return _fit(traj, f"scenario {name!r}", knot_spacing_s)
