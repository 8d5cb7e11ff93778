"""Output that is not a terminal (CI logs, pipes) gets one line per finished seed from
`quadnav run` (issue 12, item 26)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app

SHORT = ["--set", "plan.square_m=0.5", "--set", "plan.hold_s=0.5", "--set", "vision.dropouts_s=[]"]


@pytest.mark.slow  # two flights; the other piped-progress tests run in CI
def test_run_prints_a_line_per_finished_seed_when_piped(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app,
        [
            "run",
            "indoor_vision_pose",
            "--seeds",
            "2",
            "--jobs",
            "1",
            "--out",
            str(tmp_path),
            *SHORT,
        ],
    )
    assert result.exit_code == 0, result.output
    lines = re.findall(r"^indoor_vision_pose: (\d)/2 seed (\d) \(\d+\.\d s\)$", result.stderr, re.M)
    assert lines == [("1", "0"), ("2", "1")]
    assert Path(result.stdout.strip().splitlines()[-1]).is_dir()  # the run folder stays last


# Issue 21, item 14: piped progress is a few lines per run, however long the run or many its
# seeds (indoor_vio printed 20 lines per seed; a study a line per seed).
PROGRESS = re.compile(r"^(\w+): (\d+)/(\d+) .+ \(\d+\.\d s\)$", re.M)
FEW = 5  # a line per quarter of the work at most, and its end


def test_a_flight_on_the_vio_reports_a_few_lines_when_piped(tmp_path: Path) -> None:
    short_vio = ["plan.duration_s=1.5", "plan.takeoff_s=0.5", "plan.height_m=1", "plan.forward_m=1"]
    args = [x for s in short_vio for x in ("--set", s)]
    result = CliRunner().invoke(app, ["run", "indoor_vio", "--out", str(tmp_path), *args])
    assert result.exit_code == 0, result.output
    lines = PROGRESS.findall(result.stderr)
    assert 1 <= len(lines) <= FEW, result.stderr
    assert lines[-1][1:] == ("100", "100")  # the end is always said


def test_a_study_of_many_seeds_reports_a_few_lines_when_piped(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app,
        ["run", "planar", "--seeds", "12", "--jobs", "1", "--out", str(tmp_path),
         "--set", "duration_s=2", "--set", "gps.delay_s=0.3"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    lines = PROGRESS.findall(result.stderr)
    assert 1 <= len(lines) <= FEW, result.stderr
    assert lines[-1][1] == lines[-1][2] == str(3 * 12)  # (three experiments a seed)
