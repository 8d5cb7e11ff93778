"""Running the seeds of a Monte Carlo study, in this process or in a pool of processes.

Ctrl-C stops a study cleanly: the workers ignore the interrupt (no traceback from each of them),
the parent terminates them, and every result delivered before the interrupt has already been
handed to the caller, who keeps it (an append-only ``seeds.jsonl`` in the run folder).
"""

from __future__ import annotations

import signal
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

__all__ = ["run_tasks"]

T = TypeVar("T")


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _terminate(pool: ProcessPoolExecutor) -> None:
    """Stop a pool at once: cancel what has not started, end the workers that have."""
    # ProcessPoolExecutor has no public way to end running workers; each is a Process.
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        proc.terminate()
    for proc in procs:
        proc.join(timeout=5)


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
