from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from quadnav.cli.main import app

runner = CliRunner()


def test_sim_lists_and_runs_a_builtin(tmp_path: Path) -> None:
    listing = runner.invoke(app, ["sim", "--list"])
    assert listing.exit_code == 0 and "thesis002_nested_tracking" in listing.stdout
    result = runner.invoke(
        app, ["sim", "thesis002_pd_stabilization", "--set", "duration_s=3", "--out", str(tmp_path)]
    )
    assert result.exit_code == 0, result.output
    run_dir = Path(result.stdout.strip().splitlines()[-1])
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["scenario"] == "thesis002_pd_stabilization" and metrics["table"]
    for name in ("positions", "euler", "controls", "top_view"):
        assert (run_dir / "plots" / f"{name}.png").stat().st_size > 5_000
    header = (run_dir / "states.csv").read_text().splitlines()[0]
    assert header.startswith("t_ns,x_m,y_m,z_m") and "ref_x_m" in header
    assert (run_dir / "report.html").is_file() and (run_dir / "trajectory.tum").is_file()


def test_sim_from_yaml(tmp_path: Path) -> None:
    cfg = tmp_path / "s.yaml"
    cfg.write_text(
        "name: hover_test\ntrajectory: {kind: hover, position_m: [0, 0, 1]}\ninitial: {position_m: [0, 0, 0]}\nduration_s: 4\n"
    )
    result = runner.invoke(app, ["sim", str(cfg), "--out", str(tmp_path / "runs")])
    assert result.exit_code == 0, result.output
    run_dir = Path(result.stdout.strip().splitlines()[-1])
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["final_error_m"] < 0.1  # took off from the ground to 1 m


def test_sim_bad_input_is_one_line(tmp_path: Path) -> None:
    for args, fragment in (
        (["nonsense"], "neither a built-in scenario"),
        (["circle", "--set", "duration_s=-1"], "duration_s"),
        (["circle", "--set", "controller=pd"], "euler_lagrange"),
    ):
        result = runner.invoke(app, ["sim", *args, "--out", str(tmp_path)])
        assert result.exit_code == 2, (args, result.output)
        assert fragment in result.stderr and len(result.stderr.strip().splitlines()) == 1
