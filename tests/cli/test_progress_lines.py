"""Output that is not a terminal (CI logs, pipes) gets one line per finished seed from
`quadnav run` (issue 12, item 26)."""

from __future__ import annotations

import re
from pathlib import Path

from typer.testing import CliRunner

from quadnav.cli.main import app

SHORT = ["--set", "plan.square_m=0.5", "--set", "plan.hold_s=0.5", "--set", "vision.dropouts_s=[]"]


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
