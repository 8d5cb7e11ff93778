"""``--seeds`` ranges: parsed in one place for every command, bounded, never listed before the
bound is checked (issue 21, item 6)."""

from __future__ import annotations

import threading
import time
import tracemalloc

import pytest

from quadnav.errors import ConfigError
from quadnav.experiments.seeds import MAX_SEED, MAX_SEEDS, parse_seeds


def test_ranges_and_lists_up_to_the_bound_are_parsed() -> None:
    assert parse_seeds("0-4") == (0, 1, 2, 3, 4)
    assert parse_seeds(" 7 , 2-3") == (7, 2, 3)
    assert len(parse_seeds(f"1-{MAX_SEEDS}")) == MAX_SEEDS
    assert parse_seeds(str(MAX_SEED)) == (MAX_SEED,)


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("0-10000", "at most 10,000 seeds"),  # 10,001 seeds: one over
        ("0-5000,6000-11000", "at most 10,000 seeds"),  # over only counted together
        (f"0-{MAX_SEED}", "at most 10,000 seeds"),
        (f"{MAX_SEED + 1}", "at most 4,294,967,295"),
        ("9" * 5000, "at most 4,294,967,295"),  # no int() of 5,000 digits (Python refuses it)
        ("4-1", "goes down"),
        ("1,1", "named twice"),
        ("a", "give seeds as"),
    ],
)
def test_a_bad_seed_list_is_one_line_naming_the_option(text: str, fragment: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_seeds(text)
    message = str(err.value)
    assert message.startswith("--seeds ") and fragment in message and "\n" not in message
    assert len(message) < 120  # a long argument is shortened, not echoed whole


def test_a_huge_range_is_refused_at_once_without_building_it() -> None:
    """The issue's ``0-100000000`` took 10 GB: the bound is checked on the range's ends."""
    tracemalloc.start()
    start = time.perf_counter()
    try:
        with pytest.raises(ConfigError, match="at most 10,000 seeds"):
            parse_seeds("0-100000000")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000 and time.perf_counter() - start < 1.0


def _slow_task(seconds: float) -> float:
    time.sleep(seconds)
    return seconds


def test_a_stopped_pool_leaves_nothing_for_the_exit_hook_to_wake() -> None:
    """After a Ctrl-C the pool is ended at once, its manager thread has ended and is off the
    list that concurrent.futures' exit hook writes to (the hook's write to a pipe the thread had
    closed printed a 'Bad file descriptor' traceback under load). The pool's thread was read
    after shutdown() had cleared it until session 21, so none of this happened."""
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures import process as futures_process

    from quadnav.experiments.seeds import _terminate

    pool = ProcessPoolExecutor(max_workers=2)
    futures = [pool.submit(_slow_task, 5.0) for _ in range(4)]
    time.sleep(0.5)  # (the workers have started the first two)
    manager: threading.Thread | None = getattr(pool, "_executor_manager_thread", None)
    assert manager is not None and manager in futures_process._threads_wakeups
    t0 = time.monotonic()
    _terminate(pool)
    assert time.monotonic() - t0 < 4.0  # the running tasks were ended, not waited for
    assert not manager.is_alive()
    assert manager not in futures_process._threads_wakeups
    assert all(f.cancelled() or f.done() for f in futures[2:])
