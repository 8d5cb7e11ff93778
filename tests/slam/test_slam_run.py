"""The stereo SLAM behind the odometry interface, driven by the runner the VIO uses (one runner
for any visual estimator): a rendered stereo sequence of the room through EuRoC's rig (its
lenses distorted, so the pair is rectified first) into a run folder, scored against the truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quadnav.errors import SlamError
from quadnav.experiments.odometry_run import OdometryRunOptions, run_odometry
from quadnav.messages import ImageFrame
from quadnav.rig import euroc, euroc_mono
from quadnav.slam.odometry import SlamOdometry
from tests.vio.rendered import rendered


@pytest.fixture(scope="module")
def stereo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple:
    ds = rendered(tmp_path_factory, "room_easy", duration_s=4.0, still_s=0.5, rig="euroc", seed=1)
    out = tmp_path_factory.mktemp("runs")
    made: list[SlamOdometry] = []

    def make(rig: object) -> SlamOdometry:
        made.append(SlamOdometry(rig))  # type: ignore[arg-type]
        return made[-1]

    run = run_odometry(ds, ds.rig, make, out, options=OdometryRunOptions(video=False),
                       name="room_easy", kind="slam")  # fmt: skip
    return run, made[0]


def test_the_stereo_slam_runs_through_the_common_runner(stereo_run: tuple) -> None:
    run, slam = stereo_run
    m = run.metrics
    assert (run.run_dir / "estimate.tum").exists() and (run.run_dir / "metrics.json").exists()
    assert "_slam_" in run.run_dir.name
    assert m.failures == 0 and m.fraction_with_estimate > 0.95, m
    assert not isinstance(m.ape_se3, str) and m.ape_se3.rmse_m < 0.01, m.ape_se3  # (3 mm here)
    assert [e.kind for e in slam.events] == ["initialized"]
    assert slam.rejected == {}  # (every left frame met its partner)
    assert len(slam.tracker.map.keyframes) >= 2


def test_frames_that_do_not_pair_are_counted_not_raised() -> None:
    slam = SlamOdometry(euroc())
    blank = np.zeros((480, 752), np.uint8)
    assert slam.push(ImageFrame(t_ns=1, camera="cam0", load=lambda: blank)) is None
    assert slam.push(ImageFrame(t_ns=2, camera="cam0", load=lambda: blank)) is None
    assert slam.push(ImageFrame(t_ns=3, camera="cam1", load=lambda: blank)) is None
    assert slam.push(ImageFrame(t_ns=3, camera="cam7", load=lambda: blank)) is None
    assert slam.rejected == {"unpaired_frames": 2, "other_camera": 1}
    # a pair of blank images: no texture, the SLAM waits (no state, no error)
    assert slam.push(ImageFrame(t_ns=4, camera="cam0", load=lambda: blank)) is None
    assert slam.push(ImageFrame(t_ns=4, camera="cam1", load=lambda: blank)) is None
    assert slam.tracker.state == "waiting"


def test_a_mono_rig_is_a_one_line_error(tmp_path: Path) -> None:
    with pytest.raises(SlamError, match="has one camera: the stereo SLAM needs two"):
        SlamOdometry(euroc_mono())
