"""Ctrl-C and errors leave honest run folders (issue 12, item 18): what finished is kept and
the folder says it was interrupted; an input error leaves no folder at all."""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import pytest

from tests.interrupting import QUADNAV, start_interruptible, wait_for_lines


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_ctrl_c_keeps_the_finished_seeds_and_marks_the_folder(tmp_path: Path, jobs: str) -> None:
    proc = start_interruptible(["planar", "--seeds", "500", "--jobs", jobs, "--out", str(tmp_path)])
    try:
        seeds = wait_for_lines(tmp_path, "*/seeds.jsonl", 3, timeout_s=90)
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130
    assert "Traceback" not in err and "interrupted" in err
    run_dir = seeds.parent
    status = json.loads((run_dir / "status.json").read_text())
    assert status["status"] == "interrupted"
    lines = [json.loads(x) for x in seeds.read_text().splitlines()]
    assert len(lines) >= 3 and all("rmse_output_m" in x for x in lines)  # each a whole record
    assert len(lines) < 3 * 500  # it did stop
    assert not (run_dir / "metrics.json").exists()  # no summary that looks complete
    assert str(run_dir) in err


def test_an_input_error_leaves_no_folder(tmp_path: Path) -> None:
    out = tmp_path / "runs"
    result = subprocess.run(
        [*QUADNAV, "planar", "--set", "gps.delay_s=inf", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0 and "gps.delay_s" in result.stderr
    assert not out.exists() or list(out.iterdir()) == []


def test_a_finished_run_is_marked_complete(tmp_path: Path) -> None:
    result = subprocess.run(
        [*QUADNAV, "planar", "--set", "duration_s=2", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    run_dir = Path(result.stdout.strip().splitlines()[-1])
    assert json.loads((run_dir / "status.json").read_text())["status"] == "complete"
    assert (run_dir / "metrics.json").is_file()
