"""Ctrl-C for the tests: a quadnav command as a child that SIGINT stops, and waiting for the
lines a run folder's file gets as the run goes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

QUADNAV = [sys.executable, "-m", "quadnav"]


def start_interruptible(args: list[str]) -> subprocess.Popen[str]:
    """``quadnav *args`` as a child process whose SIGINT acts as Ctrl-C."""
    return subprocess.Popen(
        [*QUADNAV, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "COLUMNS": "120"},
        # A shell's background job ignores SIGINT and its children inherit that: restore it.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def wait_for_lines(root: Path, pattern: str, n: int, timeout_s: float) -> Path:
    """The first file under ``root`` matching ``pattern`` with at least ``n`` lines."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        for f in root.glob(pattern):
            if f.is_file() and f.read_text().count("\n") >= n:
                return f
        time.sleep(0.05)
    raise AssertionError(f"no {root}/{pattern} with {n} lines within {timeout_s} s")
