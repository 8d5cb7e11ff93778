"""``benchmarks/vio_memory.py``'s pure parts (issue 22, item 9): reading ``/proc`` and the
child's result line, the whole-process peak across the reset, the growth slope, the ratios, the
table (numbers or ``n/a``, never ``nan``), the JSON it writes, and its bad input in one line.
No test runs the VIO."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from tests.script_module import load_script

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "vio_memory.py"


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    return load_script(SCRIPT)


def _child(minutes: float, setup_peak: int, run_peak: int, dataset: int) -> dict[str, object]:
    per_min = 50 if minutes > 10 else 0  # kB a minute of run: the long run leaks a little
    samples = [(k * 1200, 60.0 * k, 250_000 + per_min * k) for k in range(int(minutes) + 1)]
    return {
        "minutes": minutes, "frames": int(1200 * minutes), "frames_with_estimate": 1190,
        "failures": 0, "reinitializations": 0, "ape_se3_m": 0.0612, "setup_s": 3.0,
        "run_s": 60.0, "frames_per_s": 35.2, "peak_reset": True, "samples": samples,
        "rss_kb": {"imports": 160_000, "setup_peak": setup_peak, "dataset": dataset,
                   "run_peak": run_peak, "final": run_peak},
    }  # fmt: skip


def test_proc_status_and_the_childs_result_line(bench: ModuleType) -> None:
    status = "Name:\tpython\nVmHWM:\t  426252 kB\nVmRSS:\t  221296 kB\nThreads:\t1\n"
    assert bench.proc_status_kb(status) == {"VmHWM": 426252, "VmRSS": 221296}
    out = "progress 10%\n" + bench.RESULT_TAG + json.dumps({"minutes": 3}) + "\nbye\n"
    assert bench.parse_child_output(out) == {"minutes": 3}
    with pytest.raises(ValueError, match="no result line"):
        bench.parse_child_output("Traceback ...\n")


def test_whole_process_peak_counts_the_setup_before_the_reset(bench: ModuleType) -> None:
    child = _child(3, setup_peak=430_000, run_peak=280_000, dataset=220_000)
    # ru_maxrss after the reset is the run's peak: the set-up's, higher, is the process's
    assert bench.whole_process_peak_kb(child, 281_000) == 430_000
    assert bench.whole_process_peak_kb(child, 500_000) == 500_000


def test_growth_is_the_slope_after_the_first_minute(bench: ModuleType) -> None:
    samples = [(0, 0.0, 999_999)] + [(k, 60.0 * k, 200_000 + 40 * k) for k in range(1, 31)]
    assert bench.growth_kb_per_min(samples) == pytest.approx(40.0)
    assert bench.growth_kb_per_min(samples[:3]) is None  # two samples after the first minute


def test_ratios_table_and_json(
    bench: ModuleType, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    runs = {
        3.0: _child(3, setup_peak=430_000, run_peak=280_000, dataset=220_000),
        30.0: _child(30, setup_peak=600_000, run_peak=308_000, dataset=260_000),
    }
    r = bench.ratios(runs[3.0] | {"whole_process_peak_kb": 430_000},
                     runs[30.0] | {"whole_process_peak_kb": 600_000})  # fmt: skip
    assert r["run_peak"] == pytest.approx(1.1) and r["whole_process_peak"] == pytest.approx(
        600 / 430
    )
    assert bench.ratios({"minutes": 3, "error": "n/a: exit 1"}, runs[30.0]) == {
        "whole_process_peak": "n/a: a run failed"
    }
    failed = {"minutes": 30.0, "error": "n/a: the run failed (exit -9)"}
    lines = bench.table([runs[3.0] | {"whole_process_peak_kb": 430_000}, failed])
    assert lines[2].split()[:5] == ["3", "3600", "1190", "0", "0.061"]
    assert lines[3].split()[1:3] == ["n/a:", "the"] and not any("nan" in ln for ln in lines)

    def fake_child(args: object, minutes: float) -> dict[str, object]:
        return runs[minutes] | {"whole_process_peak_kb": runs[minutes]["rss_kb"]["setup_peak"]}  # type: ignore[index]

    out = tmp_path / "vio_memory.json"
    monkeypatch.setattr(bench, "_run_child", fake_child)
    monkeypatch.setattr(bench, "_pin", lambda core: None)
    monkeypatch.setattr(sys, "argv", ["vio_memory.py", "--minutes", "30", "3", "--out", str(out)])
    bench.main()
    doc = json.loads(out.read_text())
    assert [run["minutes"] for run in doc["runs"]] == [3, 30]  # shortest first
    assert doc["ratios_longest_over_shortest"]["run_peak"] == pytest.approx(1.1)
    assert doc["sensors"] == "ideal" and doc["sequence"] == "room_easy"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--minutes", "45"], "error: --minutes 45: from 0.5 to 30"),
        (["--sequence", "moon"], "error: --sequence 'moon': one of room_easy"),
        (["--every", "0"], "error: --every must be at least 1, got 0"),
        (["--scale", "2"], "error: --scale 2: from 0.25 to 1"),
        (["--core", "9999"], "error: --core 9999: not one of this machine's cores"),
    ],
)
def test_bad_input_is_one_line(args: list[str], message: str) -> None:
    done = subprocess.run(
        [sys.executable, str(SCRIPT), *args], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), done.stderr


def test_the_slam_maps_size_is_a_line_under_the_table(bench: ModuleType) -> None:
    run = _child(30, setup_peak=600_000, run_peak=308_000, dataset=260_000)
    run |= {"whole_process_peak_kb": 600_000,
            "map": {"keyframes": 400, "good_keyframes": 390, "points": 50_000, "nbytes": 49_000_000}}  # fmt: skip
    vio = _child(3, setup_peak=1, run_peak=1, dataset=1) | {"map": None, "whole_process_peak_kb": 1}
    lines = bench.table([run, vio])
    assert len(lines) == 5  # (the head, its rule, two runs, one map)
    assert lines[-1] == (
        "30 min: the map at the end 400 keyframes (390 not culled), 50000 points, its arrays "
        "49.0 MB (122.5 kB a keyframe)"
    )
