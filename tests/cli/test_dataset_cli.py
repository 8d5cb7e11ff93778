"""``quadnav dataset``: make writes a folder the readers take and says what it made; info and
tracks read any dataset; bad requests are one-line errors that leave no folder behind."""

from __future__ import annotations

import errno
import json
import math
import os
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner, Result

from quadnav.cli.main import app
from tests.shared_data import SHARED, needs

runner = CliRunner()
EUROC = SHARED / "euroc_micro"


def one_line_error(res: Result, fragment: str) -> None:
    assert res.exit_code == 2, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0], res.stderr


def test_make_writes_a_readable_folder_and_prints_its_path_last(tmp_path: Path) -> None:
    out = tmp_path / "room"
    res = runner.invoke(
        app,
        [
            "dataset",
            "make",
            "room",
            "--duration",
            "1.5",
            "--rig",
            "thesis003_sim",
            "--out",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    assert res.stdout.strip().splitlines()[-1] == str(out)
    doc = json.loads((out / "dataset.json").read_text())
    # 0 to 1.5 s at 20 Hz, both ends, less the frame the unstated time offset pushes out
    assert doc["made"]["frames"] == 30 and doc["spec"]["rig"] == "thesis003_sim"
    assert doc["spec"]["sensors"] == doc["sensors"]["profile"] == "realistic"
    assert (out / "groundtruth.tum").read_text().count("\n") == 150  # 100 Hz over 1.5 s
    info = runner.invoke(app, ["dataset", "info", str(out)])
    assert info.exit_code == 0, info.output
    assert "30 frames, 20 Hz, 640x480" in info.stdout
    assert "IMU" in info.stdout and "samples at 200 Hz" in info.stdout


def test_make_refuses_bad_requests_in_one_line(tmp_path: Path) -> None:
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    (tmp_path / "file").write_text("x")
    gap = tmp_path / "file_gap.txt"  # 20 Hz poses, none from 1 s to 3 s
    t = [k * 0.05 for k in range(100) if not 1.0 < k * 0.05 < 3.0]
    gap.write_text("".join(f"{100 + x:.3f} {0.3 * x:.4f} 0 1 0 0 0 1\n" for x in t))
    cases = [
        (["attic", "--out", str(tmp_path / "a")], "unknown sequence or world 'attic'"),
        (["room", "--rig", "kinect", "--out", str(tmp_path / "b")], "--rig: unknown rig 'kinect'"),
        (["room", "--out", str(tmp_path / "full")], "exists and is not empty"),
        (["room", "--out", str(tmp_path / "file")], f"--out {tmp_path / 'file'}: is a file"),
        (["room", "--out", str(tmp_path / "file" / "sub")], f"{tmp_path / 'file'}"),
        (["room", "--set", "lighting=7", "--out", str(tmp_path / "c")], "lighting"),
        (
            ["room", "--motion", "nowhere.txt", "--out", str(tmp_path / "d")],
            "--motion 'nowhere.txt'",
        ),
        (["room", "--sensors", "perfect", "--out", str(tmp_path / "e")], "sensors"),
        (
            ["room", "--motion", str(gap), "--out", str(tmp_path / "g")],
            "longer than max_gap_s = 1 s that is bridged (--set max_gap_s=S)",
        ),
    ]
    for args, fragment in cases:
        one_line_error(runner.invoke(app, ["dataset", "make", *args]), fragment)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "file",
        "file_gap.txt",
        "full",
    ]  # nothing half-made


@needs(EUROC)
def test_tracks_on_the_real_euroc_frames_writes_its_statistics(tmp_path: Path) -> None:
    out = tmp_path / "tracks.json"
    res = runner.invoke(app, ["dataset", "tracks", str(EUROC), "--json", str(out)])
    assert res.exit_code == 0, res.output
    doc = json.loads(out.read_text())
    assert doc["tracks"]["n_frames"] == 95
    # the vehicle stands still: nearly every feature is kept from one frame to the next
    assert doc["tracks"]["fraction_tracked"]["median"] > 0.95
    assert doc["images"]["corners"] > 150
    one_line_error(
        runner.invoke(app, ["dataset", "tracks", str(EUROC), "--camera", "cam7"]), "cam7"
    )
    one_line_error(
        runner.invoke(app, ["dataset", "tracks", str(EUROC), "--duration", "-1"]), "--duration"
    )


def test_make_on_a_full_disk_is_one_line_naming_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 21, item 8: the images' writes find the disk full; libpng's "Write Error" leaked."""
    real = Path.write_bytes

    def full(self: Path, data: Any) -> int:
        if self.suffix == ".png":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", full)
    out = tmp_path / "room"
    res = runner.invoke(app, ["dataset", "make", "room", "--duration", "1", "--out", str(out)])
    one_line_error(res, "No space left on device")
    assert f"cannot write {out}.partial/mav0/cam0/data/" in res.stderr
    assert list(tmp_path.iterdir()) == []  # the partial folder removed


def test_info_counts_bad_imu_rows_instead_of_refusing_the_dataset(tmp_path: Path) -> None:
    """Issue 21, item 7: one out-of-order IMU row refused the whole dataset."""
    from tests.io.test_datasets_euroc import _edit, _tiny

    root = _tiny(tmp_path / "seq")
    imu = root / "mav0" / "imu0" / "data.csv"
    _edit(imu, 8, imu.read_text().splitlines()[2])  # back to line 3's stamp
    res = runner.invoke(app, ["dataset", "info", str(root)])
    assert res.exit_code == 0, res.output
    assert "49 samples at 200 Hz" in res.stdout
    assert "rejected 1 IMU rows out of order" in " ".join(res.stdout.split())


def test_a_motion_file_is_made_whole_unless_a_duration_is_given(tmp_path: Path) -> None:
    """A motion file longer than the built-in flights' 60 s is made to its end by default (it
    was cut at 60 s without a word); ``--duration`` and ``--set duration_s=`` still cut it."""
    from quadnav.experiments.datasets import _motion, _span, sequence_spec

    walk = tmp_path / "walk.txt"  # 75 s at 20 Hz: a slow walk along x, turning
    walk.write_text(
        "".join(
            f"{10 + k * 0.05:.3f} {0.02 * k * 0.05:.5f} 0 1.5 0 0 "
            f"{math.sin(0.005 * k):.6f} {math.cos(0.005 * k):.6f}\n"
            for k in range(1501)
        )
    )

    def span_s(fields: dict[str, object], sets: list[str]) -> float:
        spec = sequence_spec("room", fields, sets)
        t0, t1 = _span(spec, _motion(spec))
        return (t1 - t0) * 1e-9

    assert 74.0 < span_s({"motion": str(walk)}, []) <= 75.0  # (the spline gives up a few tenths)
    assert span_s({"motion": str(walk), "duration_s": 10.0}, []) == pytest.approx(10.0, abs=1e-6)
    assert span_s({"motion": str(walk)}, ["duration_s=20"]) == pytest.approx(20.0, abs=1e-6)
    assert 74.0 < span_s({}, [f"motion={walk}"]) <= 75.0
    assert sequence_spec("room", {"motion": "flight_path"}).duration_s == 60.0
    assert sequence_spec("hall_laps").duration_s == 75.0  # (a built-in keeps its own)
