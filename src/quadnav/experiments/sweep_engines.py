"""Where a sweep's tasks run: this machine's process pool (:func:`~quadnav.experiments.seeds.
run_tasks`, in chunks so that a million tasks are never a million futures), or Dask
distributed: a scheduler given by address, or a ``LocalCluster`` started here on loopback.

Dask is the install extra ``quadnav[sweep]``; without it, asking for it is a one-line error
naming the option and the extra. Neither engine schedules anything itself: the pool's
executor and Dask's scheduler do.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from quadnav.errors import ConfigError
from quadnav.experiments.seeds import run_tasks
from quadnav.experiments.sweep_tasks import TaskOutcome, execute_task, one_line

__all__ = ["LOCAL_CHUNK", "SweepEngine", "check_engine", "run_engine"]

#: Tasks handed to the process pool at a time (a pool per chunk; each task is seconds).
LOCAL_CHUNK = 2_000
#: Tasks in flight on Dask per worker thread (the rest are submitted as these finish).
DASK_WINDOW_PER_THREAD = 4
#: The most workers ``--local-cluster`` starts on this machine.
MAX_LOCAL_CLUSTER = 256

#: One task as the engines pass it: (kind name, validated configuration, seed).
Task = tuple[str, Any, int]
OnResult = Callable[[int, TaskOutcome], None]


@dataclass(frozen=True, slots=True, kw_only=True)
class SweepEngine:
    """``jobs`` processes here (the default), or Dask: ``scheduler`` (``tcp://HOST:8786``)
    or ``local_cluster`` workers started on 127.0.0.1, one thread each."""

    jobs: int = 1
    scheduler: str | None = None
    local_cluster: int | None = None

    @property
    def option(self) -> str:
        return "--scheduler" if self.scheduler else "--local-cluster"

    @property
    def uses_dask(self) -> bool:
        return self.scheduler is not None or self.local_cluster is not None

    def describe(self) -> str:
        if self.scheduler:
            return f"Dask scheduler {self.scheduler}"
        if self.local_cluster:
            return f"Dask LocalCluster of {self.local_cluster} worker(s) on 127.0.0.1"
        return f"a local pool of {self.jobs} process(es)"


def check_engine(engine: SweepEngine) -> None:
    """Refuse an engine that cannot start, before anything runs."""
    if engine.scheduler is not None and engine.local_cluster is not None:
        raise ConfigError("--scheduler and --local-cluster: give one of them")
    if engine.jobs < 1:
        raise ConfigError(f"--jobs {engine.jobs}: at least 1")
    if engine.local_cluster is not None and not 1 <= engine.local_cluster <= MAX_LOCAL_CLUSTER:
        raise ConfigError(
            f"--local-cluster {engine.local_cluster}: 1 to {MAX_LOCAL_CLUSTER} workers"
        )
    if engine.scheduler is not None and not engine.scheduler.startswith(("tcp://", "tls://")):
        raise ConfigError(f"--scheduler {engine.scheduler}: give tcp://HOST:8786")
    if engine.uses_dask and importlib.util.find_spec("distributed") is None:
        raise ConfigError(f"{engine.option} needs Dask distributed: pip install 'quadnav[sweep]'")


def run_engine(engine: SweepEngine, tasks: Sequence[Task], on_result: OnResult) -> None:
    """Run every task; ``on_result(index, outcome)`` in this process as each finishes."""
    if engine.uses_dask:
        _run_dask(engine, tasks, on_result)
        return
    for start in range(0, len(tasks), LOCAL_CHUNK):
        chunk = tasks[start : start + LOCAL_CHUNK]

        def collect(i: int, outcome: TaskOutcome, start: int = start) -> None:
            on_result(start + i, outcome)

        run_tasks(execute_task, chunk, collect, jobs=engine.jobs)


def _client(engine: SweepEngine) -> tuple[Any, Any]:
    """A Dask client and the cluster started for it (None with a scheduler's address)."""
    dd = importlib.import_module("distributed")  # (untyped: its names are Any here)

    if engine.local_cluster is not None:
        cluster = dd.LocalCluster(
            n_workers=engine.local_cluster,
            threads_per_worker=1,
            host="127.0.0.1",
            dashboard_address=None,  # no dashboard: nothing listens beyond the workers
            processes=True,
        )
        return dd.Client(cluster), cluster
    try:
        return dd.Client(engine.scheduler, timeout="20s"), None
    except (OSError, TimeoutError) as exc:
        raise ConfigError(
            f"--scheduler {engine.scheduler}: cannot connect ({one_line(exc)})"
        ) from None


def _run_dask(engine: SweepEngine, tasks: Sequence[Task], on_result: OnResult) -> None:
    """Submit a window of tasks, and one more as each finishes; a task whose worker died is
    a failed task, as a task that raised is."""
    as_completed = importlib.import_module("distributed").as_completed
    client, cluster = _client(engine)
    futures: dict[Any, int] = {}
    try:
        threads = sum(client.nthreads().values()) or 1
        pending = iter(enumerate(tasks))

        def submit() -> Any | None:
            nxt = next(pending, None)
            if nxt is None:
                return None
            fut = client.submit(execute_task, *nxt[1], pure=False)
            futures[fut] = nxt[0]
            return fut

        first = [f for f in (submit() for _ in range(threads * DASK_WINDOW_PER_THREAD)) if f]
        done = as_completed(first)
        for fut in done:
            index = futures.pop(fut)
            try:
                outcome = fut.result()
            except Exception as exc:  # the worker died or the task could not be sent
                outcome = TaskOutcome(status="failed", wall_s=0.0, error=one_line(exc))
            on_result(index, outcome)
            fut.release()
            if (nxt := submit()) is not None:
                done.add(nxt)
    finally:
        if futures:
            client.cancel(list(futures))
        client.close()
        if cluster is not None:
            cluster.close()
