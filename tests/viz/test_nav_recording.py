"""Issue 27, first part: a navigation run's rerun recording, read back with rerun's own reader
(``rerun.chunk.RrdReader``): the entities written and their rows against the folder's files."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.io.nav_run_files import read_nav_run
from quadnav.viz import MAX_ELLIPSOIDS, write_nav_recording

pytest.importorskip("rerun")
from rerun.chunk import RrdReader

from tests.viz.rrd import rows_and_static as _rows

runner = CliRunner()
SHORT = ["vision.source=pose", "plan.kind=takeoff_forward", "plan.takeoff_s=0.5",
         "plan.duration_s=1", "plan.height_m=0.5", "plan.forward_m=0.5"]  # fmt: skip


def _run(out: Path, *extra: str) -> Any:
    args = ["run", "--jobs", "1", *[x for s in SHORT for x in ("--set", s)], "--out", str(out)]
    return runner.invoke(app, [*args, *extra])


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short flight of ``quadnav run --rerun`` (its folder, with recording.rrd)."""
    out = tmp_path_factory.mktemp("runs")
    result = _run(out, "--rerun")
    assert result.exit_code == 0, result.output
    (folder,) = [p for p in out.iterdir() if p.is_dir()]
    return folder


def _data_lines(path: Path, header: int) -> int:
    return sum(1 for line in path.read_text().splitlines()[header:] if line.strip())


def test_run_rerun_writes_every_stream_with_the_files_rows(run_dir: Path) -> None:
    rows, static = _rows(run_dir / "recording.rrd")
    n_truth = _data_lines(run_dir / "truth.tum", 0)
    n_output = _data_lines(run_dir / "output.tum", 0)
    n_delayed = _data_lines(run_dir / "delayed.csv", 1)
    assert 100 < n_truth < 2000  # short enough that nothing is decimated but the ellipsoids
    assert rows["/world/truth"] == n_truth
    assert rows["/world/output"] == rows["/world/vehicle"] == n_output
    assert rows["/world/delayed"] == n_delayed
    assert rows["/world/setpoint"] == _data_lines(run_dir / "positions.csv", 1)
    assert MAX_ELLIPSOIDS / 2 <= rows["/world/delayed/sigma"] <= min(n_delayed, MAX_ELLIPSOIDS)
    sources = {p.stem.removeprefix("innovations_") for p in run_dir.glob("innovations_*.csv")}
    assert {"vision", "baro"} <= sources
    for source in sources:
        table = run_dir / f"innovations_{source}.csv"
        n = _data_lines(table, 1)
        width = sum(
            c.startswith("innovation_") for c in table.read_text().split("\n")[0].split(",")
        )
        assert rows[f"/test_ratio/{source}"] == n
        assert [rows[f"/innovations/{source}/{k}"] for k in range(width)] == [n] * width
    # the whole trajectories as static line strips, and the vehicle's axes
    assert {"/world/trajectories/truth", "/world/trajectories/output", "/world/vehicle"} <= set(
        static
    )
    strip = static["/world/trajectories/truth"].column("LineStrips3D:strips")[0].as_py()[0]
    truth = read_nav_run(run_dir).truth
    np.testing.assert_allclose(np.array(strip), truth.p_W_B, atol=1e-6)  # float32 in the file
    assert RrdReader(run_dir / "recording.rrd").blueprints()  # the layout travels with it


def test_a_long_stream_is_decimated_to_the_bound(run_dir: Path, tmp_path: Path) -> None:
    files = read_nav_run(run_dir)
    info = write_nav_recording(
        files, tmp_path / "small.rrd", max_points=50, max_scalars=10, max_ellipsoids=5
    )
    rows, _ = _rows(tmp_path / "small.rrd")
    assert rows == {k: v for k, v in info.rows.items() if v}  # what it says it wrote
    for entity in ("/world/truth", "/world/output", "/world/vehicle", "/world/delayed"):
        assert 25 < rows[entity] <= 50, entity
    assert 2 < rows["/world/delayed/sigma"] <= 5
    assert 5 <= rows["/test_ratio/vision"] <= 10
    assert info.size_bytes < (run_dir / "recording.rrd").stat().st_size


def test_view_writes_the_events_of_a_run(run_dir: Path, tmp_path: Path) -> None:
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    (copy / "recording.rrd").unlink()
    metrics = json.loads((copy / "metrics.json").read_text())
    metrics["per_seed"][0]["filter_events"] = ["0.700 s: vision reset", "1.250 s: baro re-anchored"]
    (copy / "metrics.json").write_text(json.dumps(metrics))
    result = runner.invoke(app, ["view", str(copy)])
    assert result.exit_code == 0, result.output
    assert str(copy / "recording.rrd") in result.stdout.replace("\n", "")
    texts = []
    for chunk in RrdReader(copy / "recording.rrd").stream():
        if chunk.entity_path == "/events":
            batch = chunk.to_record_batch()
            texts += [x[0] for x in batch.column("TextLog:text").to_pylist()]
            stamps = batch.column("t").to_pylist()
    assert texts == ["vision reset", "baro re-anchored"]
    assert [s.total_seconds() for s in stamps] == pytest.approx([0.7, 1.25])


def test_view_spawn_without_a_display_says_so_and_writes_the_file(
    run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "x.rrd"
    result = runner.invoke(app, ["view", str(run_dir), "--spawn", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "viewer not opened: no display" in result.stdout
    assert out.stat().st_size > 0


def test_view_refuses_a_folder_that_is_no_run_in_one_line(tmp_path: Path) -> None:
    (tmp_path / "metrics.json").write_text("{}")
    for folder in (tmp_path, tmp_path / "missing"):
        result = runner.invoke(app, ["view", str(folder)])
        assert result.exit_code == 2
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"error: {folder}:"), result.stderr
    assert not (tmp_path / "recording.rrd").exists()


def _without_rerun(monkeypatch: pytest.MonkeyPatch) -> None:
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "rerun" else real(name, *a)
    )


def test_rerun_without_the_extra_is_one_line_before_the_flight(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _without_rerun(monkeypatch)
    result = _run(tmp_path / "runs", "--rerun")
    assert result.exit_code == 2
    assert result.stderr.strip() == "error: --rerun needs rerun: pip install 'quadnav[viz]'"
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
    result = runner.invoke(app, ["view", str(tmp_path)])
    assert result.stderr.strip() == "error: quadnav view needs rerun: pip install 'quadnav[viz]'"
