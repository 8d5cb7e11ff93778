"""An odometry (``quadnav vio SEQ ... --seeds 0-4``) over several datasets and seeds: one run folder per
run inside a study folder, and a table of ATE, drift, failures and speed per run with the mean
and median over the runs of each dataset (``summary.json``, ``summary.md``, printed by the CLI).

A built-in sequence name is made once per seed; a dataset folder is one run whatever the seeds
(its images are what they are), so the lead's ``v102_s0 ... v102_s4`` folders are five runs of
one group when named ``v102_s*``: a folder's group is its name without a trailing ``_s<N>``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from quadnav.eval.na import Metric, fmt_metric, is_na
from quadnav.eval.vio_metrics import MIN_DRIFT_DISTANCE_M
from quadnav.experiments.odometry_run import OdometryRun
from quadnav.io.run_folder import append_jsonl, create_run_folder, write_json, write_text

__all__ = [
    "GROUP_HEADER",
    "ROW_HEADER",
    "OdometryGroup",
    "OdometryRow",
    "OdometryStudy",
    "group_cells",
    "group_of",
    "row_cells",
    "row_of",
    "run_odometry_study",
    "summarize",
    "summary_markdown",
]

Progress = Callable[[int, int, str], None]
#: One run: (dataset source, seed, the folder its run folder goes in) -> the finished run.
RunOne = Callable[[str, int, Path], OdometryRun]


def group_of(source: str) -> str:
    """The group a run's dataset belongs to: a sequence's name, or a folder's name without a
    trailing ``_s<N>`` (the seed of a made dataset)."""
    name = Path(source).name or source
    return re.sub(r"_s\d+$", "", name)


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometryRow:
    """One run of the study."""

    group: str
    dataset: str
    seed: int | None
    ate_4dof_rmse_m: Metric
    #: the final trajectory's (``estimate_final.tum``, not causal) APE after SE(3)
    final_ape_se3_m: Metric
    final_error_m: Metric
    drift_final_pct: Metric
    drift_rpe_pct: Metric
    gravity_error_deg: Metric
    nees_over_6: Metric
    fraction_with_estimate: float
    failures: int
    reinitializations: int
    frames_per_s: float
    run_dir: str


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometryGroup:
    """Mean and median over one group's runs (runs without a number are left out and
    counted in ``runs_without_ate``)."""

    group: str
    runs: int
    runs_without_ate: int
    ate_mean_m: Metric
    ate_median_m: Metric
    final_ape_se3_mean_m: Metric
    drift_final_mean_pct: Metric
    drift_final_median_pct: Metric
    drift_rpe_median_pct: Metric
    nees_over_6_mean: Metric
    failures: int
    reinitializations: int
    frames_per_s_median: float


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometryStudy:
    rows: tuple[OdometryRow, ...]
    groups: tuple[OdometryGroup, ...]
    run_dir: Path

    def as_json(self) -> dict[str, object]:
        return {"runs": [asdict(r) for r in self.rows], "groups": [asdict(g) for g in self.groups]}


def _field(value: object, name: str) -> Metric:
    return value if isinstance(value, str) else float(getattr(value, name))


def row_of(run: OdometryRun, group: str, seed: int | None) -> OdometryRow:
    m = run.metrics
    return OdometryRow(
        group=group, dataset=run.dataset, seed=seed,
        ate_4dof_rmse_m=_field(m.ape_4dof, "rmse_m"), final_error_m=m.final_error_m,
        final_ape_se3_m=_final_se3(run),
        drift_final_pct=m.drift_final_pct,
        drift_rpe_pct=m.drift_rpe_pct, gravity_error_deg=m.gravity_error_deg,
        nees_over_6=_field(m.nees_pose, "mean_over_dof"),
        fraction_with_estimate=m.fraction_with_estimate, failures=m.failures,
        reinitializations=m.reinitializations, frames_per_s=run.timing.frames_per_s,
        run_dir=str(run.run_dir),
    )  # fmt: skip


def _final_se3(run: OdometryRun) -> Metric:
    ape = (run.final or {}).get("ape_se3")
    if isinstance(ape, dict) and isinstance(ape.get("rmse_m"), int | float):
        return float(ape["rmse_m"])
    return "n/a: no final trajectory scored"


def _numbers(values: Sequence[Metric]) -> list[float]:
    return [float(v) for v in values if not is_na(v) and math.isfinite(float(v))]


def _mean(values: Sequence[Metric], what: str) -> Metric:
    nums = _numbers(values)
    return float(np.mean(nums)) if nums else f"n/a: no run has {what}"


def _median(values: Sequence[Metric], what: str) -> Metric:
    nums = _numbers(values)
    return float(np.median(nums)) if nums else f"n/a: no run has {what}"


def summarize(rows: Sequence[OdometryRow]) -> tuple[OdometryGroup, ...]:
    """Per group (in the order first met): mean and median of each metric over its runs."""
    groups: dict[str, list[OdometryRow]] = {}
    for r in rows:
        groups.setdefault(r.group, []).append(r)
    out = []
    for name, rs in groups.items():
        ate = [r.ate_4dof_rmse_m for r in rs]
        drift = [r.drift_final_pct for r in rs]
        out.append(
            OdometryGroup(
                group=name,
                runs=len(rs),
                runs_without_ate=len(rs) - len(_numbers(ate)),
                ate_mean_m=_mean(ate, "an ATE"),
                ate_median_m=_median(ate, "an ATE"),
                final_ape_se3_mean_m=_mean(
                    [r.final_ape_se3_m for r in rs], "a final trajectory scored"
                ),
                drift_final_mean_pct=_mean(drift, "a drift"),
                drift_final_median_pct=_median(drift, "a drift"),
                drift_rpe_median_pct=_median([r.drift_rpe_pct for r in rs], "an RPE drift"),
                nees_over_6_mean=_mean([r.nees_over_6 for r in rs], "a NEES"),
                failures=sum(r.failures for r in rs),
                reinitializations=sum(r.reinitializations for r in rs),
                frames_per_s_median=float(np.median([r.frames_per_s for r in rs])),
            )
        )
    return tuple(out)


ROW_HEADER = (
    "dataset", "seed", "ATE 4-DoF (m)", "final traj. SE(3) (m)", "final error (m)", "drift final (%)", "drift RPE (%)",
    "gravity (deg)", "NEES/6", "with estimate", "failures", "re-inits", "frames/s",
)  # fmt: skip
GROUP_HEADER = (
    "group", "runs", "ATE mean (m)", "ATE median (m)", "final traj. SE(3) mean (m)",
    "drift mean (%)", "drift median (%)",
    "RPE drift median (%)", "NEES/6 mean", "failures", "re-inits", "frames/s median",
)  # fmt: skip


def _cell(value: Metric, spec: str) -> str:
    """A table cell: the number, or ``n/a`` (the reason stays in ``summary.json``)."""
    return "n/a" if is_na(value) else fmt_metric(value, spec)


def row_cells(r: OdometryRow) -> list[str]:
    return [
        r.dataset, "-" if r.seed is None else str(r.seed), _cell(r.ate_4dof_rmse_m, ".3f"),
        _cell(r.final_ape_se3_m, ".3f"), _cell(r.final_error_m, ".3f"),
        _cell(r.drift_final_pct, ".2f"), _cell(r.drift_rpe_pct, ".2f"),
        _cell(r.gravity_error_deg, ".2f"), _cell(r.nees_over_6, ".2f"),
        f"{100 * r.fraction_with_estimate:.0f} %", str(r.failures), str(r.reinitializations),
        f"{r.frames_per_s:.1f}",
    ]  # fmt: skip


def group_cells(g: OdometryGroup) -> list[str]:
    return [
        g.group, str(g.runs), _cell(g.ate_mean_m, ".3f"), _cell(g.ate_median_m, ".3f"),
        _cell(g.final_ape_se3_mean_m, ".3f"),
        _cell(g.drift_final_mean_pct, ".2f"), _cell(g.drift_final_median_pct, ".2f"),
        _cell(g.drift_rpe_median_pct, ".2f"), _cell(g.nees_over_6_mean, ".2f"),
        str(g.failures), str(g.reinitializations), f"{g.frames_per_s_median:.1f}",
    ]  # fmt: skip


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def summary_markdown(study: OdometryStudy) -> str:
    """The study's two tables (per run, per group) as Markdown."""
    return (
        "## Per group (mean and median over its runs)\n\n"
        + _md_table(GROUP_HEADER, [group_cells(g) for g in study.groups])
        + "\n\n## Per run\n\n"
        + _md_table(ROW_HEADER, [row_cells(r) for r in study.rows])
        + "\n\nATE: APE translation RMSE after a position + yaw alignment. Final traj.: the"
        " final trajectory's (estimate_final.tum, not causal; smoothed with --final-ba) after"
        " SE(3). Drift final: the last"
        " pose's error after aligning the first seconds, in % of the distance travelled (n/a"
        f" under {MIN_DRIFT_DISTANCE_M:g} m travelled); drift RPE: mean RPE over 10 m (1 m on"
        " shorter paths, n/a under 2 m) of path, in % of it.\n"
    )


