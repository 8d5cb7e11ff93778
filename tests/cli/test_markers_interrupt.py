"""Ctrl-C in `quadnav markers` (issue 21, item 1): a video file stopped half way is an
interrupted run (exit 130, status interrupted, its rows kept), as `quadnav run` does. A live
camera, which only Ctrl-C or the window ends, still finishes its run
(tests/cli/test_markers_sources.py::test_ctrl_c_ends_a_live_run_with_its_results_written)."""

from __future__ import annotations

import csv
import signal
from pathlib import Path

import cv2
import numpy as np

from quadnav.geometry.camera import thesis_camera
from quadnav.io.run_folder import read_run_status
from tests.cli.conftest import marker_views
from tests.interrupting import start_interruptible, wait_for_lines


def _video(path: Path, n: int) -> Path:
    """``n`` frames of marker 5 (twelve views, over and over) as an MP4 at 40 fps."""
    images, _ = marker_views(thesis_camera(), 12)
    w = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"mp4v"), 40, (640, 480))
    for k in range(n):
        w.write(cv2.cvtColor(images[k % len(images)], cv2.COLOR_GRAY2BGR))
    w.release()
    return path


def test_ctrl_c_on_a_video_file_is_an_interrupted_run(frames, tmp_path: Path) -> None:
    _, cal, _ = frames
    video = _video(tmp_path / "flight.mp4", 2000)
    out = tmp_path / "runs"
    proc = start_interruptible(["markers", str(video), "--camera", str(cal),
                                "--set", "mount_rpy_deg=[0,0,0]", "--out", str(out)])  # fmt: skip
    try:
        wait_for_lines(out, "*/poses.csv", 21, timeout_s=120)  # a header and 20 rows
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted" in err
    (run,) = out.glob("*_markers")
    assert read_run_status(run) == "interrupted" and str(run) in err
    rows = list(csv.DictReader((run / "poses.csv").open()))
    assert 20 <= len(rows) < 2000  # it stopped, with what it had done
    assert [int(r["frame"]) for r in rows] == list(range(len(rows)))
    assert all(np.isfinite(float(r["z_m"])) for r in rows)  # each row whole
    assert not (run / "metrics.json").exists()  # no summary that looks complete
    assert cv2.VideoCapture(str(run / "overlay.mp4")).isOpened()  # the video closed, readable
