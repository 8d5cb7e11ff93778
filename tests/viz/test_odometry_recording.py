"""Issue 27, second part: a VIO run's rerun recording (``quadnav vio --rerun``, ``quadnav view``),
read back with rerun's own reader (``rerun.chunk.RrdReader``): the entities written and their
rows against the folder's files and ``viz.npz``, the bounds, loops, and the one-line errors."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.experiments.odometry_run import resolve_dataset
from quadnav.io.odometry_run_files import read_odometry_run, read_viz_capture
from quadnav.io.trajectory_io import read_tum

pytest.importorskip("rerun")
from rerun.chunk import RrdReader

from tests.viz.rrd import rows_and_static as _rows

runner = CliRunner()
SECONDS = 3.0


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 s of the room, made as ``quadnav vio room_easy`` makes a built-in sequence."""
    root = tmp_path_factory.mktemp("vio_cache")
    return resolve_dataset("room_easy", seed=0, duration_s=SECONDS, cache_root=root).root


@pytest.fixture(scope="module")
def run_dir(made: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``quadnav vio DATASET --rerun``'s folder."""
    out = tmp_path_factory.mktemp("runs")
    result = runner.invoke(app, ["vio", str(made), "--no-video", "--rerun", "--out", str(out)])
    assert result.exit_code == 0, result.output
    (folder,) = [p for p in out.iterdir() if p.is_dir()]
    return folder


def test_vio_rerun_records_the_run_and_what_its_camera_showed(run_dir: Path) -> None:
    rows, static = _rows(run_dir / "recording.rrd")
    est, kf = read_tum(run_dir / "estimate.tum"), read_tum(run_dir / "keyframes.tum")
    cap = read_viz_capture(run_dir / "viz.npz")
    n_frames = json.loads((run_dir / "timing.json").read_text())["frames"]
    assert 40 <= len(est) <= n_frames and len(kf) >= 3
    assert rows["/world/estimate"] == rows["/world/vehicle"] == len(est)
    assert rows["/world/truth"] > len(est)  # the ground truth at its own rate, every n-th
    assert rows["/world/keyframes"] == len(kf)
    # every frame counted, every n-th image kept (n from the bound), each with its features
    assert len(cap.frame_t_ns) == n_frames
    assert rows["/camera/image"] == len(cap.image_t_ns) == -(-n_frames // cap.image_every)
    assert (
        rows["/camera/image/features"]
        == len(np.unique(cap.feature_image))
        > 0.8 * len(cap.image_t_ns)
    )
    assert cap.width <= 320 and cap.image_scale >= 2  # EuRoC's 752 pixels, downsampled
    assert cap.image_bytes(0)[:2] == b"\xff\xd8"  # a JPEG
    assert cap.feature_uv.min() >= 0 and cap.feature_uv[:, 0].max() < cap.width + 1
    # the landmarks the keyframes saw: the map, growing by first sight
    assert len(cap.landmark_ids) > 50 and len(np.unique(cap.landmark_ids)) == len(cap.landmark_ids)
    assert rows["/world/map"] == len(np.unique(cap.landmark_t_ns))
    assert 0 < rows["/world/estimate/sigma"] <= 30
    assert rows["/series/tracked"] == rows["/series/sigma_m"] == len(cap.state_t_ns)
    assert len(est) <= len(cap.state_t_ns) <= n_frames
    events = [json.loads(line) for line in (run_dir / "events.jsonl").read_text().splitlines()]
    assert rows["/events"] == len(events) >= 1
    assert {"/world/vehicle", "/world/vehicle/camera", "/world/trajectories/estimate"} <= set(
        static
    )
    strip = static["/world/trajectories/estimate"].column("LineStrips3D:strips")[0].as_py()[0]
    np.testing.assert_allclose(np.array(strip), est.p_W_B, atol=1e-5)  # float32 in the file
    said = json.loads((run_dir / "recording.json").read_text())
    assert said["rows"] == {k: v for k, v in rows.items() if k in said["rows"]}
    assert said["every"]["/camera/image"] == cap.image_every
    assert said["size_bytes"] == (run_dir / "recording.rrd").stat().st_size
    assert RrdReader(run_dir / "recording.rrd").blueprints()


def test_the_timeline_starts_at_the_run(run_dir: Path) -> None:
    """Seconds from the run's first stamp, not since 1970."""
    for chunk in RrdReader(run_dir / "recording.rrd").stream():
        if chunk.entity_path == "/world/estimate" and not chunk.is_static:
            t = [s.total_seconds() for s in chunk.to_record_batch().column("t").to_pylist()]
    assert 0.0 <= t[0] < 2.0 and t[-1] <= SECONDS + 0.1


def test_view_of_a_folder_without_viz_npz_and_its_loops(run_dir: Path, tmp_path: Path) -> None:
    """``quadnav view`` builds what the files hold: no camera without ``viz.npz``; each accepted
    loop of ``loop.json`` an edge (rejected places none)."""
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    for name in ("viz.npz", "recording.rrd", "recording.json"):
        (copy / name).unlink()
    kf = read_tum(copy / "keyframes.tum")
    shutil.copy(copy / "keyframes.tum", copy / "keyframes_loop.tum")
    places = [
        {"stage": "accepted", "t_old_ns": int(kf.t_ns[0]), "t_new_ns": int(kf.t_ns[-1])},
        {"stage": "pnp", "t_old_ns": int(kf.t_ns[0]), "t_new_ns": int(kf.t_ns[-2])},
        {"stage": "accepted", "t_old_ns": int(kf.t_ns[1]), "t_new_ns": int(kf.t_ns[-2])},
    ]
    (copy / "loop.json").write_text(json.dumps({"places": places}))
    result = runner.invoke(app, ["view", str(copy)])
    assert result.exit_code == 0, result.output
    rows, _ = _rows(copy / "recording.rrd")
    assert not any(k.startswith(("/camera", "/series", "/world/map")) for k in rows)
    assert rows["/world/loops"] == 2
    assert rows["/world/keyframes"] == len(kf)
    edges = []
    for chunk in RrdReader(copy / "recording.rrd").stream():
        if chunk.entity_path == "/world/loops":
            edges += chunk.to_record_batch().column("LineStrips3D:strips").to_pylist()
    np.testing.assert_allclose(np.array(edges[0][0]), kf.p_W_B[[1, -2]], atol=1e-5)
    assert read_odometry_run(copy).loops == ((int(kf.t_ns[0]), int(kf.t_ns[-1])),
                                             (int(kf.t_ns[1]), int(kf.t_ns[-2])))  # fmt: skip


def test_a_long_run_keeps_at_most_the_bound_of_images(made: Path, tmp_path: Path) -> None:
    """The capture's bounds: every n-th image, n from the frames to come; downsampled."""
    from quadnav.experiments.odometry_run import OdometryRunOptions, run_odometry
    from quadnav.io.datasets import open_dataset
    from quadnav.io.run_folder import run_guard
    from quadnav.vio import VioConfig, VioEstimator
    from quadnav.viz.odometry_capture import OdometryCapture

    ds = open_dataset(made)
    capture = OdometryCapture(max_images=7, max_width=100)
    with run_guard():
        run = run_odometry(
            ds, ds.rig, lambda rig: VioEstimator(rig, VioConfig()), tmp_path,
            options=OdometryRunOptions(video=False), observer=capture,
        )  # fmt: skip
    cap = read_viz_capture(run.run_dir / "viz.npz")
    assert len(cap.image_t_ns) == 7 and cap.image_every == -(-run.timing.frames // 7)
    assert cap.width <= 100 and cap.image_scale == 8  # 752 pixels / 8 = 94
    np.testing.assert_array_equal(cap.image_t_ns, cap.frame_t_ns[:: cap.image_every])


def _without_rerun(monkeypatch: pytest.MonkeyPatch) -> None:
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "rerun" else real(name, *a)
    )


@pytest.mark.parametrize("command", ["vio", "slam"])
def test_rerun_without_the_extra_is_one_line_before_the_run(
    command: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _without_rerun(monkeypatch)
    out = tmp_path / "runs"
    result = runner.invoke(app, [command, "room_easy", "--rerun", "--out", str(out)])
    assert result.exit_code == 2
    assert result.stderr.strip() == "error: --rerun needs rerun: pip install 'quadnav[viz]'"
    assert not out.exists()
