from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app

runner = CliRunner()
SHORT = ["--set", "duration_s=2", "--set", "gps.delay_s=0.3"]


def test_planar_writes_a_run_folder_and_prints_its_path_last(tmp_path: Path) -> None:
    result = runner.invoke(app, ["run", "planar", "--out", str(tmp_path), "--jobs", "1", *SHORT])
    assert result.exit_code == 0, result.output
    last = result.stdout.strip().splitlines()[-1]
    run_dir = Path(last)
    assert run_dir.parent == tmp_path and run_dir.is_dir()
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert set(metrics["summary"]) == {"no_update", "naive", "handled"}
    assert "handled" in result.stdout and "out/floor" in result.stdout
    assert "duration_s: 2" in (run_dir / "config.yaml").read_text()
    # Each column of the terminal table shows its own field of the summary.
    row = next(x for x in result.stdout.splitlines() if "handled" in x)
    cells = [c.strip() for c in row.strip("│ ").split("│")]
    s = metrics["summary"]["handled"]
    assert cells == [
        "handled",
        f"{s['rmse_delayed_m']['median']:.4f}",
        f"{s['rmse_output_m']['median']:.4f}",
        f"{s['rmse_floor_m']['median']:.4f}",
        f"{s['output_over_floor']['median']:.3f}",
        f"{s['nees_mean']['median']:.3g}",
        str(s["gps_fused_total"]),
        str(s["gps_rejected_gate_total"]),
        str(s["gps_rejected_too_old_total"]),
    ]
    assert len(set(cells[1:4])) == 3  # delayed, output and floor differ: a swap would show


def test_planar_with_seeds_and_a_config_file(tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("experiments: [handled]\nduration_s: 2\ngps:\n  delay_s: 0.2\n")
    result = runner.invoke(
        app, ["planar", str(cfg), "--seeds", "3", "--out", str(tmp_path / "r"), "--jobs", "2"]
    )
    assert result.exit_code == 0, result.output
    run_dir = Path(result.stdout.strip().splitlines()[-1])
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert [m["seed"] for m in metrics["per_seed"]["handled"]] == [0, 1, 2]
    assert (run_dir / "plots" / "monte_carlo.png").is_file()


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--set", "gps.delay_s=-1"], "gps.delay_s"),
        (["--set", "gps.period_s=0.001"], "gps.period_s"),
        (["--set", "nonsense=1"], "nonsense: unknown key"),
        (["/no/such/config.yaml"], "not found"),
        (["--set", "oops"], "key.subkey=value"),
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(
    tmp_path: Path, args: list[str], fragment: str
) -> None:
    result = runner.invoke(app, ["planar", "--out", str(tmp_path), *args])
    assert result.exit_code == 2
    assert fragment in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert "Traceback" not in result.output
    assert not any(tmp_path.iterdir()), "no run folder for a config that does not validate"


def test_console_script_maps_errors_to_exit_code_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("gps: {delay_s: [1, 2}\n")
    proc = subprocess.run(
        [sys.executable, "-m", "quadnav", "run", str(bad)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert proc.stderr.startswith("error: ") and len(proc.stderr.strip().splitlines()) == 1


def test_help_lists_the_commands() -> None:
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    assert "run" in result.stdout and "planar" in result.stdout
