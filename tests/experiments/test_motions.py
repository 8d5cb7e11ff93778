"""Motions for the dataset maker: from files, from the flights of ``quadnav run`` and
``quadnav sim``, and from the real motion profiles (issue 14, item 3)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quadnav.errors import ExperimentError, QuadnavError
from quadnav.experiments.motions import (
    REAL_MOTIONS,
    motion_from_file,
    motion_from_profile,
    motion_from_scenario,
)
from quadnav.io.trajectory_io import read_trajectory, write_trajectory
from tests.shared_data import SHARED, needs
from tests.sim.test_motion import synthetic_trajectory

MOTIONS = SHARED / "motions"
#: A short flight of a ``quadnav run`` scenario (a 0.5 m square at 0.5 m instead of 2 m at 1.5 m).
SHORT_RUN = ("plan.square_m=0.5", "plan.hold_s=0.2", "plan.height_m=0.5")


def test_a_run_scenarios_motion_agrees_with_its_own_truth() -> None:
    motion = motion_from_scenario("indoor_vision_pose", 3, overrides=SHORT_RUN)
    assert motion.poses is not None  # the truth of the run, every IMU step after alignment
    fit = motion.fit_to(motion.poses)
    assert fit.n_poses > 0.95 * len(motion.poses)
    assert fit.rms_position_m < 0.5e-3 and fit.max_position_m < 5e-3
    assert fit.rms_rotation_deg < 0.05
    # The worst is the touch-down, a ground impact (~90 m/s^2 for a few ms) no C2 motion
    # follows; in the air the spline is within a millimetre.
    t = motion.poses.t_ns
    airborne = (motion.poses.p_W_B[:, 2] > 0.02) & (t >= motion.t_start_ns) & (t <= motion.t_end_ns)
    p, _ = motion.pose(t[airborne])
    assert np.linalg.norm(p - motion.poses.p_W_B[airborne], axis=1).max() < 1e-3
    assert motion.poses.path_length_m() > 2.5  # it flew: climb, square, descent
    v = np.linalg.norm(motion.velocity(motion.poses.t_ns[100:-100]), axis=1)
    assert 0.3 < v.max() < 2.0  # the plan's 1 m/s


def test_a_sim_flights_motion_agrees_with_its_logged_state() -> None:
    motion = motion_from_scenario("circle", 1, overrides=("duration_s=2",))
    assert motion.poses is not None
    fit = motion.fit_to(motion.poses)
    assert fit.rms_position_m < 1e-4 and fit.rms_rotation_deg < 0.01
    assert np.median(np.diff(motion.poses.t_ns)) == 4_000_000  # logged at 250 Hz for the fit


def test_an_unknown_scenario_names_the_choices() -> None:
    with pytest.raises(ExperimentError, match=r"choose from indoor_vision, .*circle"):
        motion_from_scenario("no_such_flight", 0)


@pytest.mark.parametrize("fmt", ["tum", "euroc"])
def test_a_trajectory_file_becomes_a_motion_through_its_poses(tmp_path: Path, fmt: str) -> None:
    traj = synthetic_trajectory(rate_hz=200.0)
    path = tmp_path / ("gt.csv" if fmt == "euroc" else "gt.txt")
    write_trajectory(path, traj, fmt)
    motion = motion_from_file(path)  # the format guessed
    fit = motion.fit_to(read_trajectory(path, fmt))
    assert fit.rms_position_m < 1e-4 and fit.rms_rotation_deg < 0.01
    assert motion.t_start_ns > traj.t_ns[0] and motion.t_end_ns < traj.t_ns[-1]


def test_a_file_too_short_for_the_spline_is_an_error_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "short.txt"
    path.write_text("".join(f"{k * 0.01:.2f} 0 0 {k} 0 0 0 1\n" for k in range(4)))
    with pytest.raises(ExperimentError, match=r"short\.txt: motion: 4 poses .* knot_spacing_s"):
        motion_from_file(path)
    with pytest.raises(QuadnavError):
        motion_from_file(tmp_path / "absent.txt")


@needs(MOTIONS)
def test_the_real_profiles_are_the_files_they_claim() -> None:
    assert set(REAL_MOTIONS) == {"euroc_MH_01_easy", "euroc_V1_02_medium", "tumvi_corridor1"}
    for profile in REAL_MOTIONS.values():
        traj = read_trajectory(MOTIONS / profile.filename, "tum")
        assert profile.length_m == pytest.approx(traj.path_length_m(), rel=0.01)
        assert 1.0 / np.median(np.diff(traj.t_s)) == pytest.approx(profile.rate_hz, rel=0.01)
    motion = motion_from_profile("euroc_V1_02_medium", MOTIONS)
    assert motion.poses is not None and motion.fit_to(motion.poses).rms_position_m < 1e-3


def test_a_profile_is_read_from_the_folder_the_user_gives(tmp_path: Path) -> None:
    with pytest.raises(ExperimentError, match="choose from euroc_MH_01_easy"):
        motion_from_profile("euroc_MH_02", tmp_path)
    with pytest.raises(ExperimentError, match=r"tumvi_corridor1\.txt not found"):
        motion_from_profile("tumvi_corridor1", tmp_path)
