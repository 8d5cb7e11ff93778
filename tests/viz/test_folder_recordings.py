"""Issue 27, part 3: ``--rerun`` on ``quadnav sim``, ``markers``, ``replay`` and ``dataset
make``, and ``quadnav view`` of their folders: each recording read back with rerun's own reader
(``rerun.chunk.RrdReader``), its entities and rows against the folder's files."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app
from tests.shared_data import PX4_SITL, needs

pytest.importorskip("rerun")
from rerun.chunk import RrdReader

from tests.viz.rrd import rows_and_static

runner = CliRunner()


def _lines(path: Path, header: int = 0) -> int:
    return sum(1 for x in path.read_text().splitlines()[header:] if x.strip() and x[0] != "#")


def _made(out: Path, args: list[str]) -> Path:
    result = runner.invoke(app, [*args, "--out", str(out)])
    assert result.exit_code == 0, result.output
    (folder,) = [p for p in out.iterdir() if p.is_dir()]
    assert f"{folder / 'recording.rrd'} (" in result.stdout.replace("\n", "")
    return folder


def _viewed(folder: Path, tmp_path: Path) -> dict[str, int]:
    """The rows of ``quadnav view``'s recording of a copy of ``folder`` without its own."""
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    (copy / "recording.rrd").unlink()
    result = runner.invoke(app, ["view", str(copy)])
    assert result.exit_code == 0, result.output
    return rows_and_static(copy / "recording.rrd")[0]


def test_sim_rerun_records_the_flight_its_setpoints_and_controls(tmp_path: Path) -> None:
    args = ["sim", "thesis002_pd_stabilization", "--set", "duration_s=2", "--rerun"]
    folder = _made(tmp_path / "runs", args)
    rows, static = rows_and_static(folder / "recording.rrd")
    n = _lines(folder / "trajectory.tum")
    assert n == _lines(folder / "states.csv", 1) == 201
    assert rows["/world/flown"] == rows["/world/vehicle"] == rows["/world/setpoint"] == n
    for name in ("thrust/thrust_n", "torques/tau_phi", "torques/tau_theta", "torques/tau_psi"):
        assert rows[f"/controls/{name}"] == _lines(folder / "controls.csv", 1)
    assert not any(e.startswith("/controls/rotors") for e in rows)  # NaN in this model
    assert [rows[f"/velocity/{a}"] for a in "xyz"] == [n] * 3
    assert {"/world/trajectories/flown", "/world/vehicle"} <= set(static)
    strip = static["/world/trajectories/flown"].column("LineStrips3D:strips")[0].as_py()[0]
    first = [float(v) for v in (folder / "trajectory.tum").read_text().split()[1:4]]
    np.testing.assert_allclose(strip[0], first, atol=1e-6)
    assert RrdReader(folder / "recording.rrd").blueprints()
    info = json.loads((folder / "recording.json").read_text())
    assert info["rows"]["/world/flown"] == n and info["every"]["/world/flown"] == 1
    assert _viewed(folder, tmp_path) == rows  # quadnav view of the folder: the same recording


@pytest.fixture(scope="module")
def markers_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Six renders of marker 5 through ``quadnav markers --rerun``, the drawn frames kept."""
    import cv2

    from quadnav.geometry.camera import thesis_camera
    from quadnav.io.opencv_yaml import write_camera_yaml
    from tests.cli.conftest import marker_views

    root = tmp_path_factory.mktemp("markers")
    cam = thesis_camera()
    (root / "frames").mkdir()
    for k, img in enumerate(marker_views(cam, 6)[0]):
        cv2.imwrite(str(root / "frames" / f"f{k:03d}.png"), img)
    (root / "frames" / "f003.png").write_bytes(np.zeros((10, 10), np.uint8).tobytes())
    write_camera_yaml(root / "cal.yml", cam)
    args = ["markers", str(root / "frames"), "--camera", str(root / "cal.yml"), "--set",
            "fps=10", "--set", "write_images=true", "--rerun"]  # fmt: skip
    return _made(root / "out", args)


def test_markers_rerun_records_poses_target_camera_and_drawn_frames(markers_run: Path) -> None:
    rows, static = rows_and_static(markers_run / "recording.rrd")
    poses = (markers_run / "poses.csv").read_text().splitlines()
    header, body = poses[0].split(","), [x.split(",") for x in poses[1:]]
    with_pose = sum(r[header.index("x_m")] != "nan" for r in body)
    assert 0 < with_pose == rows["/world/markers"] == rows["/world/vehicle"]
    assert rows["/camera/image"] == len(list((markers_run / "images").glob("frame_*.png")))
    assert [rows[f"/series/{s}"] for s in ("n_markers", "rms_px", "detect_ms", "pose_ms")] == [
        len(body)
    ] * 4
    targets = static["/world/targets"]
    assert targets.column("LineStrips3D:strips")[0].as_py()[0][0] == pytest.approx(
        [-0.2335 / 2, -0.2335 / 2, 0.0]
    )  # marker 5's corner, 0.2335 m the side, the world at its centre
    assert targets.column("LineStrips3D:labels").to_pylist()[0] == ["marker 5"]
    resolution = static["/world/vehicle/camera"].column("Pinhole:resolution").to_pylist()[0]
    assert resolution[0][0] <= 320  # the frustum of the downsampled drawn frames


def test_markers_view_falls_back_to_the_video_then_to_no_image(
    markers_run: Path, tmp_path: Path
) -> None:
    copy = tmp_path / "run"
    shutil.copytree(markers_run, copy)
    shutil.rmtree(copy / "images")
    result = runner.invoke(app, ["view", str(copy)])
    assert result.exit_code == 0, result.output
    rows, _ = rows_and_static(copy / "recording.rrd")
    assert rows["/camera/image"] == _lines(copy / "poses.csv", 1)  # every frame of overlay.mp4
    (copy / "overlay.mp4").unlink()
    assert runner.invoke(app, ["view", str(copy)]).exit_code == 0
    rows, _ = rows_and_static(copy / "recording.rrd")
    assert "/camera/image" not in rows and rows["/world/vehicle"] > 0


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two seconds of the room through the one-camera EuRoC rig, made with --rerun."""
    out = tmp_path_factory.mktemp("dataset") / "room"
    args = ["dataset", "make", "room_easy", "--rig", "euroc_mono", "--duration", "2", "--rerun"]
    result = runner.invoke(app, [*args, "--out", str(out)])
    assert result.exit_code == 0, result.output
    return out


