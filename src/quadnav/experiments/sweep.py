"""Parameter sweeps (issue 26): a grid of configuration values x seeds, one task per (grid
point, seed), run on a process pool or Dask, written as a tidy table as the tasks finish.

The sweep folder (``--out``) holds ``sweep.json`` (what the sweep is, and its fingerprint),
``config.yaml`` (the scenario with the ``--set`` overrides), ``tasks.jsonl`` (one line per
finished task, append-only: the source of truth), ``results.parquet`` (one row per finished
task, rewritten atomically every few seconds and at the end), and, once every task has
finished, ``plots/*.png`` and ``report.html``. Running the same sweep into the same folder
again runs only the tasks its journal does not hold (``retry_failed``: the failed ones too);
a different sweep (scenario, grid, seeds or overrides) into it is refused. Ctrl-C keeps what
finished and marks the folder ``interrupted``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from quadnav.config_model import ConfigModel
from quadnav.errors import ConfigError, QuadnavError
from quadnav.eval.report import ReportSection, ReportTable, write_report
from quadnav.eval.sweep_plots import plot_sweep, value_label
from quadnav.experiments.sweep_engines import SweepEngine, check_engine, run_engine
from quadnav.experiments.sweep_grid import (
    GridAxis,
    GridValue,
    check_sweep_size,
    grid_axis,
    grid_points,
    override,
    parse_grid_option,
    sweep_seeds,
)
from quadnav.experiments.sweep_tasks import TASK_KINDS, TaskKind, TaskOutcome, kind_of_scenario
from quadnav.io.config import dump_config, load_config
from quadnav.io.run_folder import (
    append_jsonl,
    finish_run_folder,
    open_run_folder,
    read_json,
    read_jsonl,
    write_json,
    write_text,
)
from quadnav.io.tables import write_parquet

__all__ = [
    "GridPoint",
    "SweepFile",
    "SweepPlan",
    "SweepResult",
    "SweepSpec",
    "default_folder",
    "load_sweep_file",
    "plan_sweep",
    "run_sweep",
    "sweep_spec",
]

Progress = Callable[[int, int, str], None]
#: Seconds between rewrites of ``results.parquet`` while tasks finish.
REWRITE_EVERY_S = 5.0
#: Failed tasks listed in the report (all of them are in the table).
REPORT_FAILED = 20


class SweepFile(BaseModel):
    """``--grid-file``: a sweep in YAML (the command line's values take precedence). Not a
    configuration of a flight (its ``set`` and ``grid`` are those): unknown keys refused."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: str | None = None
    scenario: str | None = None
    grid: dict[str, Any] = Field(default_factory=dict)
    seeds: int | str | None = None
    set: list[str] | dict[str, Any] = Field(default_factory=list)


@dataclass(frozen=True, slots=True, kw_only=True)
class SweepSpec:
    """A sweep as asked: the task kind, the scenario, the grid, ``--seeds``, ``--set``."""

    scenario: str
    grid: tuple[GridAxis, ...]
    seeds: str = "1"
    overrides: tuple[str, ...] = ()
    kind: str = "nav"


@dataclass(frozen=True, slots=True)
class GridPoint:
    index: int
    params: tuple[tuple[str, GridValue], ...]
    config: ConfigModel


@dataclass(frozen=True, slots=True, kw_only=True)
class SweepPlan:
    """A sweep validated: every grid point's configuration built, the seeds listed."""

    spec: SweepSpec
    kind: TaskKind
    base: ConfigModel
    points: tuple[GridPoint, ...]
    seeds: tuple[int, ...]
    fingerprint: str

    @property
    def n_tasks(self) -> int:
        return len(self.points) * len(self.seeds)

    def task(self, task_id: int) -> tuple[GridPoint, int]:
        return self.points[task_id // len(self.seeds)], self.seeds[task_id % len(self.seeds)]


@dataclass(frozen=True, slots=True, kw_only=True)
class SweepResult:
    folder: Path
    tasks: int  # in the sweep
    done_before: int  # finished by an earlier run into the folder
    ran: int  # finished by this run
    ok: int  # in the table
    failed: int  # in the table
    status: str  # complete or interrupted


def load_sweep_file(path: Path) -> SweepFile:
    try:
        return load_config(SweepFile, Path(path))
    except QuadnavError as exc:
        raise ConfigError(f"--grid-file {exc}") from None


def sweep_spec(
    file: SweepFile | None,
    scenario: str | None,
    grid: Sequence[str],
    seeds: str | None,
    overrides: Sequence[str],
    kind: str | None = None,
) -> SweepSpec:
    """The sweep from a ``--grid-file`` and the command line: SCENARIO, ``--kind`` and
    ``--seeds`` replace the file's, a ``--grid`` replaces the file's axis of the same key,
    ``--set`` comes after. Without a kind, SCENARIO's (:func:`kind_of_scenario`); without
    SCENARIO, the kind's default one (``nav``'s without either)."""
    f = file or SweepFile()
    kind_name, scenario = _kind_and_scenario(kind or f.kind, scenario or f.scenario)
    axes = {k: grid_axis(k, v, from_text=False) for k, v in f.grid.items()}
    for text in grid:
        axis = parse_grid_option(text)
        axes[axis.key] = axis
    if not axes:
        raise ConfigError("--grid: give at least one KEY=SPEC (or a --grid-file with a grid)")
    file_set = (
        [override(k, v) for k, v in f.set.items()] if isinstance(f.set, dict) else list(f.set)
    )
    return SweepSpec(
        scenario=scenario,
        grid=tuple(axes.values()),
        seeds=str(seeds if seeds is not None else f.seeds if f.seeds is not None else 1),
        overrides=(*file_set, *overrides),
        kind=kind_name,
    )


def _kind_and_scenario(kind: str | None, scenario: str | None) -> tuple[str, str]:
    if kind is not None and kind not in TASK_KINDS:
        raise ConfigError(f"--kind {kind}: not a kind of task; choose from {', '.join(TASK_KINDS)}")
    if scenario is None:
        name = kind or "nav"
        return name, TASK_KINDS[name].default_scenario
    return kind or kind_of_scenario(scenario), scenario


def _build(kind: TaskKind, spec: SweepSpec, params: Sequence[tuple[str, GridValue]]) -> ConfigModel:
    return kind.build(spec.scenario, [*spec.overrides, *(override(k, v) for k, v in params)])


def plan_sweep(spec: SweepSpec) -> SweepPlan:
    """Validate the sweep before anything runs: its size from the specs, each grid value
    alone (an error names ``--grid KEY``), then each grid point's whole configuration."""
    if spec.kind not in TASK_KINDS:
        raise ConfigError(f"kind {spec.kind!r}: choose from {', '.join(TASK_KINDS)}")
    kind = TASK_KINDS[spec.kind]
    base = kind.build(spec.scenario, spec.overrides)
    seeds = sweep_seeds(spec.seeds, int(getattr(base, "seed", 0)))
    check_sweep_size(spec.grid, len(seeds))
    for axis in spec.grid:
        for v in axis.values:
            try:
                _build(kind, spec, [(axis.key, v)])
            except QuadnavError as exc:
                raise ConfigError(f"--grid {axis.key}={value_label(v)}: {exc}") from None
    points = []
    for k, params in enumerate(grid_points(spec.grid)):
        try:
            points.append(GridPoint(k, params, _build(kind, spec, params)))
        except QuadnavError as exc:
            shown = ", ".join(f"{key}={value_label(v)}" for key, v in params)
            raise ConfigError(f"--grid point {shown}: {exc}") from None
    identity = {
        "kind": spec.kind,
        "base": base.model_dump(mode="json"),
        "grid": [[a.key, list(a.values)] for a in spec.grid],
        "seeds": list(seeds),
    }
    digest = hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()
    return SweepPlan(
        spec=spec, kind=kind, base=base, points=tuple(points), seeds=seeds, fingerprint=digest
    )


def default_folder(plan: SweepPlan, root: Path) -> Path:
    """``root/sweep_<name>_<fingerprint>``: the same sweep goes to (and resumes in) the same
    folder."""
    name = str(getattr(plan.base, "name", plan.spec.kind))
    return Path(root) / f"sweep_{name}_{plan.fingerprint[:10]}"


def _open_folder(plan: SweepPlan, folder: Path) -> None:
    """Create the sweep folder, or reopen it for the same sweep; another sweep's is refused."""
    marker = folder / "sweep.json"
    if marker.is_file():
        if read_json(marker).get("fingerprint") != plan.fingerprint:
            raise ConfigError(
                f"--out {folder}: holds another sweep (its scenario, grid, seeds or --set "
                "differ); give another --out"
            )
    elif folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise ConfigError(f"--out {folder}: not a sweep folder (no sweep.json) and not empty")
    open_run_folder(folder)
    write_text(folder / "config.yaml", dump_config(plan.base))
    write_json(marker, {
        "fingerprint": plan.fingerprint, "kind": plan.spec.kind, "scenario": plan.spec.scenario,
        "grid": {a.key: list(a.values) for a in plan.spec.grid}, "seeds": list(plan.seeds),
        "set": list(plan.spec.overrides), "tasks": plan.n_tasks,
    })  # fmt: skip


def _finished(plan: SweepPlan, folder: Path, *, retry_failed: bool) -> dict[int, dict[str, object]]:
    """The journal's last record of each task (a failed one left out with ``retry_failed``)."""
    done: dict[int, dict[str, object]] = {}
    for rec in read_jsonl(folder / "tasks.jsonl", repair=True):
        task = rec.get("task")
        if isinstance(task, int) and 0 <= task < plan.n_tasks:
            done[task] = rec
    if retry_failed:
        done = {k: r for k, r in done.items() if r.get("status") == "ok"}
    return done


def _record(plan: SweepPlan, task_id: int, out: TaskOutcome) -> dict[str, object]:
    point, seed = plan.task(task_id)
    return {
        "task": task_id, "point": point.index, "seed": seed, "params": dict(point.params),
        "status": out.status, "error": out.error, "wall_s": round(out.wall_s, 4),
        "metrics": out.metrics,
    }  # fmt: skip


def _metric_names(plan: SweepPlan, records: Sequence[Mapping[str, object]]) -> list[str]:
    """The metric columns: the kind's headline ones first, then the others by name."""
    seen: dict[str, None] = {}
    for rec in records:
        m = rec.get("metrics")
        if isinstance(m, dict):
            seen.update(dict.fromkeys(m))
    head = [n for n in plan.kind.headline if n in seen]
    return head + sorted(n for n in seen if n not in head)


def _number(value: object) -> float | None:
    """A metric's cell: its number, or null for ``n/a: why`` (the journal keeps the why)."""
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _columns(plan: SweepPlan, done: Mapping[int, Mapping[str, object]]) -> dict[str, list[object]]:
    """The tidy table: one row per finished task, in task order."""
    ids = sorted(done)
    records = [done[i] for i in ids]
    cols: dict[str, list[object]] = {"task": list(ids)}
    for axis in plan.spec.grid:
        cols[axis.key] = [dict(plan.task(i)[0].params)[axis.key] for i in ids]
    cols["seed"] = [plan.task(i)[1] for i in ids]
    for name in ("status", "error"):
        cols[name] = [str(r.get(name, "")) for r in records]
    cols["wall_s"] = [_number(r.get("wall_s")) for r in records]
    for name in _metric_names(plan, records):
        cols[name] = [_number(_metrics(r).get(name)) for r in records]
    return cols


def _metrics(rec: Mapping[str, object]) -> Mapping[str, object]:
    m = rec.get("metrics")
    return m if isinstance(m, dict) else {}


class _Collector:
    """Each finished task: a journal line at once, the table every few seconds, progress."""

    def __init__(self, plan: SweepPlan, folder: Path, done: dict[int, dict[str, object]],
                 todo: Sequence[int], progress: Progress | None, rewrite_every_s: float) -> None:  # fmt: skip
        self.plan, self.folder, self.done, self.todo = plan, folder, done, todo
        self.progress, self.rewrite_every_s = progress, rewrite_every_s
        self.before = len(done)
        self.ran = self.failed = 0
        self.last_write = time.monotonic()
        self.last_write_s = 0.0

    def __call__(self, index: int, outcome: TaskOutcome) -> None:
        task_id = self.todo[index]
        record = _record(self.plan, task_id, outcome)
        append_jsonl(self.folder / "tasks.jsonl", record)
        self.done[task_id] = record
        self.ran += 1
        self.failed += outcome.status == "failed"
        if time.monotonic() - self.last_write >= self.rewrite_every_s:
            self.write_table()
            # a large table: rewrite no more than a twentieth of the time
            self.rewrite_every_s = max(self.rewrite_every_s, 20 * self.last_write_s)
        if self.progress is not None:
            before = f", {self.before} done before" if self.before else ""
            what = f"{self.ran - self.failed} ok, {self.failed} failed{before}"
            self.progress(self.ran, len(self.todo), what)

    def write_table(self) -> None:
        t0 = time.monotonic()
        write_parquet(self.folder / "results.parquet", _columns(self.plan, self.done))
        self.last_write = time.monotonic()
        self.last_write_s = self.last_write - t0


def run_sweep(
    plan: SweepPlan,
    folder: Path,
    engine: SweepEngine,
    *,
    progress: Progress | None = None,
    retry_failed: bool = False,
    rewrite_every_s: float = REWRITE_EVERY_S,
) -> SweepResult:
    """Run the tasks of ``plan`` that ``folder``'s journal does not hold, on ``engine``;
    write the table as they finish, then the plots and the report."""
    check_engine(engine)
    folder = Path(folder)
    _open_folder(plan, folder)
    done = _finished(plan, folder, retry_failed=retry_failed)
    # seed-major: every grid point's first seed before any point's second (an early picture)
    order = sorted(range(plan.n_tasks), key=lambda t: (t % len(plan.seeds), t))
    todo = [t for t in order if t not in done]
    collect = _Collector(plan, folder, done, todo, progress, rewrite_every_s)
    tasks = []
    for t in todo:
        point, seed = plan.task(t)
        tasks.append((plan.spec.kind, point.config, seed))
    if progress is not None:
        progress(0, len(todo), f"{len(done)} done before" if done else "")
    try:
        run_engine(engine, tasks, collect)
    except KeyboardInterrupt:
        collect.write_table()
        _outputs_so_far(plan, folder, done, engine)
        finish_run_folder(folder, "interrupted", "interrupted (Ctrl-C)")
        raise
    except BaseException as exc:
        collect.write_table()
        finish_run_folder(folder, "failed", str(exc) or type(exc).__name__)
        raise
    collect.write_table()
    _write_outputs(plan, folder, done, engine)
    finish_run_folder(folder)
    failed = sum(r.get("status") == "failed" for r in done.values())
    return SweepResult(folder=folder, tasks=plan.n_tasks, done_before=collect.before,
                       ran=collect.ran, ok=len(done) - failed, failed=failed, status="complete")  # fmt: skip


def _outputs_so_far(
    plan: SweepPlan, folder: Path, done: Mapping[int, Mapping[str, object]], engine: SweepEngine
) -> None:
    """An interrupted sweep's plots and report of the tasks that finished, saying it was
    interrupted (the same command again finishes the rest and draws them anew). A second
    Ctrl-C, or a plot that cannot be drawn, leaves them out: the table and the journal are
    written already."""
    if not done:
        return
    note = (
        f"Interrupted (Ctrl-C) after {len(done)} of {plan.n_tasks} task(s): what is below is "
        "what finished. Run the same command again to finish the rest."
    )
    with contextlib.suppress(KeyboardInterrupt, QuadnavError, OSError):
        _write_outputs(plan, folder, done, engine, note=note)


def _write_outputs(
    plan: SweepPlan,
    folder: Path,
    done: Mapping[int, Mapping[str, object]],
    engine: SweepEngine,
    *,
    note: str = "",
) -> None:
    """The plots of the headline metrics against each parameter, and the report (``note``
    first when it is given)."""
    cols = _columns(plan, done)
    params = {a.key: cols[a.key] for a in plan.spec.grid}
    head = [n for n in plan.kind.headline if n in cols] or _metric_names(plan, list(done.values()))
    metrics = {n: np.array([np.nan if v is None else v for v in cols[n]], dtype=np.float64)
               for n in head}  # fmt: skip
    images = plot_sweep(params, metrics, folder / "plots")
    write_report(
        folder / "report.html",
        title=f"Sweep of {plan.spec.scenario}: {len(plan.points)} grid point(s) x "
        f"{len(plan.seeds)} seed(s)",
        sections=[
            *([ReportSection(heading="Interrupted", text=note)] if note else []),
            _summary_section(plan, cols, engine),
            _medians_section(plan, cols, metrics),
            *_failed_section(plan, cols),
            ReportSection(heading="Plots", images=images),
            ReportSection(heading="Sweep", code=json.dumps(
                read_json(folder / "sweep.json"), indent=1)),
        ],
    )  # fmt: skip


def _summary_section(
    plan: SweepPlan, cols: Mapping[str, list[object]], engine: SweepEngine
) -> ReportSection:
    n_failed = sum(s == "failed" for s in cols["status"])
    walls = [w for w in cols["wall_s"] if isinstance(w, float)]
    grid = [[a.key, ", ".join(value_label(v) for v in a.values)] for a in plan.spec.grid]
    return ReportSection(
        heading="Tasks",
        text=f"{len(cols['task'])} task(s): {len(cols['task']) - n_failed} ok, {n_failed} "
        f"failed; seeds {plan.seeds[0]}..{plan.seeds[-1]}; median wall time per task "
        f"{float(np.median(walls)) if walls else float('nan'):.2f} s (this run on "
        f"{engine.describe()}). Table: results.parquet; journal: tasks.jsonl.",
        tables=[ReportTable("the grid", ["key", "values"], grid)],
    )


def _medians_section(
    plan: SweepPlan, cols: Mapping[str, list[object]], metrics: Mapping[str, np.ndarray]
) -> ReportSection:
    """Per grid point: the tasks that finished ok, and each headline metric's median."""
    keys = [a.key for a in plan.spec.grid]
    point_of_row = np.array([plan.task(int(t))[0].index for t in cols["task"]])  # type: ignore[call-overload]
    ok = np.array([s == "ok" for s in cols["status"]])
    rows: list[list[object]] = []
    for point in plan.points:
        sel = point_of_row == point.index
        row: list[object] = [value_label(v) for _, v in point.params]
        row.append(int((sel & ok).sum()))
        for y in metrics.values():
            v = y[sel & np.isfinite(y)]
            row.append(float(np.median(v)) if len(v) else "n/a")
        rows.append(row)
    return ReportSection(
        heading="Medians per grid point",
        tables=[ReportTable("median over the seeds that gave the metric",
                            [*keys, "ok", *metrics], rows)],
    )  # fmt: skip


def _failed_section(plan: SweepPlan, cols: Mapping[str, list[object]]) -> list[ReportSection]:
    rows = [
        [cols["task"][k], *(value_label(cols[a.key][k]) for a in plan.spec.grid),
         cols["seed"][k], cols["error"][k]]
        for k, s in enumerate(cols["status"]) if s == "failed"
    ]  # fmt: skip
    if not rows:
        return []
    headers = ["task", *(a.key for a in plan.spec.grid), "seed", "error"]
    return [ReportSection(
        heading="Failed tasks",
        tables=[ReportTable(f"{len(rows)} failed (the first {REPORT_FAILED} here)", headers,
                            rows[:REPORT_FAILED])],
    )]  # fmt: skip
