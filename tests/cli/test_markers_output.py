"""What `quadnav markers` says (issue 21, item 14): no `nan` in the summary, a few progress
lines when the output is not a terminal even for a stream of unknown length, and saved overlay
images announced (where, how much) and capped."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.geometry.camera import thesis_camera
from tests.cli.conftest import marker_views

runner = CliRunner()
IDENTITY_MOUNT = ["--set", "mount_rpy_deg=[0,0,0]", "--set", "video=false"]


def _folder(root: Path, n: int) -> Path:
    images, _ = marker_views(thesis_camera(), n)
    folder = root / "frames"
    folder.mkdir()
    for k, im in enumerate(images):
        cv2.imwrite(str(folder / f"f{k:03d}.png"), im)
    return folder


def test_two_poses_give_no_jitter_and_the_summary_says_why(frames, tmp_path: Path) -> None:
    _, cal, _ = frames
    folder = _folder(tmp_path, 2)
    res = runner.invoke(app, ["markers", str(folder), "--camera", str(cal), *IDENTITY_MOUNT,
                              "--out", str(tmp_path / "out")])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "nan" not in res.stdout.lower()
    row = next(ln for ln in res.stdout.splitlines() if "frame-to-frame jitter" in ln)
    assert "n/a (no 3 consecutive frames with a pose)" in row
    run = next((tmp_path / "out").glob("*_markers"))
    stats = json.loads((run / "stats.json").read_text())
    assert stats["frames_with_pose"] == 2 and stats["jitter_rms_mm"] is None


def test_a_piped_raw_stream_prints_a_few_progress_lines(frames, tmp_path: Path) -> None:
    """A raw stream has no frame count: the progress went out once per frame (2,605 lines for
    a thesis .h264). Piped, it is a line every 10 s and the last one at the end."""
    _, cal, _ = frames
    images, _ = marker_views(thesis_camera(), 6)
    stream = tmp_path / "flight.mjpeg"  # a raw stream, as a raw .h264: no timestamps, no count
    stream.write_bytes(b"".join(cv2.imencode(".jpg", images[k % 6])[1].tobytes() for k in range(40)))  # fmt: skip
    res = runner.invoke(app, ["markers", str(stream), "--camera", str(cal), *IDENTITY_MOUNT,
                              "--fps", "40", "--out", str(tmp_path / "out")])  # fmt: skip
    assert res.exit_code == 0, res.output
    progress = re.findall(r"^markers: (\d+) (\d+) poses \(\d+\.\d s\)$", res.stderr, re.M)
    assert 1 <= len(progress) <= 3, res.stderr
    assert progress[-1] == ("40", "40")  # the last line says where it ended


def test_saved_images_are_announced_and_capped(frames, tmp_path: Path) -> None:
    _, cal, _ = frames
    folder = _folder(tmp_path, 8)
    out = tmp_path / "out"
    res = runner.invoke(app, ["markers", str(folder), "--camera", str(cal), *IDENTITY_MOUNT,
                              "--set", "write_images=true", "--max-images-mb", "0.6",
                              "--out", str(out)])  # fmt: skip
    assert res.exit_code == 0, res.output
    run = next(out.glob("*_markers"))
    stats = json.loads((run / "stats.json").read_text())
    written = sorted((run / "images").glob("frame_*.png"))
    size = sum(p.stat().st_size for p in written)
    assert 1 <= len(written) < 8 and size <= 0.6e6
    assert stats["images_written"] == len(written)
    assert stats["images_not_written"] == 8 - len(written)
    assert np.isclose(stats["images_mb"], size / 1e6)
    notes = [ln for ln in res.stderr.splitlines() if ln.startswith("note: images:")]
    assert len(notes) == 2, res.stderr  # where and how much at the start; the cap, once
    assert str(run / "images") in notes[0] and "MB each, about" in notes[0] and "8 frames" in notes[0]  # fmt: skip
    assert "stopped at" in notes[1] and "--max-images-mb 0.6" in notes[1]
    row = next(ln for ln in res.stdout.splitlines() if "overlay images" in ln)
    assert f"{len(written)} (" in row and "not written" in row


def test_a_bad_images_cap_is_one_line(frames, tmp_path: Path) -> None:
    folder, cal, _ = frames
    for bad in ("0", "-5", "nan"):
        res = runner.invoke(app, ["markers", str(folder), "--camera", str(cal),
                                  "--max-images-mb", bad, "--out", str(tmp_path)])  # fmt: skip
        assert res.exit_code == 2, res.output
        assert "--max-images-mb" in res.output and "Traceback" not in res.output
        assert len(res.output.strip().splitlines()) == 1
