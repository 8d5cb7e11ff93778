"""What one task of a sweep does: a registry of task kinds.

A task kind builds a validated configuration from a scenario and ``--set`` overrides (the
parent builds every grid point's before anything runs), and runs one seed of it, returning
flat metrics (a number or an ``"n/a: why"`` text per name). :func:`execute_task` runs a task
where the engine puts it (this process, a pool's worker, a Dask worker) by the kind's name:
it never raises for a task's own failure, which it returns as a one-line error.

``nav`` (``quadnav run``'s scenarios) is the one kind so far; the other commands' runs
(planar, sim, vio, slam) become kinds by :func:`register_task_kind`, the engine unchanged.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from quadnav.config_model import ConfigModel
from quadnav.errors import ConfigError
from quadnav.eval.na import Metric, na

__all__ = [
    "TASK_KINDS",
    "TaskKind",
    "TaskOutcome",
    "execute_task",
    "flat_metrics",
    "nav_task_config",
    "register_task_kind",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class TaskKind:
    """A kind of task: ``build(scenario, overrides)`` validates a configuration (a
    :class:`~quadnav.errors.QuadnavError` naming the key when it cannot), ``run(config,
    seed)`` flies one seed and returns its flat metrics; ``headline`` names the metrics the
    sweep's plots and report show (every metric is in its table)."""

    name: str
    description: str
    build: Callable[[str, Sequence[str]], ConfigModel]
    run: Callable[[Any, int], Mapping[str, Metric]]
    headline: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True, kw_only=True)
class TaskOutcome:
    """What one task gave: ``ok`` with its metrics, or ``failed`` with a one-line error."""

    status: Literal["ok", "failed"]
    wall_s: float
    error: str = ""
    metrics: dict[str, Metric] = field(default_factory=dict)


#: Every kind of task by name.
TASK_KINDS: dict[str, TaskKind] = {}


def register_task_kind(kind: TaskKind) -> None:
    """Add (or replace) a kind. A kind used by a process pool or Dask must be registered when
    its module is imported, so that a worker finds it by name."""
    TASK_KINDS[kind.name] = kind


def one_line(exc: BaseException) -> str:
    """An exception as one line: its type and the first line of its message, shortened."""
    text = str(exc).strip().splitlines()
    line = f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__
    return line if len(line) <= 300 else line[:297] + "..."


def execute_task(kind: str, config: Any, seed: int) -> TaskOutcome:
    """Run one task; an exception of the task (not an interrupt) is a failed outcome."""
    t0 = time.perf_counter()
    try:
        metrics = TASK_KINDS[kind].run(config, seed)
    except Exception as exc:
        return TaskOutcome(status="failed", wall_s=time.perf_counter() - t0, error=one_line(exc))
    return TaskOutcome(status="ok", wall_s=time.perf_counter() - t0, metrics=dict(metrics))


def _metric(value: object) -> Metric | None:
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, int | float):
        return float(value) if math.isfinite(value) else na("not finite")
    return value if isinstance(value, str) else None


def _worst(values: list[object], none: str) -> Metric:
    """A list of per-event metrics (dropouts) as its worst: a text (never recovered) first."""
    texts = [v for v in values if isinstance(v, str)]
    nums = [float(v) for v in values if isinstance(v, int | float)]
    return texts[0] if texts else max(nums) if nums else na(none)


def _max_name(name: str) -> str:
    """``dropout_end_error_m`` -> ``dropout_end_error_max_m`` (the unit stays last)."""
    stem, _, unit = name.rpartition("_")
    return f"{stem}_max_{unit}" if stem and unit in ("m", "s", "deg") else f"{name}_max"


def flat_metrics(record: Mapping[str, object], *, skip: Sequence[str] = ()) -> dict[str, Metric]:
    """A flight's metrics record as flat names: numbers and texts as they are, a mapping's
    entries as ``name.key``, a list of numbers as its worst (``name`` with ``_max``)."""
    out: dict[str, Metric] = {}
    for name, value in record.items():
        if name in skip:
            continue
        if isinstance(value, Mapping):
            for k, v in value.items():
                m = _metric(v)
                if m is not None:
                    out[f"{name}.{k}"] = m
        elif isinstance(value, list):
            if all(isinstance(v, int | float | str) for v in value):
                out[_max_name(name)] = _worst(value, "none in the flight")
        elif (m := _metric(value)) is not None:
            out[name] = m
    return out


def nav_task_config(scenario: str, overrides: Sequence[str]) -> ConfigModel:
    """A scenario of ``quadnav run`` (a built-in name or a YAML file) with overrides."""
    from quadnav.experiments.nav import NavScenario
    from quadnav.experiments.scenarios import NAV_SCENARIOS, nav_builtin
    from quadnav.io.config import load_config

    if scenario in NAV_SCENARIOS:
        return nav_builtin(scenario, overrides)
    if scenario == "planar":
        raise ConfigError("SCENARIO planar: a sweep runs quadnav run's navigation scenarios so far")
    if not Path(scenario).is_file():
        raise ConfigError(
            f"SCENARIO {scenario!r} is neither a built-in scenario ({', '.join(NAV_SCENARIOS)}) "
            "nor a file"
        )
    return load_config(NavScenario, Path(scenario), overrides)


#: The record's entries that are not metrics of the flight (or too many to be columns).
_NAV_SKIP = ("seed", "filter_events", "vio_events", "landed_at_m", "counts", "vio_loop")


def _nav_task(config: Any, seed: int) -> dict[str, Metric]:
    """One seeded flight, as ``quadnav run`` flies it, and its metrics."""
    from quadnav.experiments.nav import run_nav
    from quadnav.experiments.nav_study import nav_metrics

    return flat_metrics(nav_metrics(run_nav(config, seed)).to_json(), skip=_NAV_SKIP)


register_task_kind(
    TaskKind(
        name="nav",
        description="one seeded flight of a quadnav run scenario (run_nav + nav_metrics)",
        build=nav_task_config,
        run=_nav_task,
        headline=(
            "output_rmse_m",
            "output_rmse_with_vision_m",
            "delayed_rmse_m",
            "attitude_rmse_deg",
            "nees_mean",
            "hold_max_horizontal_error_m",
            "end_position_error_m",
        ),
    )
)
