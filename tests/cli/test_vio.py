"""``quadnav vio``: a short real run of the estimator on a built-in sequence made by the command,
and every bad input as one line naming the option."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.io.run_folder import read_run_status
from quadnav.io.trajectory_io import read_tum
from tests.shared_data import SHARED, needs

runner = CliRunner()


@pytest.fixture(scope="module")
def first_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """``quadnav vio room_easy --duration 4``: the command makes 4 s of the room (at rest for
    2 s, then flying) under OUT/datasets and runs the real estimator over it."""
    out = tmp_path_factory.mktemp("vio_cli")
    result = runner.invoke(app, ["vio", "room_easy", "--duration", "4", "--out", str(out)])
    assert result.exit_code == 0, result.output
    run_dir = Path(result.stdout.strip().splitlines()[-1])
    return out, run_dir


def test_a_short_real_run_is_metric_and_gravity_aligned(first_run: tuple[Path, Path]) -> None:
    out, run_dir = first_run
    assert run_dir.parent == out and read_run_status(run_dir) == "complete"
    m = json.loads((run_dir / "metrics.json").read_text())
    # a static start then 2 s of flight: the estimate must be metric and level; 5 cm and
    # 1 degree are loose bounds for a VINS-class estimator on clean synthetic images
    assert m["ape_4dof"]["rmse_m"] < 0.05
    assert m["gravity_error_deg"] < 1.0
    assert m["fraction_with_estimate"] > 0.5 and m["failures"] == 0
    assert m["ape_sim3"]["scale"] == pytest.approx(1.0, abs=0.2)
    events = [json.loads(x) for x in (run_dir / "events.jsonl").read_text().splitlines()]
    assert events and events[0]["kind"] == "initialized"
    assert m["timing"]["frames_per_s"] > 0 and "optimize" in m["timing"]["stage_ms_per_call"]


def test_the_sequence_is_made_once(first_run: tuple[Path, Path]) -> None:
    out, _ = first_run
    (made,) = (out / "datasets").iterdir()
    stamp = (made / "dataset.json").stat().st_mtime_ns
    result = runner.invoke(app, ["vio", "room_easy", "--duration", "4", "--no-video",
                                 "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert [made] == list((out / "datasets").iterdir())
    assert (made / "dataset.json").stat().st_mtime_ns == stamp
    assert not (Path(result.stdout.strip().splitlines()[-1]) / "tracks.mp4").exists()


def test_final_ba_writes_the_smoothed_trajectory_into_the_metrics_and_the_report(
    first_run: tuple[Path, Path],
) -> None:
    """``--final-ba`` on the same 4 s: ``metrics.json``'s ``final`` has the smoothing's report
    (one segment, none failed, the graph's error lowered), the final APE is printed and in
    the report; without it (the first run) the final trajectory is the window's, unsmoothed."""
    out, plain = first_run
    result = runner.invoke(app, ["vio", "room_easy", "--duration", "4", "--no-video",
                                 "--final-ba", "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "final trajectory (--final-ba, not causal): APE after SE(3)" in result.stdout
    run_dir = Path(result.stdout.strip().splitlines()[-1])
    final = json.loads((run_dir / "metrics.json").read_text())["final"]
    said = f"APE after SE(3) {final['ape_se3']['rmse_m']:.4f} m"
    assert said in result.stdout  # the number printed is the one scored
    sm = final["smoothing"]
    assert sm["segments"] == 1 and sm["failed"] == 0 and sm["error_after"] < sm["error_before"]
    assert final["ape_se3"]["rmse_m"] < 0.05
    assert "final trajectory (not causal): APE SE(3)" in (run_dir / "report.html").read_text()
    plain_final = json.loads((plain / "metrics.json").read_text())["final"]
    assert "smoothing" not in plain_final and plain_final["ape_se3"]["rmse_m"] < 0.05


def test_loop_closure_without_a_revisit_leaves_the_estimate_and_reports(
    first_run: tuple[Path, Path],
) -> None:
    """``--loop`` on 4 s that revisit nothing: the same estimate to the last digit, every
    keyframe in the pose graph's file, the counts in loop.json, the graph's worker stopped."""
    out, plain = first_run
    result = runner.invoke(app, ["vio", "room_easy", "--duration", "4", "--no-video", "--loop",
                                 "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    run_dir = Path(result.stdout.strip().splitlines()[-1])
    assert read_run_status(run_dir) == "complete"
    assert (run_dir / "estimate.tum").read_text() == (plain / "estimate.tum").read_text()
    loop = json.loads((run_dir / "loop.json").read_text())
    keyframes = (run_dir / "keyframes.tum").read_text().splitlines()
    assert loop["keyframes"] == len(keyframes) > 3 and loop["accepted"] == 0
    assert loop["undescribed"] == 0 and loop["graph_failures"] == 0
    assert (run_dir / "keyframes_loop.tum").read_text().splitlines() == keyframes
    # judged against the truth: nothing accepted, so no precision; the figure and the section
    m = json.loads((run_dir / "metrics.json").read_text())
    assert m["loop_accepted"] == 0 and m["loop_precision"].startswith("n/a")
    assert m["loop_keyframes_ape_rmse_before_m"] == m["loop_keyframes_ape_rmse_after_m"] < 0.05
    assert (run_dir / "plots" / "loop_graph.png").is_file()
    assert "Loop closure" in (run_dir / "report.html").read_text()
    # the final trajectory through the pose graph's keyframes: with no loop, the window's
    final, plain_final = (read_tum(d / "estimate_final.tum") for d in (run_dir, plain))
    assert final.t_ns.tolist() == plain_final.t_ns.tolist()
    assert np.allclose(final.p_W_B, plain_final.p_W_B, atol=1e-6)
    # with --final-ba the loop closer's run is smoothed whole, through it
    result = runner.invoke(app, ["vio", "room_easy", "--duration", "4", "--no-video", "--loop",
                                 "--final-ba", "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    fin = json.loads((Path(result.stdout.strip().splitlines()[-1]) / "metrics.json").read_text())
    sm = fin["final"]["smoothing"]
    assert sm["segments"] == 1 and sm["failed"] == 0 and sm["loops"] == 0
    assert sm["error_after"] < sm["error_before"] and fin["final"]["ape_se3"]["rmse_m"] < 0.05


def test_a_map_saved_by_one_run_is_where_the_next_reports(
    first_run: tuple[Path, Path], tmp_path: Path
) -> None:
    """``--save-map`` writes the run's keyframes; ``--load-map`` starts the next run on them:
    over the same images it is recognised within its first keyframes and joined."""
    out, _ = first_run
    folder = tmp_path / "map"
    base = ["vio", "room_easy", "--duration", "4", "--no-video", "--out", str(out)]
    result = runner.invoke(app, [*base, "--save-map", str(folder)])
    assert result.exit_code == 0, result.output
    saved = json.loads((folder / "map.json").read_text())
    first = Path(result.stdout.strip().splitlines()[-1])
    assert (
        json.loads((first / "loop.json").read_text())["map_saved_keyframes"]
        == saved["keyframes"]
        > 3
    )
    result = runner.invoke(app, [*base, "--load-map", str(folder)])
    assert result.exit_code == 0, result.output
    second = json.loads((Path(result.stdout.strip().splitlines()[-1]) / "loop.json").read_text())
    assert second["map_keyframes"] == saved["keyframes"]
    assert second["joins"] and second["joins"][0]["how"] == "relocalized", second["joins"]


def test_a_blackout_withholds_the_images_and_starts_a_segment(
    first_run: tuple[Path, Path], tmp_path: Path
) -> None:
    """``--blackout 2.5:0.6``: no image from 2.5 s to 3.1 s after the first (the IMU goes on);
    loop closure sees the gap, starts a segment and says when it relocalized (if it did)."""
    out, _ = first_run
    base = ["vio", "room_easy", "--duration", "4", "--no-video", "--out", str(out)]
    result = runner.invoke(app, [*base, "--loop", "--blackout", "2.5:0.6"])
    assert result.exit_code == 0, result.output
    run_dir = Path(result.stdout.strip().splitlines()[-1])
    loop = json.loads((run_dir / "loop.json").read_text())
    assert loop["blackout"]["start_s"] == 2.5 and abs(loop["blackout"]["end_s"] - 3.1) < 1e-9
    assert loop["segments"] == 2
    events = [json.loads(x) for x in (run_dir / "events.jsonl").read_text().splitlines()]
    gap = [e for e in events if e["kind"] == "image_gap"]
    assert len(gap) == 1 and 3.1 <= gap[0]["t_s"] < 3.2, gap


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["/no/such/folder"], "DATASET '/no/such/folder': no such file or folder"),
        (["room_eazy"], "DATASET 'room_eazy'"),
        (["room_easy", "--set", "window_size=3"], "window_size: unknown key"),
        (["room_easy", "--set", "window_keyframes=1"], "window_keyframes"),
        (["room_easy", "--seeds", "4-1"], "--seeds '4-1'"),
        (["room_easy", "--seeds", "0-100000000"], "--seeds '0-100000000': at most 10,000 seeds"),
        (["room_easy", "--duration", "-1"], "--duration must be"),
        (["room_easy", "--rig", "nope"], "--rig"),
        (["room_easy", "--config", "/no/vio.yaml"], "--config /no/vio.yaml"),
        (["room_easy", "--calibration", "/no/cam.yaml"], "--calibration /no/cam.yaml"),
        (["room_easy", "--load-map", "/no/map"], "--load-map /no/map: no such folder"),
        (["room_easy", "--seeds", "0-1", "--save-map", "/no/map"], "one run saves one map"),
        (["room_easy", "--blackout", "20"], "--blackout '20': give START:SECONDS"),
        (["room_easy", "--blackout", "20:-3"], "--blackout's length"),
        (["room_easy", "--loop-set", "nope=1"], "--loop-set nope: unknown key"),
        (["room_easy", "--load-map", ".", "--final-ba"], "--final-ba: not with --load-map"),
    ],
)
def test_bad_input_is_one_line_naming_the_option(
    args: list[str], message: str, tmp_path: Path
) -> None:
    result = runner.invoke(app, ["vio", *args, "--out", str(tmp_path)])
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], result.stderr
    assert "Traceback" not in result.output
    assert not (tmp_path / "datasets").exists()  # refused before any rendering


def test_an_unknown_camera_is_named(first_run: tuple[Path, Path], tmp_path: Path) -> None:
    out, _ = first_run
    (made,) = (out / "datasets").iterdir()
    result = runner.invoke(app, ["vio", str(made), "--camera", "cam1", "--out", str(tmp_path)])
    assert result.exit_code == 2
    assert result.stderr.strip() == "error: --camera 'cam1': the dataset's cameras are cam0"


EUROC_MICRO = SHARED / "euroc_micro"


@needs(EUROC_MICRO)
def test_a_full_disk_is_one_error_and_the_run_is_marked_failed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 21, item 8: the disk fills up as the estimate is written. The status file (the
    last one written) cannot be made anew either; it left ``running`` and its own error."""
    real = Path.write_text
    full = {"now": False}

    def write_text(self: Path, *a: Any, **kw: Any) -> int:
        full["now"] = full["now"] or self.name == ".estimate.tum.partial"
        if full["now"]:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
        return real(self, *a, **kw)

    real_open = Path.open

    def open_(self: Path, mode: str = "r", *a: Any, **kw: Any) -> Any:
        if "w" in mode and self.name == ".estimate.tum.partial":  # written a block at a time
            full["now"] = True
        if "w" in mode and full["now"]:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
        return real_open(self, mode, *a, **kw)

    monkeypatch.setattr(Path, "write_text", write_text)
    monkeypatch.setattr(Path, "open", open_)
    result = runner.invoke(
        app, ["vio", str(EUROC_MICRO), "--no-video", "--duration", "1", "--out", str(tmp_path)]
    )
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    (run_dir,) = tmp_path.iterdir()
    assert lines[-2:] == [
        f"error: cannot write {run_dir / 'estimate.tum'}: No space left on device",
        f"partial results (marked failed): {run_dir}",
    ]
    assert not any(line.startswith("error:") for line in lines[:-2])
    assert read_run_status(run_dir) == "failed"


@needs(EUROC_MICRO)
def test_a_run_at_rest_gives_no_drift_in_percent_and_no_unused_cameras_notes(
    tmp_path: Path,
) -> None:
    """Issue 21, item 14: euroc_micro moves 1.4 cm: its drift printed 67 %; and its 4 missing
    cam1 images were noted on a run of cam0."""
    result = runner.invoke(app, ["vio", str(EUROC_MICRO), "--no-video", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    notes = [ln for ln in result.stderr.splitlines() if ln.startswith("note:")]
    assert "note: drift final (%) n/a: the ground truth travels 0.014 m, under the 1 m" in notes[0]
    assert not any("missing images" in n or "cam1" in n for n in notes), notes
    (row,) = [ln for ln in result.stdout.splitlines() if ln.startswith("│")]
    cells = [c.strip() for c in row.strip("│").split("│")]
    # drift final and RPE (%), after ATE, the final trajectory's APE and the final error
    assert cells[3:5] == ["n/a", "n/a"]


def test_an_out_that_is_a_file_is_named(tmp_path: Path) -> None:
    """Issue 21, item 5's twin: ``--out`` naming a file."""
    (tmp_path / "file").write_text("x")
    result = runner.invoke(app, ["vio", "room_easy", "--out", str(tmp_path / "file")])
    assert result.exit_code == 2
    assert result.stderr.strip() == f"error: --out {tmp_path / 'file'}: is a file, not a folder"
