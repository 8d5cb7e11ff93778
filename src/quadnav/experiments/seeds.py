"""The seeds of a Monte Carlo study: ``--seeds`` ranges parsed (bounded), and the seeds run in
this process or in a pool of processes.

Ctrl-C stops a study cleanly: the workers ignore the interrupt (no traceback from each of them),
the parent terminates them, and every result delivered before the interrupt has already been
handed to the caller, who keeps it (an append-only ``seeds.jsonl`` in the run folder).
"""

from __future__ import annotations

import re
import signal
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

from quadnav.errors import ConfigError

__all__ = ["MAX_SEED", "MAX_SEEDS", "parse_seeds", "run_tasks"]

T = TypeVar("T")

#: The most seeds one ``--seeds`` may name (a study of more is not run from one command line).
MAX_SEEDS = 10_000
#: The largest seed (an unsigned 32-bit integer, what every generator takes).
MAX_SEED = 2**32 - 1
_PART = re.compile(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?")


def parse_seeds(text: str, option: str = "--seeds") -> tuple[int, ...]:
    """``--seeds``: ``0-4``, ``0,2,7`` or ``3``, each in ``[0, MAX_SEED]``, at most
    ``MAX_SEEDS`` of them, none twice. The count is checked from the ranges' bounds before any
    seed is listed, so ``0-100000000`` is refused at once, not after building it."""
    shown = f"{option} {text if len(text) <= 40 else text[:37] + '...'!r}"
    bounds: list[tuple[int, int]] = []
    total = 0
    for part in text.split(","):
        m = _PART.fullmatch(part)
        if m is None:
            raise ConfigError(f"{shown}: give seeds as 0-4, 0,2,7 or 3")
        ends = [g for g in m.groups() if g is not None]
        if any(len(g) > len(str(MAX_SEED)) or int(g) > MAX_SEED for g in ends):
            raise ConfigError(f"{shown}: a seed must be at most {MAX_SEED:,}")
        lo, hi = int(ends[0]), int(ends[-1])
        if hi < lo:
            raise ConfigError(f"{shown}: the range {lo}-{hi} goes down")
        total += hi - lo + 1
        if total > MAX_SEEDS:
            raise ConfigError(f"{shown}: at most {MAX_SEEDS:,} seeds in one study")
        bounds.append((lo, hi))
    seeds = [s for lo, hi in bounds for s in range(lo, hi + 1)]
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"{shown}: a seed is named twice")
    return tuple(seeds)


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _terminate(pool: ProcessPoolExecutor) -> None:
    """Stop a pool at once: cancel what has not started, end the workers that have."""
    # ProcessPoolExecutor has no public way to end running workers; each is a Process.
    procs = list((getattr(pool, "_processes", None) or {}).values())
    # (read before shutdown(), which sets the pool's thread to None: read after, as it was
    # until session 21, nothing below ran and the race stayed open)
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        proc.terminate()
    for proc in procs:
        proc.join(timeout=5)
    # Its manager thread closes the pool's wake-up pipe as it ends; let it end now, and take it
    # off the list the interpreter's exit hook wakes (that hook writes to the pipe: under load
    # the two raced, "Bad file descriptor" and a traceback after a Ctrl-C).
    if manager is not None:
        manager.join(timeout=5)
        from concurrent.futures import process as futures_process

        getattr(futures_process, "_threads_wakeups", {}).pop(manager, None)


def run_tasks(
    fn: Callable[..., T],
    tasks: Sequence[tuple[Any, ...]],
    on_result: Callable[[int, T], None],
    *,
    jobs: int = 1,
) -> None:
    """Call ``fn(*task)`` for every task and ``on_result(index, result)`` as each finishes
    (in order with ``jobs`` = 1, in finishing order otherwise)."""
    if jobs <= 1 or len(tasks) <= 1:
        for i, task in enumerate(tasks):
            on_result(i, fn(*task))
        return
    pool = ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), initializer=_ignore_sigint)
    try:
        futures: dict[Future[T], int] = {pool.submit(fn, *task): i for i, task in enumerate(tasks)}
        for fut in as_completed(futures):
            on_result(futures[fut], fut.result())
    except BaseException:
        _terminate(pool)
        raise
    pool.shutdown()