def run_odometry_study(
    sources: Sequence[str],
    seeds: Sequence[int] | None,
    run_one: RunOne,
    out: Path,
    *,
    is_sequence: Callable[[str], bool],
    kind: str = "vio",
    progress: Progress | None = None,
) -> OdometryStudy:
    """Every source (for a built-in sequence, every seed) through ``run_one``, each into its
    own run folder inside the study's; the tables. Each finished run is appended to
    ``runs.jsonl`` at once, so an interrupted study keeps what it did."""
    plan: list[tuple[str, int | None]] = []
    for src in sources:
        if is_sequence(src):
            plan.extend((src, s) for s in (seeds or (0,)))
        else:
            plan.append((src, None))
    study_dir = create_run_folder(out, f"{kind}_study")
    write_text(study_dir / "config.yaml", f"sources: {list(sources)}\nseeds: {list(seeds or [])}\n")
    rows = []
    for k, (src, seed) in enumerate(plan):
        if progress is not None:
            progress(k, len(plan), f"{group_of(src)} seed {seed if seed is not None else '-'}")
        run = run_one(src, seed or 0, study_dir / "runs")
        rows.append(row_of(run, group_of(src), seed))
        append_jsonl(study_dir / "runs.jsonl", asdict(rows[-1]))
    if progress is not None:
        progress(len(plan), len(plan), "done")
    study = OdometryStudy(rows=tuple(rows), groups=summarize(rows), run_dir=study_dir)
    write_json(study_dir / "summary.json", study.as_json())
    write_text(study_dir / "summary.md", summary_markdown(study))
    return study
