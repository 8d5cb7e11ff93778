"""``quadnav sweep`` on the command line: a sweep file with options on top, one-line refusals
naming the option, and Ctrl-C on the process pool then the same command again."""

from __future__ import annotations

import json
import signal
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.io.tables import read_parquet_columns
from tests.interrupting import start_interruptible, wait_for_lines

runner = CliRunner()
SHORT = {"plan.kind": "takeoff_forward", "plan.takeoff_s": 0.5, "plan.duration_s": 3,
         "plan.height_m": 1, "plan.forward_m": 1}  # fmt: skip


def test_a_sweep_file_with_a_grid_added_on_the_command_line(tmp_path: Path) -> None:
    sweep = {"scenario": "indoor_vision_pose", "grid": {"vision.delay_s": "0.05:0.25:2"},
             "seeds": 1, "set": SHORT}  # fmt: skip
    (tmp_path / "sweep.yaml").write_text(yaml.safe_dump(sweep))
    out = tmp_path / "s"
    args = ["sweep", "--grid-file", str(tmp_path / "sweep.yaml"), "--grid",
            "vision.sigma_m=[0.01,0.03]", "--jobs", "1", "--out", str(out)]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert result.stdout.strip().splitlines()[-1] == str(out)
    t = read_parquet_columns(out / "results.parquet")
    assert sorted(zip(t["vision.delay_s"], t["vision.sigma_m"], strict=True)) == [
        (0.05, 0.01), (0.05, 0.03), (0.25, 0.01), (0.25, 0.03)
    ]  # fmt: skip
    assert t["seed"] == [0] * 4 and set(t["status"]) == {"ok"}
    config = yaml.safe_load((out / "config.yaml").read_text())
    assert config["plan"]["duration_s"] == 3  # the file's set
    assert len(list((out / "plots").glob("output_rmse_m__*.png"))) == 2  # one per key
    again = runner.invoke(app, args)  # the same sweep: nothing to run
    assert again.exit_code == 0 and "run now" in again.stdout
    assert (out / "tasks.jsonl").read_text().count("\n") == 4


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--grid", "vision.delay=0:1:3"], "--grid vision.delay=0:"),
        (["--grid", "vision.delay_s=0:1:2000"], "--grid vision.delay_s=0:1:2000"),
        (["--grid", "vision.delay_s=0:1:1000", "--seeds", "2000"], "--seeds"),
        (
            ["--grid", "vision.delay_s=0.1", "--local-cluster", "2", "--scheduler", "tcp://a:1"],
            "--scheduler and --local-cluster",
        ),
    ],
)
def test_a_refusal_is_one_line_naming_the_option(
    tmp_path: Path, args: list[str], named: str
) -> None:
    result = runner.invoke(
        app, ["sweep", "indoor_vision_pose", *args, "--out", str(tmp_path / "s")]
    )
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {named}"), result.stderr
    assert not (tmp_path / "s").exists()  # refused before anything started


def test_dask_without_the_extra_names_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a: None if name == "distributed" else real(name, *a),
    )
    args = ["sweep", "--grid", "vision.delay_s=0.1", "--local-cluster", "2", "--out", str(tmp_path)]
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    assert (
        result.stderr.strip()
        == "error: --local-cluster needs Dask distributed: pip install 'quadnav[sweep]'"
    )


def test_ctrl_c_on_the_pool_keeps_what_finished_and_the_same_command_resumes(
    tmp_path: Path,
) -> None:
    out = tmp_path / "s"
    sets = [x for k, v in {**SHORT, "plan.duration_s": 6}.items() for x in ("--set", f"{k}={v}")]
    args = ["sweep", "indoor_vision_pose", "--grid", "vision.delay_s=0.05:0.3:6", "--seeds", "2",
            "--jobs", "2", "--out", str(out), *sets]  # fmt: skip
    proc = start_interruptible(args)
    try:
        journal = wait_for_lines(out, "tasks.jsonl", 2, timeout_s=90)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130 and "Traceback" not in err and "interrupted" in err
    assert json.loads((out / "status.json").read_text())["status"] == "interrupted"
    first = [json.loads(x)["task"] for x in journal.read_text().splitlines()]
    assert 2 <= len(first) < 12
    assert len(read_parquet_columns(out / "results.parquet")["task"]) == len(first)
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    tasks = [json.loads(x)["task"] for x in journal.read_text().splitlines()]
    assert sorted(tasks) == list(range(12))  # each task once: the finished ones not redone
    assert json.loads((out / "status.json").read_text())["status"] == "complete"
