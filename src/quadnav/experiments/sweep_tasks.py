"""What one task of a sweep does: a registry of task kinds.

A task kind builds a validated configuration from a scenario and ``--set`` overrides (the
parent builds every grid point's before anything runs), and runs one seed of it, returning
flat metrics (a number or an ``"n/a: why"`` text per name). :func:`execute_task` runs a task
where the engine puts it (this process, a pool's worker, a Dask worker) by the kind's name:
it never raises for a task's own failure, which it returns as a one-line error.

The kinds: ``nav`` (``quadnav run``'s scenarios), ``planar`` (``quadnav planar``'s
experiments, one seed of each), ``sim`` (``quadnav sim``'s flights) and ``vio`` (``quadnav
vio`` on a built-in sequence, :mod:`quadnav.experiments.sweep_vio`) and ``slam`` (``quadnav
slam`` on one, chosen by ``--kind slam``: its sequences' names are vio's); another command's
runs become a kind by :func:`register_task_kind`, the engine unchanged.
:func:`kind_of_scenario` picks the kind of a built-in scenario's name (the kinds' names are
disjoint); a YAML file is a ``nav`` scenario unless the kind is given.
"""

from __future__ import annotations

import contextlib
import gc
import math
import time
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from quadnav.config_model import ConfigModel
from quadnav.errors import ConfigError
from quadnav.eval.na import Metric, na

if TYPE_CHECKING:
    from quadnav.experiments.planar import ExperimentName

