"""The benchmarks take bad input as the CLI does: one line naming the option or path, exit
code 2, no traceback (issue 21, item 14: ``benchmarks/vio.py`` with a missing dataset)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["/no/such/dataset"], "error: DATASET /no/such/dataset: no such file or folder"),
        (["--core", "9999"], "error: --core 9999: not one of this machine's cores"),
        (["--core", "x"], "error: --core x:"),
        (["--frames", "0"], "error: --frames must be at least 1, got 0"),
    ],
)
def test_vio_benchmark_refuses_bad_input_in_one_line(args: list[str], message: str) -> None:
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "vio.py"), *args],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), done.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--keyframes", "0"], "error: --keyframes must be at least 1, got 0"),
        (["--views", "1"], "error: --views must be at least 2, got 1"),
        (["--seeds", "-1"], "error: --seeds must be at least 0, got -1"),
    ],
)
def test_place_benchmark_refuses_bad_input_in_one_line(args: list[str], message: str) -> None:
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "place.py"), *args],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [message], done.stderr


def test_posegraph_benchmark_refuses_bad_repeats_in_one_line() -> None:
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "posegraph.py"), "--repeats", "0"],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == "error: --repeats must be at least 1, got 0"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["/no/such/dataset"], "error: DATASET /no/such/dataset: no such file or folder"),
        ([".", "--map", "/no/such/map"], "error: --map /no/such/map: no such folder"),
        ([".", "--repeats", "0"], "error: --repeats must be at least 1, got 0"),
        ([".", "--keyframes", "0"], "error: --keyframes must be at least 1, got 0"),
        ([".", "--minutes", "0"], "error: --minutes must be in (0, 600], got 0.0"),
        ([".", "--skip-runs"], "error: --skip-runs needs --map and --keyframes-per-s"),
        ([".", "--keyframes-per-s", "0"], "error: --keyframes-per-s must be in (0, 1000], got 0.0"),
    ],
)
def test_loop_benchmark_refuses_bad_input_in_one_line(args: list[str], message: str) -> None:
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "loop.py"), *args],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [message], done.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--repeats", "0"], "error: --repeats must be at least 1, got 0"),
        (["--frames", "-1"], "error: --frames must be at least 0, got -1"),
        (["--core", "9999"], "error: --core 9999: not one of this machine's cores"),
        (["--before", "/tmp"], "error: --before /tmp: not a quadnav src/ folder"),
        (["--zed", "/no/such/dataset"], "error: --zed /no/such/dataset: not an EuRoC folder"),
    ],
)
def test_slam_benchmark_refuses_bad_input_in_one_line(args: list[str], message: str) -> None:
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "slam.py"), *args],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), done.stderr
