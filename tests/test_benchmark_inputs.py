"""The benchmarks take bad input as the CLI does: one line naming the option or path, exit
code 2, no traceback (issue 21, item 14: ``benchmarks/vio.py`` with a missing dataset)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _refused(script: str, args: list[str]) -> str:
    """``benchmarks/SCRIPT ARGS``'s error output, once it has exited with code 2 (bad input)."""
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / script), *args],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    return done.stderr


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
    stderr = _refused("vio.py", args)
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--keyframes", "0"], "error: --keyframes must be at least 1, got 0"),
        (["--views", "1"], "error: --views must be at least 2, got 1"),
        (["--seeds", "-1"], "error: --seeds must be at least 0, got -1"),
    ],
)
def test_place_benchmark_refuses_bad_input_in_one_line(args: list[str], message: str) -> None:
    stderr = _refused("place.py", args)
    assert stderr.strip().splitlines() == [message], stderr


def test_posegraph_benchmark_refuses_bad_repeats_in_one_line() -> None:
    stderr = _refused("posegraph.py", ["--repeats", "0"])
    assert stderr.strip() == "error: --repeats must be at least 1, got 0"


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
    stderr = _refused("loop.py", args)
    assert stderr.strip().splitlines() == [message], stderr


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
    stderr = _refused("slam.py", args)
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), stderr


@pytest.mark.parametrize(
    ("script", "args", "message"),
    [
        ("vio_peer", ["/no/such/dataset"], "error: DATASET /no/such/dataset: no groundtruth.tum"),
        ("vio_peer", [".", "--systems", "vins"], "error: --systems 'vins': choose among"),
        ("vio_peer", [".", "--repeats", "0"], "error: --repeats must be at least 1, got 0"),
        ("slam_peer", ["/no/such/dataset"], "error: DATASET /no/such/dataset: no groundtruth.tum"),
        ("slam_peer", [".", "--systems", "orb_mono"], "error: --systems 'orb_mono': choose among"),
        ("slam_peer", [".", "--quadnav-repeats", "0"],
         "error: --quadnav-repeats must be at least 1, got 0"),
    ],
)  # fmt: skip
def test_peer_benchmarks_refuse_bad_input_in_one_line(
    script: str, args: list[str], message: str
) -> None:
    stderr = _refused(f"{script}.py", args)
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--flights", "0"], "error: --flights must be at least 1, got 0"),
        (["--jobs", "0"], "error: --jobs must be at least 1, got 0"),
        (["--flight-s", "2"], "error: --flight-s must be in (3.5, 3600], got 2"),
    ],
)
def test_sweep_benchmark_refuses_bad_input_in_one_line(args: list[str], message: str) -> None:
    stderr = _refused("sweep.py", args)
    assert stderr.strip().splitlines() == [message], stderr
