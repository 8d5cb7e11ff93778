"""Pinning a benchmark to one core before numpy, OpenCV or GTSAM load (their thread pools size
themselves from the affinity mask they see, and child processes inherit it), and the one-line
error of a bad option. Imports only ``os`` and ``sys``: import it first."""

from __future__ import annotations

import os
import sys

__all__ = ["fail", "pin_to_core"]


def fail(message: str) -> None:
    """A bad input: one line naming the option or path, exit code 2 (as the CLI does)."""
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def pin_to_core(argv: list[str]) -> int:
    """Pin this process to the core given by ``--core`` in ``argv`` (default: the one core it
    was started on, as a benchmark's child is, else 0), set the BLAS and OpenMP pools to one
    thread, and return the core."""
    inherited = sorted(os.sched_getaffinity(0))
    default = str(inherited[0]) if len(inherited) == 1 else "0"
    arg = argv[argv.index("--core") + 1] if "--core" in argv[:-1] else default
    try:
        core = int(arg)
        os.sched_setaffinity(0, {core})
    except (ValueError, OSError):
        fail(f"--core {arg}: not one of this machine's cores {sorted(os.sched_getaffinity(0))}")
    for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[v] = "1"
    return core
