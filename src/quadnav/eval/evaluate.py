"""``quadnav eval``: compare estimates with a reference and write a run folder with a report."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Literal, NotRequired, TypedDict, get_args

import numpy as np

from quadnav.errors import EvalError
from quadnav.eval.align import Alignment, AlignMethod, GravityAxis, align
from quadnav.eval.associate import associate
from quadnav.eval.metrics import (
    ErrorStats,
    RpeUnit,
    ape,
    ape_matrices,
    pose_errors,
    position_nees,
    rpe_matrices,
)
from quadnav.eval.report import ReportSection, ReportTable, write_report
from quadnav.eval.runs import compare_runs, format_table
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.run_folder import create_run_folder, write_json, write_text
from quadnav.io.trajectory_io import TrajectoryFormat, read_trajectory, write_tum

__all__ = [
    "OPTION_NAMES",
    "EstimateMetrics",
    "EstimateResult",
    "EvalOptions",
    "EvalRun",
    "compare_runs",
    "evaluate_pair",
    "format_table",
    "run_eval",
]

Progress = Callable[[int, int, str], None]
MAX_T_MAX_DIFF_S = 1e6
MAX_T_OFFSET_S = 4e9
MAX_RPE_DELTA = 1e9

# The command-line option of each EvalOptions field, for error messages.
OPTION_NAMES: dict[str, str] = {
    "ref_format": "--ref-format",
    "est_format": "--format",
    "topic": "--topic",
    "t_max_diff_s": "--t-max-diff",
    "t_offset_s": "--t-offset",
    "interpolate": "--interpolate",
    "align": "--align",
    "align_first_n": "--align-first",
    "gravity_axis": "--gravity-axis",
    "rpe_delta": "--rpe-delta",
    "rpe_unit": "--rpe-unit",
    "rpe_all_pairs": "--all-pairs",
    "rpe_pairs_from": "--pairs-from-reference",
    "plots": "--no-plots",
}


@dataclass(frozen=True, slots=True, kw_only=True)
class EvalOptions:
    """How estimates are compared with the reference (saved as the run's config.yaml).

    Checked on construction: a bad value is an :class:`EvalError` naming the command-line
    option (``--t-offset: ...``). A plain dataclass: no model schema to build, and no YAML
    library to load, at start-up.
    """

    ref_format: TrajectoryFormat | None = None  # guessed when None
    est_format: TrajectoryFormat | None = None
    topic: str | None = None  # ROS bag topic, when a bag holds several
    t_max_diff_s: float = 0.01
    t_offset_s: float = 0.0  # added to the estimate's timestamps
    interpolate: bool = False  # interpolate the reference at estimate times
    align: AlignMethod = "none"
    align_first_n: int | None = None  # estimate the alignment on the first N poses
    # The axis 4dof alignment rotates about: None is y for KITTI (a reference without
    # timestamps, in its camera frame) and z otherwise.
    gravity_axis: GravityAxis | None = None
    rpe_delta: float = 1.0
    rpe_unit: RpeUnit = "frames"
    rpe_all_pairs: bool = False
    rpe_pairs_from: Literal["estimate", "reference"] = "estimate"
    plots: bool = True

    def __post_init__(self) -> None:
        _choice(self, "ref_format", (None, *get_args(TrajectoryFormat)))
        _choice(self, "est_format", (None, *get_args(TrajectoryFormat)))
        _choice(self, "align", get_args(AlignMethod))
        _choice(self, "gravity_axis", (None, *get_args(GravityAxis)))
        _choice(self, "rpe_unit", get_args(RpeUnit))
        _choice(self, "rpe_pairs_from", ("estimate", "reference"))
        # Bounds keep every time in int64 nanoseconds: 1e6 s is 11.6 days; 4e9 s covers the
        # gap between Unix time and a log that starts at zero.
        _number(self, "t_max_diff_s", 0.0, MAX_T_MAX_DIFF_S)
        _number(self, "t_offset_s", -MAX_T_OFFSET_S, MAX_T_OFFSET_S)
        _number(self, "rpe_delta", 0.0, MAX_RPE_DELTA, low_open=True)
        n = self.align_first_n
        if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
            raise EvalError(f"--align-first: must be a whole number >= 1 (got {n!r})")
        if self.topic is not None and not isinstance(self.topic, str):
            raise EvalError(f"--topic: must be text (got {self.topic!r})")

    def as_yaml(self) -> str:
        """Every field, one ``key: value`` line each (JSON scalars, which YAML reads)."""
        return "".join(f"{f.name}: {json.dumps(getattr(self, f.name))}\n" for f in fields(self))


def _choice(opts: EvalOptions, name: str, allowed: tuple[object, ...]) -> None:
    value = getattr(opts, name)
    if value not in allowed:
        shown = ", ".join(str(a) for a in allowed if a is not None)
        raise EvalError(f"{OPTION_NAMES[name]}: must be one of {shown} (got {value!r})")


def _number(opts: EvalOptions, name: str, lo: float, hi: float, *, low_open: bool = False) -> None:
    value = getattr(opts, name)
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or not (lo < value <= hi if low_open else lo <= value <= hi):
        low = f"> {lo:g}" if low_open else f">= {lo:g}"
        raise EvalError(
            f"{OPTION_NAMES[name]}: must be a finite number {low} and <= {hi:g} (got {value!r})"
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class EstimateMetrics:
    """The error statistics of one estimate, named as ``metrics.json`` names them."""

    ape_trans_m: ErrorStats
    ape_rot_deg: ErrorStats
    ape_full: ErrorStats
    rpe_trans_m: ErrorStats
    rpe_rot_deg: ErrorStats
    nees_pos: ErrorStats | None = None  # only for an estimate that carries covariances

    def named(self) -> tuple[tuple[str, ErrorStats], ...]:
        """Each statistic with its name, in order (NEES only when there is one)."""
        pairs = ((f.name, getattr(self, f.name)) for f in fields(self))
        return tuple((name, stats) for name, stats in pairs if stats is not None)


# The shapes of ``metrics.json`` (TypedDicts, not dataclasses: the file is the contract that
# users' scripts read, so its keys, "APE rmse (m)" included, are spelt out once, here).
SummaryRow = TypedDict(
    "SummaryRow",
    {
        "estimate": str,
        "matched": int,
        "align": str,
        "APE rmse (m)": float,
        "APE mean (m)": float,
        "APE max (m)": float,
        "APE rot rmse (deg)": float,
        "RPE rmse (m)": float,
        "RPE rot rmse (deg)": float,
        "NEES mean": NotRequired[float],
    },
)


class AlignmentJson(TypedDict):
    method: str
    R: list[list[float]]
    t: list[float]
    s: float
    n_used: int


class EstimateJson(TypedDict):
    matched: int
    alignment: AlignmentJson
    ape_trans_m: dict[str, float]
    ape_rot_deg: dict[str, float]
    ape_full: dict[str, float]
    rpe_trans_m: dict[str, float]
    rpe_rot_deg: dict[str, float]
    nees_pos: NotRequired[dict[str, float]]


class EvalMetricsJson(TypedDict):
    kind: Literal["eval"]
    reference: str
    estimates: dict[str, EstimateJson]
    notes: list[str]
    table: list[SummaryRow]


@dataclass(frozen=True, slots=True)
class EstimateResult:
    """Everything measured for one estimate against the reference."""

    name: str
    n_matched: int
    alignment: Alignment
    metrics: EstimateMetrics
    ref: Trajectory
    est_aligned: Trajectory
    ape_trans: np.ndarray
    notes: tuple[str, ...] = ()

    def row(self) -> SummaryRow:
        """A flat summary row (for tables)."""
        m = self.metrics
        row: SummaryRow = {
            "estimate": self.name,
            "matched": self.n_matched,
            "align": self.alignment.method,
            "APE rmse (m)": m.ape_trans_m.rmse,
            "APE mean (m)": m.ape_trans_m.mean,
            "APE max (m)": m.ape_trans_m.max,
            "APE rot rmse (deg)": m.ape_rot_deg.rmse,
            "RPE rmse (m)": m.rpe_trans_m.rmse,
            "RPE rot rmse (deg)": m.rpe_rot_deg.rmse,
        }
        if m.nees_pos is not None:
            row["NEES mean"] = m.nees_pos.mean
        return row

    def as_json(self) -> EstimateJson:
        """This estimate's entry of ``metrics.json``."""
        a = self.alignment
        out: EstimateJson = {
            "matched": self.n_matched,
            "alignment": {
                "method": a.method,
                "R": a.R.as_matrix().tolist(),
                "t": np.asarray(a.t, dtype=np.float64).tolist(),
                "s": float(a.s),
                "n_used": a.n_used,
            },
            "ape_trans_m": self.metrics.ape_trans_m.as_dict(),
            "ape_rot_deg": self.metrics.ape_rot_deg.as_dict(),
            "ape_full": self.metrics.ape_full.as_dict(),
            "rpe_trans_m": self.metrics.rpe_trans_m.as_dict(),
            "rpe_rot_deg": self.metrics.rpe_rot_deg.as_dict(),
        }
        if self.metrics.nees_pos is not None:
            out["nees_pos"] = self.metrics.nees_pos.as_dict()
        return out


def evaluate_pair(ref: Trajectory, est: Trajectory, opts: EvalOptions) -> EstimateResult:
    """Associate, align and measure one estimate."""
    r, e = associate(
        ref,
        est,
        t_max_diff_s=opts.t_max_diff_s,
        t_offset_s=opts.t_offset_s,
        interpolate=opts.interpolate,
    )
    axis, notes = _gravity_axis(ref, opts)
    e_al, alignment = align(r, e, opts.align, first_n=opts.align_first_n, gravity_axis=axis)
    ape_t = ape(r, e_al, "trans")
    E = ape_matrices(r, e_al)
    # RPE on the aligned estimate, as evo_rpe -a/-as (a similarity scales the relative motions).
    E_rel, _ = rpe_matrices(
        r,
        e_al,
        delta=opts.rpe_delta,
        unit=opts.rpe_unit,
        all_pairs=opts.rpe_all_pairs,
        pairs_from=opts.rpe_pairs_from,
    )
    metrics = EstimateMetrics(
        ape_trans_m=ErrorStats.of(ape_t),
        ape_rot_deg=ErrorStats.of(np.degrees(pose_errors(E, "rot"))),
        ape_full=ErrorStats.of(pose_errors(E, "full")),
        rpe_trans_m=ErrorStats.of(pose_errors(E_rel, "trans")),
        rpe_rot_deg=ErrorStats.of(np.degrees(pose_errors(E_rel, "rot"))),
        nees_pos=ErrorStats.of(position_nees(r, e_al)) if e_al.cov_p is not None else None,
    )
    return EstimateResult(
        name=est.name or "estimate",
        n_matched=len(e),
        alignment=alignment,
        metrics=metrics,
        ref=r,
        est_aligned=e_al,
        ape_trans=ape_t,
        notes=notes,
    )


def _gravity_axis(ref: Trajectory, opts: EvalOptions) -> tuple[GravityAxis, tuple[str, ...]]:
    """The axis of 4dof alignment, and a note when it was chosen for KITTI."""
    if opts.gravity_axis is not None:
        return opts.gravity_axis, ()
    if ref.timed:
        return "z", ()
    note = (
        "4dof alignment rotates about y, the vertical of KITTI's camera frame (the reference "
        "has no timestamps: KITTI); pass --gravity-axis z for a z-up frame"
    )
    return "y", (note,) if opts.align == "4dof" else ()


@dataclass(frozen=True, slots=True)
class EvalRun:
    """The run folder of ``quadnav eval``, each estimate's result, and the notes it printed."""

    run_dir: Path
    results: tuple[EstimateResult, ...]
    notes: tuple[str, ...] = ()


def _unique_names(trajs: list[Trajectory]) -> list[Trajectory]:
    seen: dict[str, int] = {}
    out = []
    for t in trajs:
        base = t.name or "estimate"
        seen[base] = seen.get(base, 0) + 1
        out.append(replace(t, name=base if seen[base] == 1 else f"{base}-{seen[base]}"))
    return out


def _read_inputs(
    ref_path: Path, est_paths: list[Path], opts: EvalOptions
) -> tuple[Trajectory, list[Trajectory]]:
    ref = read_trajectory(ref_path, opts.ref_format, topic=opts.topic)
    ests = _unique_names([read_trajectory(p, opts.est_format, topic=opts.topic) for p in est_paths])
    if ref.name in {e.name for e in ests}:
        ref = replace(ref, name=f"{ref.name} (reference)", cov_p=None)
    return ref, ests


def run_eval(
    ref_path: Path,
    est_paths: list[Path],
    opts: EvalOptions,
    *,
    runs_root: Path,
    progress: Progress | None = None,
) -> EvalRun:
    """Read, evaluate every estimate, and write a run folder with metrics, plots and a report."""
    if not est_paths:
        raise EvalError("give at least one estimate to evaluate")
    ref, ests = _read_inputs(ref_path, est_paths, opts)
    results = []
    for k, est in enumerate(ests):
        results.append(evaluate_pair(ref, est, opts))
        if progress is not None:
            progress(k + 1, len(ests), est.name)
    notes = tuple(t.meta["note"] for t in (ref, *ests) if "note" in t.meta)
    notes += tuple(dict.fromkeys(n for res in results for n in res.notes))
    run_dir = create_run_folder(runs_root, "eval")
    write_text(
        run_dir / "config.yaml",
        opts.as_yaml()
        + f"reference: {json.dumps(str(ref_path))}\n"
        + f"estimates: {json.dumps([str(p) for p in est_paths])}\n",
    )
    images = _write_plots(run_dir, ref, results) if opts.plots else []
    for res in results:
        write_tum(run_dir / "aligned" / f"{res.name}.tum", res.est_aligned)
    table = [res.row() for res in results]
    write_json(run_dir / "metrics.json", _metrics_json(ref_path, results, table, notes))
    write_report(
        run_dir / "report.html",
        title=f"Trajectory evaluation against {Path(ref_path).name}",
        sections=[
            ReportSection(
                heading="Metrics",
                text=f"{len(results)} estimate(s); alignment {opts.align}; RPE delta "
                f"{opts.rpe_delta} {opts.rpe_unit}." + "".join(f"\n{n}" for n in notes),
                tables=[_report_table(table)],
            ),
            ReportSection(heading="Plots", images=images),
            ReportSection(heading="Configuration", code=(run_dir / "config.yaml").read_text()),
        ],
    )
    return EvalRun(run_dir=run_dir, results=tuple(results), notes=notes)


def _write_plots(run_dir: Path, ref: Trajectory, results: list[EstimateResult]) -> list[Path]:
    from quadnav.eval.plots import plot_errors, plot_trajectories, plot_xyz  # matplotlib: slow

    plot_xyz(ref, [r.est_aligned for r in results], run_dir / "plots" / "xyz.png")
    plot_trajectories(ref, [r.est_aligned for r in results], run_dir / "plots" / "trajectories.png")
    images = [run_dir / "plots" / "xyz.png", run_dir / "plots" / "trajectories.png"]
    for res in results:
        p = run_dir / "plots" / f"ape_{res.name}.png"
        plot_errors(res.ref, res.est_aligned, res.ape_trans, p, what="APE translation (m)")
        images.append(p)
    return images


def _metrics_json(
    ref_path: Path,
    results: list[EstimateResult],
    table: list[SummaryRow],
    notes: tuple[str, ...],
) -> EvalMetricsJson:
    return {
        "kind": "eval",
        "reference": str(ref_path),
        "estimates": {res.name: res.as_json() for res in results},
        "notes": list(notes),
        "table": table,
    }


def _report_table(rows: Sequence[Mapping[str, object]], caption: str = "") -> ReportTable:
    headers = list(dict.fromkeys(k for row in rows for k in row))
    return ReportTable(caption, headers, [[row.get(h, "") for h in headers] for row in rows])
