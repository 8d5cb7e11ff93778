"""Issue 27: ``quadnav slam --rerun`` on 3 s of a built-in stereo sequence: the SLAM's image
carries the keypoints it tracked on its map (ids: map points), read back with rerun's reader."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.experiments.odometry_run import resolve_dataset
from quadnav.io.odometry_run_files import read_viz_capture

pytest.importorskip("rerun")

from tests.viz.rrd import rows_and_static

runner = CliRunner()


@pytest.fixture(scope="module")
def slam_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``quadnav slam DATASET --rerun`` over 3 s of room_easy through EuRoC's stereo rig."""
    cache = tmp_path_factory.mktemp("slam_cache")
    made = resolve_dataset("room_easy", seed=0, rig="euroc", duration_s=3.0, cache_root=cache)
    out = tmp_path_factory.mktemp("runs")
    result = runner.invoke(app, ["slam", str(made.root), "--rerun", "--out", str(out)])
    assert result.exit_code == 0, result.output
    (folder,) = [p for p in out.iterdir() if p.is_dir()]
    return folder


def test_slam_rerun_draws_the_keypoints_tracked_on_its_map(slam_run: Path) -> None:
    rows, _ = rows_and_static(slam_run / "recording.rrd")
    cap = read_viz_capture(slam_run / "viz.npz")
    n_frames = json.loads((slam_run / "timing.json").read_text())["frames"]
    assert rows["/camera/image"] == len(cap.image_t_ns) == -(-n_frames // cap.image_every)
    with_points = np.unique(cap.feature_image)
    assert len(with_points) >= 0.8 * len(cap.image_t_ns)  # tracked from the first frames on
    assert rows["/camera/image/features"] == len(with_points)
    assert (cap.feature_ids >= 0).all()  # each one a map point's
    per_image = np.bincount(cap.feature_image)
    assert np.median(per_image[with_points]) > 50
    uv, (w, h) = cap.feature_uv, (cap.width, cap.height)
    assert ((uv >= 0) & (uv <= [w, h])).all()  # in the (downsampled) image, through the lens
    assert cap.feature_length.max() > 10  # map points tracked over many frames
