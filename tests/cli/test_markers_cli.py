"""`quadnav markers` and `quadnav calibrate` end to end on synthetic frames (a corrupt one
among them) and on bad input."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.geometry.rotations import Pose

runner = CliRunner()
METRICS_KEYS = ["frames", "frames_processed", "frames_skipped", "frames_with_pose",
                "fraction_with_pose", "frames_rejected", "jitter_rms_mm", "jitter_median_mm",
                "detect_ms_median", "pose_ms_median", "rms_px_median", "fps"]  # fmt: skip
STATS_KEYS = ["source", "time_base", "fps", "frames", "frames_processed", "frames_skipped",
              "skipped", "frames_with_pose", "fraction_with_pose", "frames_rejected",
              "rejected_by_reason", "frames_marker_fallback", "world_marker_id", "jitter_rms_mm", "jitter_median_mm",
              "detect_ms_median", "pose_ms_median", "rms_px_median", "camera_properties",
              "calibration", "notes", "images_written", "images_mb", "images_not_written", "stopped_by",
              "unknown_detector_parameters", "run_dir"]  # fmt: skip


def test_markers_on_an_image_folder_with_a_corrupt_frame(frames, tmp_path: Path) -> None:
    folder, cal, truth = frames
    res = runner.invoke(app, ["markers", str(folder), "--camera", str(cal), "--out", str(tmp_path),
                              "--set", "mount_rpy_deg=[0,0,0]", "--set", "fps=10"])  # fmt: skip
    assert res.exit_code == 0, res.output
    run = next(tmp_path.glob("*_markers"))
    stats = json.loads((run / "stats.json").read_text())
    assert stats["frames"] == 10 and stats["frames_skipped"] == 1 and stats["frames_with_pose"] == 9
    assert stats["world_marker_id"] == 5
    # The files' layout, key by key, as users' scripts read them (no link: no "mavlink" key).
    assert list(stats) == STATS_KEYS and stats["run_dir"] == str(run)
    assert len(stats["skipped"]) == 1 and stats["skipped"][0].startswith("frame 3: ")
    metrics = json.loads((run / "metrics.json").read_text())
    assert list(metrics) == ["kind", *METRICS_KEYS]
    rows = list(csv.DictReader((run / "poses.csv").open()))
    assert [int(r["frame"]) for r in rows] == [0, 1, 2, 4, 5, 6, 7, 8, 9]
    for r in rows:
        # with an identity mount the "vehicle" is the camera: compare with the rendered pose
        p = np.array([float(r["x_m"]), float(r["y_m"]), float(r["z_m"])])
        err = np.linalg.norm(p - truth[int(r["frame"])].p_A_B)
        sigma = np.sqrt(sum(float(r[f"cov_{a}_{a}"]) for a in "xyz"))
        # nearly head-on, a single marker's tilt is ambiguous: the covariance says so
        assert err < 0.05 and err < 4 * sigma + 0.005
        assert r["ids"] == "5" and float(r["cov_z_z"]) > 0
    assert (run / "overlay.mp4").stat().st_size > 10_000
    assert (run / "report.html").is_file()


def test_markers_bad_input_is_one_line(frames, tmp_path: Path) -> None:
    folder, cal, _ = frames
    cases = [
        (["markers", str(folder)], "no camera calibration"),
        (["markers", str(folder), "--camera", str(tmp_path / "nope.yml")], "no such file"),
        (["markers", str(folder), "--camera", str(cal), "--set", "dictionary=DICT_9X9_1"], "unknown ArUco dictionary"),
        (["markers", str(tmp_path / "missing.mp4"), "--camera", str(cal)], "no such file or folder"),
    ]  # fmt: skip
    for args, msg in cases:
        res = runner.invoke(app, [*args, "--out", str(tmp_path)])
        assert res.exit_code == 2, (args, res.output)
        assert msg in res.output
        assert "Traceback" not in res.output


def test_calibrate_writes_a_calibration_opencv_reads(tmp_path: Path) -> None:
    data = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "aruco"
    if not data.exists():
        pytest.skip(f"shared test data not found at {data}")
    folder = tmp_path / "views"
    folder.mkdir()
    for f in ("img_00.jpg", "img_02.jpg", "img_03.jpg"):
        (folder / f).write_bytes((data / f).read_bytes())
    (folder / "broken.jpg").write_bytes(b"not a jpeg")
    out = tmp_path / "camera.yml"
    res = runner.invoke(app, ["calibrate", str(folder), "--out", str(out)])
    assert res.exit_code == 0, res.output
    fs = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    assert 440 < K[0, 0] < 480 and fs.getNode("avg_reprojection_error").real() < 0.25
    assert "3 / 0" in res.output  # 3 views used, none rejected; the broken file is counted apart
    assert "4 / 1" in res.output


def test_markers_as_companion_sends_vision_estimates_and_setpoints(frames, tmp_path: Path) -> None:
    import os
    import socket

    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    folder, cal, _ = frames
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    autopilot = mavutil.mavlink_connection(
        f"udpin:127.0.0.1:{port}", source_system=1, dialect="common"
    )
    plan = tmp_path / "plan.tum"
    plan.write_text("0.0 0 0 1.5 0 0 0 1\n0.5 1 0 1.5 0 0 0 1\n")
    res = runner.invoke(app, ["markers", str(folder), "--camera", str(cal), "--out", str(tmp_path),
                              "--set", "mount_rpy_deg=[0,0,0]", "--set", "fps=10", "--set", "video=false",
                              "--mavlink", f"udpout:127.0.0.1:{port}", "--setpoints", str(plan)])  # fmt: skip
    assert res.exit_code == 0, res.output
    got: dict[str, list] = {}
    while (m := autopilot.recv_match(blocking=True, timeout=0.5)) is not None:
        got.setdefault(m.get_type(), []).append(m)
    autopilot.close()
    vis = got["VISION_POSITION_ESTIMATE"]
    assert len(vis) == 9  # one per frame with a pose (the corrupt frame has none)
    # NED at the boundary: the camera 1.2-1.6 m above the marker is z = -1.2..-1.6 down
    assert all(-1.7 < v.z < -1.1 for v in vis) and all(v.covariance[0] > 0 for v in vis)
    sp = got["SET_POSITION_TARGET_LOCAL_NED"]
    assert (
        len(sp) == 9
        and sp[0].z == pytest.approx(-1.5)
        and max(p.y for p in sp) == pytest.approx(1.0)
    )
    assert "HEARTBEAT" in got
    # stats.json ends with what the link sent: one estimate per pose, one setpoint per frame
    stats = json.loads((next(tmp_path.glob("*_markers")) / "stats.json").read_text())
    assert list(stats) == [*STATS_KEYS, "mavlink"]
    assert list(stats["mavlink"]) == ["url", "sent", "received", "bad_packets"]
    sent = stats["mavlink"]["sent"]
    assert sent["VISION_POSITION_ESTIMATE"] == 9 and sent["SET_POSITION_TARGET_LOCAL_NED"] == 9
    assert stats["mavlink"]["url"] == f"udpout:127.0.0.1:{port}"
    assert "MAVLink messages sent" in res.output


def test_marker_map_from_yaml_places_the_vehicle_in_the_world(frames, tmp_path: Path) -> None:
    """The same frames with marker 5 declared at (1, 2, 0) m, turned 90 degrees, in a YAML
    marker map: every pose moves and turns with it."""
    folder, cal, truth = frames
    params = tmp_path / "map.yaml"
    params.write_text(
        "dictionary: DICT_4X4_250\ntarget: map\nmount_rpy_deg: [0, 0, 0]\nfps: 10\nvideo: false\n"
        "map_markers:\n  - {id: 5, length_m: 0.2335, position_m: [1.0, 2.0, 0.0], rpy_deg: [0, 0, 90]}\n"
    )
    res = runner.invoke(
        app,
        [
            "markers",
            str(folder),
            "--camera",
            str(cal),
            "--params",
            str(params),
            "--out",
            str(tmp_path),
        ],
    )
    assert res.exit_code == 0, res.output
    run = next(tmp_path.glob("*_markers"))
    rows = list(csv.DictReader((run / "poses.csv").open()))
    assert len([r for r in rows if r["x_m"] != "nan"]) == 9
    from scipy.spatial.transform import Rotation

    T_W_M = Pose(Rotation.from_euler("z", 90, degrees=True), np.array([1.0, 2.0, 0.0]))
    for r in rows:
        want = (T_W_M @ truth[int(r["frame"])]).p_A_B
        got = np.array([float(r["x_m"]), float(r["y_m"]), float(r["z_m"])])
        assert np.linalg.norm(got - want) < 0.05
