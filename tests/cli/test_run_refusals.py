"""Issue 21, item 14: what a fault scenario refused and how often the filter reset were only in
``metrics.json``; ``quadnav run`` prints them after its metrics and ``report.html`` has them."""

from __future__ import annotations

import html
import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app

# fault_gps_glitch shortened: a 20 m jump for 3 s, longer than estimator.reset_after_s (2 s)
GLITCH = ["plan.square_m=8", "plan.hold_s=1", "faults.gps_glitch=[[12,15,20,0]]"]
RESET = "gps: rejected for 2 s, position reset to it"


@pytest.mark.slow  # two glitch flights; test_nav_faults.py counts the refusals in CI
def test_the_glitch_s_refusals_and_resets_are_on_the_terminal_and_in_the_report(
    tmp_path: Path,
) -> None:
    args = [x for s in GLITCH for x in ("--set", s)]
    result = CliRunner().invoke(
        app,
        ["run", "fault_gps_glitch", "--seeds", "2", "--jobs", "1", "--out", str(tmp_path), *args],
    )
    assert result.exit_code == 0, result.output
    run_dir = Path(result.stdout.strip().splitlines()[-1])
    per_seed = json.loads((run_dir / "metrics.json").read_text())["per_seed"]
    gated = sum(m["counts"]["gps"]["rejected_gate"] for m in per_seed)
    assert gated >= 2 * 5  # (3 s of 5 Hz fixes a seed, but for the resets)
    out = result.stdout
    assert "total over 2 seed(s)" in out
    assert re.search(rf"gps: refused by the innovation gate\s*│\s*{gated}\s*│", out), out
    # each seed's resets, with its time, as the filter logged them
    for seed in (0, 1):
        assert re.search(rf"seed {seed}, \d+\.\d{{3}} s: {RESET}", out), out
    report = html.unescape((run_dir / "report.html").read_text())
    assert "Refused samples and resets" in report
    assert "gps: refused by the innovation gate" in report and f"<td>{gated}</td>" in report
    assert re.search(rf"seed 1, \d+\.\d{{3}} s: {RESET}", report)
