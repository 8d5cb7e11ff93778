"""Ctrl-C and errors leave honest run folders (issue 12, item 18): what finished is kept and
the folder says it was interrupted; an input error leaves no folder at all."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

QUADNAV = [sys.executable, "-m", "quadnav"]


def _wait_for_lines(root: Path, pattern: str, n: int, timeout_s: float) -> Path:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        for f in root.glob(pattern):
            if f.is_file() and f.read_text().count("\n") >= n:
                return f
        time.sleep(0.05)
    raise AssertionError(f"no {root}/{pattern} with {n} lines within {timeout_s} s")


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_ctrl_c_keeps_the_finished_seeds_and_marks_the_folder(tmp_path: Path, jobs: str) -> None:
    proc = subprocess.Popen(
        [*QUADNAV, "planar", "--seeds", "500", "--jobs", jobs, "--out", str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "COLUMNS": "120"},
        # A shell's background job ignores SIGINT and its children inherit that: restore it.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        seeds = _wait_for_lines(tmp_path, "*/seeds.jsonl", 3, timeout_s=90)
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