def test_dataset_make_rerun_records_truth_images_and_imu(dataset: Path) -> None:
    rows, static = rows_and_static(dataset / "recording.rrd")
    n_truth = _lines(dataset / "mav0" / "state_groundtruth_estimate0" / "data.csv")  # as read
    assert rows["/world/truth"] == rows["/world/vehicle"] == n_truth
    assert rows["/cameras/cam0"] == _lines(dataset / "mav0" / "cam0" / "data.csv") == 40
    n_imu = _lines(dataset / "mav0" / "imu0" / "data.csv")
    for axis in "xyz":
        assert rows[f"/imu/gyro/{axis}"] == rows[f"/imu/accel/{axis}"] == n_imu
    assert "/world/vehicle/cam0" in static  # the camera's frustum on the body
    stamps = []
    for chunk in RrdReader(dataset / "recording.rrd").stream():
        if chunk.entity_path == "/world/truth":
            stamps += chunk.to_record_batch().column("t").to_pylist()
    assert min(stamps).total_seconds() == 0.0 and max(stamps).total_seconds() < 2.1


@needs(PX4_SITL)
def test_replay_rerun_records_the_three_trajectories_and_gnss_checks(tmp_path: Path) -> None:
    folder = _made(tmp_path / "runs", ["replay", str(PX4_SITL), "--rerun"])
    rows, static = rows_and_static(folder / "recording.rrd")
    for name in ("quadnav", "px4", "truth"):
        assert rows[f"/world/{name}"] == _lines(folder / f"{name}.tum")
        assert f"/world/trajectories/{name}" in static
    assert rows["/world/vehicle"] == rows["/world/quadnav"]
    n = _lines(folder / "gnss_checks.csv", 1)
    assert [rows[f"/gnss/{c}"] for c in ("eph", "epv", "used")] == [n] * 3
    notes = json.loads((folder / "metrics.json").read_text())["notes"]
    assert rows["/events"] == len(notes) > 0


def test_planar_rerun_records_each_variant_its_fixes_and_innovations(tmp_path: Path) -> None:
    """``quadnav run planar --rerun``: the truth once, each variant's delayed and output
    estimates, its GPS fixes and innovations, row for row against its files; ``quadnav view``
    of the folder gives the same recording."""
    args = ["run", "planar", "--set", "duration_s=3", "--rerun"]
    folder = _made(tmp_path / "runs", args)
    rows, static = rows_and_static(folder / "recording.rrd")
    variants = sorted(d.name for d in folder.iterdir() if (d / "truth.tum").is_file())
    assert variants == ["handled", "naive", "no_update"]
    assert rows["/world/truth"] == _lines(folder / "handled" / "truth.tum")
    for v in variants:
        for name in ("delayed", "output"):
            assert rows[f"/world/{v}/{name}"] == _lines(folder / v / f"{name}.tum"), (v, name)
            assert f"/world/{v}/trajectories/{name}" in static
        if (folder / v / "gps.csv").is_file():
            assert rows[f"/world/{v}/gps"] == _lines(folder / v / "gps.csv", 1) > 0
        n = _lines(folder / v / "innovations.csv", 1)
        if v == "no_update":  # nothing fused, no innovation
            assert n == 0 and f"/test_ratio/{v}" not in rows
        else:
            assert rows[f"/test_ratio/{v}"] == rows[f"/innovations/{v}/x"] == n > 0
    assert _viewed(folder, tmp_path) == rows
