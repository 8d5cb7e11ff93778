from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from quadnav.eval.runs import compare_runs, format_table


def folder(root: Path, name: str, metrics: object | None, raw: str | None = None) -> Path:
    d = root / name
    d.mkdir()
    if raw is not None:
        (d / "metrics.json").write_text(raw)
    elif metrics is not None:
        (d / "metrics.json").write_text(json.dumps(metrics))
    return d


def mixed(root: Path) -> list[Path]:
    """One folder of each kind, shaped as each command writes its metrics.json."""
    return [
        folder(root, "p_planar", {"kind": "planar", "summary": {}, "per_seed": [],
               "table": [{"experiment": "handled", "RMSE output (m)": 0.21}]}),
        folder(root, "e_eval", {"kind": "eval", "estimates": {},
               "table": [{"estimate": "orb", "matched": 4541, "APE rmse (m)": 1.30}]}),
        # replay writes no kind and nests one dict per comparison
        folder(root, "r_replay", {"log": "x.ulg", "duration_s": 31.0, "counts": {"gps": 3},
               "quadnav_vs_px4": {"n": 10, "horizontal_rms_m": 0.4, "vertical_rms_m": 0.1},
               "quadnav_vs_truth": {"n": 10, "horizontal_rms_m": 0.3, "vertical_rms_m": 0.2}}),
        folder(root, "m_markers", {"kind": "markers", "frames": 1086, "frames_with_pose": 1040,
               "reprojection_rms_px": 0.42, "detector": "aruco"}),
        folder(root, "n_run", {"kind": "nav", "summary": {}, "table": [{"scenario": "indoor",
               "NEES (15)": 14.2}]}),
        folder(root, "s_sim", {"kind": "sim", "peak_thrust_n": 20.0,
               "table": [{"scenario": "hover", "settling (s)": 2.5}]}),
        folder(root, "x_empty", None),
        folder(root, "y_broken", None, raw="{not json"),
    ]  # fmt: skip


def test_a_mix_of_run_kinds_gives_each_its_own_metrics(tmp_path: Path) -> None:
    rows = compare_runs(mixed(tmp_path))
    by_run: dict[str, list] = {}
    for r in rows:
        by_run.setdefault(r.run, []).append(r)
    assert [r.kind for r in rows[:2]] == ["planar", "eval"]
    assert by_run["e_eval"][0].cells["APE rmse (m)"] == 1.30
    replay = by_run["r_replay"]
    assert [r.kind for r in replay] == ["replay", "replay"]
    assert [r.cells["pair"] for r in replay] == ["quadnav vs px4", "quadnav vs truth"]
    assert replay[1].cells["horizontal_rms_m"] == 0.3
    (markers,) = by_run["m_markers"]
    assert markers.kind == "markers" and markers.cells["reprojection_rms_px"] == 0.42
    assert markers.cells["detector"] == "aruco"
    assert by_run["s_sim"][0].cells == {"scenario": "hover", "settling (s)": 2.5}
    assert by_run["x_empty"][0].note == "no metrics.json"
    assert by_run["y_broken"][0].note.startswith("metrics.json unreadable")


def test_markdown_has_a_table_per_kind_and_csv_one_table(tmp_path: Path) -> None:
    rows = compare_runs(mixed(tmp_path))
    md = format_table(rows, "markdown")
    blocks = md.split("\n\n")
    assert blocks[0] == "planar:"
    assert blocks[1].splitlines()[0] == "| run | experiment | RMSE output (m) |"
    markers = blocks[blocks.index("markers:") + 1].splitlines()
    assert markers[0] == "| run | frames | frames_with_pose | reprojection_rms_px | detector |"
    assert markers[2] == "| m_markers | 1086 | 1040 | 0.42 | aruco |"
    tail = blocks[blocks.index("without metrics:") + 1]
    assert "| x_empty |  | no metrics.json |" in tail
    table = list(csv.reader(io.StringIO(format_table(rows, "csv"))))
    assert table[0][:3] == ["run", "kind", "note"]
    assert len(table) == 1 + 9  # header; planar, eval, 2 replay pairs, markers, run, sim, 2 notes
    assert all(len(r) == len(table[0]) for r in table)