__all__ = [
    "TASK_KINDS",
    "TaskKind",
    "TaskOutcome",
    "execute_task",
    "flat_metrics",
    "kind_of_scenario",
    "nav_task_config",
    "planar_task_config",
    "register_task_kind",
    "sim_task_config",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class TaskKind:
    """A kind of task: ``build(scenario, overrides)`` validates a configuration (a
    :class:`~quadnav.errors.QuadnavError` naming the key when it cannot), ``run(config,
    seed)`` flies one seed and returns its flat metrics; ``headline`` names the metrics the
    sweep's plots and report show (every metric is in its table); ``scenarios()`` lists its
    built-in scenarios' names and ``default_scenario`` is the one a sweep without SCENARIO
    runs."""

    name: str
    description: str
    build: Callable[[str, Sequence[str]], ConfigModel]
    run: Callable[[Any, int], Mapping[str, Metric]]
    headline: tuple[str, ...] = ()
    scenarios: Callable[[], Collection[str]] = tuple
    default_scenario: str = ""


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


#: The kind of a YAML file's scenario unless ``--kind`` names another.
FILE_KIND = "nav"


def kind_of_scenario(scenario: str) -> str:
    """The kind whose built-in scenarios include ``scenario`` (a file: :data:`FILE_KIND`);
    an unknown name, or one of several kinds, is a one-line error naming it and the kinds."""
    found = [k.name for k in TASK_KINDS.values() if scenario in k.scenarios()]
    if len(found) == 1:
        return found[0]
    kinds = ", ".join(TASK_KINDS)
    if found:
        raise ConfigError(
            f"SCENARIO {scenario!r}: a scenario of the kinds {', '.join(found)}: "
            f"give --kind ({kinds})"
        )
    if Path(scenario).is_file():
        return FILE_KIND
    raise ConfigError(
        f"SCENARIO {scenario!r}: neither a built-in scenario of a kind ({kinds}: "
        "quadnav run's, planar, quadnav sim --list's, quadnav dataset list's) nor a file"
    )


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


@contextlib.contextmanager
def _collector_paused() -> Iterator[None]:
    """Python's cycle collector off for a flight, and one collection after it: a flight logs
    tens of thousands of small objects that live to its end, which the collector would walk
    again and again (about 5 % of a flight); what cycles it leaves go after it. That collection
    is of the youngest generation, where everything made since the collector was paused still
    is (nothing was promoted): a full one would walk every object of the process, the imported
    modules' and numba's, about 0.1 s a flight for nothing of the flight's. (Not for a flight
    that renders images, nor the image-processing kinds: their long runs must not hold their
    garbage to the end.)"""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()
            gc.collect(0)


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
    _check_file(scenario, "nav", ", ".join(NAV_SCENARIOS))
    return load_config(NavScenario, Path(scenario), overrides)


def _check_file(scenario: str, kind: str, builtins: str) -> None:
    if not Path(scenario).is_file():
        raise ConfigError(
            f"SCENARIO {scenario!r}: neither a built-in scenario of the kind {kind} ({builtins}) "
            "nor a file"
        )


#: The record's entries that are not metrics of the flight (or too many to be columns).
_NAV_SKIP = ("seed", "filter_events", "vio_events", "landed_at_m", "counts", "vio_loop")


def _nav_task(config: Any, seed: int) -> dict[str, Metric]:
    """One seeded flight, as ``quadnav run`` flies it, and its metrics."""
    from quadnav.experiments.nav import run_nav
    from quadnav.experiments.nav_study import nav_metrics

    renders = (config.vision.enabled and config.vision.source == "camera") or (
        config.vio.enabled and config.vio.source == "camera"
    )
    with contextlib.nullcontext() if renders else _collector_paused():
        return flat_metrics(nav_metrics(run_nav(config, seed)).to_json(), skip=_NAV_SKIP)


def _nav_scenarios() -> Collection[str]:
    from quadnav.experiments.scenarios import NAV_SCENARIOS

    return NAV_SCENARIOS


register_task_kind(
    TaskKind(
        name="nav",
        description="one seeded flight of a quadnav run scenario (run_nav + nav_metrics)",
        build=nav_task_config,
        run=_nav_task,
        scenarios=_nav_scenarios,
        default_scenario="indoor_vision",
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


# -- planar: thesis 000's experiments (quadnav planar) -------------------------------------------


def planar_task_config(scenario: str, overrides: Sequence[str]) -> ConfigModel:
    """``planar`` (thesis 000's parameters) or a YAML file of ``quadnav planar``, with overrides.
    Its ``seed`` is the sweep's first seed; its ``seeds`` is not used (``--seeds`` is)."""
    from quadnav.experiments.planar import PlanarConfig
    from quadnav.io.config import load_config

    if scenario == "planar":
        return load_config(PlanarConfig, None, overrides)
    _check_file(scenario, "planar", "planar")
    return load_config(PlanarConfig, Path(scenario), overrides)


def _planar_task(config: Any, seed: int) -> dict[str, Metric]:
    """One seed of each configured experiment, as ``quadnav planar`` runs it: its metrics as
    ``<experiment>.<metric>`` (``handled.rmse_output_m``)."""
    record = {exp: _planar_seed_metrics(config, exp, seed) for exp in config.experiments}
    return flat_metrics(record)


def _planar_seed_metrics(config: Any, experiment: ExperimentName, seed: int) -> dict[str, object]:
    """One planar experiment's metrics for one seed (its ``seed`` field left out)."""
    from quadnav.experiments.planar import run_planar
    from quadnav.experiments.planar_study import planar_metrics

    metrics = asdict(planar_metrics(run_planar(config, experiment, seed)))
    del metrics["seed"]
    return metrics


register_task_kind(
    TaskKind(
        name="planar",
        description="one seed of each experiment of quadnav planar (run_planar + planar_metrics)",
        build=planar_task_config,
        run=_planar_task,
        scenarios=lambda: ("planar",),
        default_scenario="planar",
        headline=(
            "handled.rmse_output_m",
            "handled.rmse_delayed_m",
            "handled.output_over_floor",
            "handled.nees_mean",
            "naive.rmse_output_m",
            "no_update.rmse_output_m",
        ),
    )
)


# -- sim: quadnav sim's closed-loop flights ------------------------------------------------------


def sim_task_config(scenario: str, overrides: Sequence[str]) -> ConfigModel:
    """A scenario of ``quadnav sim`` (a built-in name or a YAML file) with overrides."""
    from quadnav.experiments.flight import BUILTIN, FlightConfig, builtin_config
    from quadnav.io.config import load_config

    if scenario in BUILTIN:
        return load_config(FlightConfig, None, overrides, base=builtin_config(scenario))
    _check_file(scenario, "sim", ", ".join(BUILTIN))
    return load_config(FlightConfig, Path(scenario), overrides)


#: A flight's figures that are not metrics of it (the wall time is the table's ``wall_s``).
_SIM_SKIP = ("scenario", "duration_s", "torque_unit", "sim_seconds_per_wall_second",
             "rotor_speed_range_rad_s")  # fmt: skip


def _sim_task(config: Any, seed: int) -> dict[str, Metric]:
    """One flight of ``quadnav sim`` with ``seed`` (run_flight + flight_metrics), flat: the
    rotor speeds' range as ``rotor_speed_min_rad_s`` and ``rotor_speed_max_rad_s``, the events
    as ``events.<name>`` (a list of times left out)."""
    from quadnav.experiments.flight import run_flight
    from quadnav.experiments.flight_study import flight_metrics

    m = flight_metrics(run_flight(config.model_copy(update={"seed": seed})))
    out = flat_metrics(m.to_json(), skip=_SIM_SKIP)
    if m.rotor_speed_range_rad_s is not None:
        out["rotor_speed_min_rad_s"], out["rotor_speed_max_rad_s"] = m.rotor_speed_range_rad_s
    return out


def _sim_scenarios() -> Collection[str]:
    from quadnav.experiments.flight import BUILTIN

    return BUILTIN


register_task_kind(
    TaskKind(
        name="sim",
        description="one seeded flight of a quadnav sim scenario (run_flight + flight_metrics)",
        build=sim_task_config,
        run=_sim_task,
        scenarios=_sim_scenarios,
        default_scenario="circle",
        headline=(
            "tracking_rmse_m",
            "settling_time_s",
            "max_tilt_deg",
            "saturation_time_s",
            "peak_thrust_n",
            "min_obstacle_distance_m",
        ),
    )
)


# -- vio: quadnav vio on a built-in sequence (experiments/sweep_vio.py) --------------------------


def _vio_build(scenario: str, overrides: Sequence[str]) -> ConfigModel:
    from quadnav.experiments.sweep_vio import vio_task_config

    return vio_task_config(scenario, tuple(overrides))


def _vio_task(config: Any, seed: int) -> dict[str, Metric]:
    from quadnav.experiments.sweep_vio import run_vio_task

    return run_vio_task(config, seed)


def _vio_scenarios() -> Collection[str]:
    from quadnav.experiments.datasets import SEQUENCES

    return SEQUENCES


register_task_kind(
    TaskKind(
        name="vio",
        description="quadnav vio on a built-in sequence made for the seed (no video)",
        build=_vio_build,
        run=_vio_task,
        scenarios=_vio_scenarios,
        default_scenario="room_easy",
        headline=(
            "ape_4dof.rmse_m",
            "final_error_m",
            "nees_pose.mean_over_dof",
            "fraction_with_estimate",
            "failures",
        ),
    )
)


# -- slam: quadnav slam on a built-in sequence (experiments/sweep_vio.py) -----------------------


def _slam_build(scenario: str, overrides: Sequence[str]) -> ConfigModel:
    from quadnav.experiments.sweep_vio import slam_task_config

    return slam_task_config(scenario, tuple(overrides))


def _slam_task(config: Any, seed: int) -> dict[str, Metric]:
    from quadnav.experiments.sweep_vio import run_slam_task

    return run_slam_task(config, seed)


register_task_kind(
    TaskKind(
        name="slam",
        description="quadnav slam on a built-in sequence made for the seed with a stereo or "
        "RGB-D rig (keys n_features, th_depth_baselines, loop, rig, duration_s); the "
        "sequences' names are vio's: give --kind slam",
        build=_slam_build,
        run=_slam_task,
        scenarios=tuple,  # (vio's names: chosen by --kind, never by name)
        default_scenario="room_easy",
        headline=(
            "ape_se3.rmse_m",
            "final_ape_se3.rmse_m",
            "fraction_with_estimate",
            "failures",
        ),
    )
)
