"""Evaluation: association, alignment, APE/RPE/NEES, plots and run reports, over trajectories and
arrays. It runs nothing: the studies that produce the runs are in :mod:`quadnav.experiments`."""

from __future__ import annotations

from typing import TYPE_CHECKING

# Light and needed by every evaluation; align and associate are also submodule names, so the
# functions must be bound here, after their modules.
from quadnav.errors import EvalError
from quadnav.eval.align import Alignment, AlignMethod, align, umeyama, yaw_translation
from quadnav.eval.associate import associate
from quadnav.eval.metrics import (
    ErrorStats,
    PoseRelation,
    RpeUnit,
    ape,
    ape_matrices,
    error_stats,
    nees,
    nis,
    pose_errors,
    position_nees,
    rpe,
    rpe_matrices,
    rpe_pairs,
    settling_time_s,
)
from quadnav.lazy import lazy_getattr

if TYPE_CHECKING:
    from quadnav.eval.evaluate import (
        EstimateMetrics,
        EstimateResult,
        EvalOptions,
        EvalRun,
        evaluate_pair,
        run_eval,
    )
    from quadnav.eval.planar import planar_trajectory, plot_monte_carlo, summarize_seeds
    from quadnav.eval.plots import plot_errors, plot_trajectories, plot_xyz
    from quadnav.eval.report import ReportSection, ReportTable, write_report
    from quadnav.eval.runs import RunRow, compare_runs, format_table

__all__ = [
    "AlignMethod",
    "Alignment",
    "ErrorStats",
    "EstimateMetrics",
    "EstimateResult",
    "EvalError",
    "EvalOptions",
    "EvalRun",
    "PoseRelation",
    "ReportSection",
    "ReportTable",
    "RpeUnit",
    "RunRow",
    "align",
    "ape",
    "ape_matrices",
    "associate",
    "compare_runs",
    "error_stats",
    "evaluate_pair",
    "format_table",
    "nees",
    "nis",
    "planar_trajectory",
    "plot_errors",
    "plot_monte_carlo",
    "plot_trajectories",
    "plot_xyz",
    "pose_errors",
    "position_nees",
    "rpe",
    "rpe_matrices",
    "rpe_pairs",
    "run_eval",
    "settling_time_s",
    "summarize_seeds",
    "umeyama",
    "write_report",
    "yaw_translation",
]

# The module of each other name: they load on first use, so ``quadnav eval`` does not import the
# plots (matplotlib) it does not need.
_WHERE: dict[str, str] = {
    "EstimateMetrics": "quadnav.eval.evaluate",
    "EstimateResult": "quadnav.eval.evaluate",
    "EvalOptions": "quadnav.eval.evaluate",
    "EvalRun": "quadnav.eval.evaluate",
    "ReportSection": "quadnav.eval.report",
    "ReportTable": "quadnav.eval.report",
    "RunRow": "quadnav.eval.runs",
    "compare_runs": "quadnav.eval.runs",
    "evaluate_pair": "quadnav.eval.evaluate",
    "format_table": "quadnav.eval.runs",
    "planar_trajectory": "quadnav.eval.planar",
    "plot_errors": "quadnav.eval.plots",
    "plot_monte_carlo": "quadnav.eval.planar",
    "plot_trajectories": "quadnav.eval.plots",
    "plot_xyz": "quadnav.eval.plots",
    "run_eval": "quadnav.eval.evaluate",
    "summarize_seeds": "quadnav.eval.planar",
    "write_report": "quadnav.eval.report",
}


__getattr__ = lazy_getattr(__name__, _WHERE)


def __dir__() -> list[str]:
    return sorted(__all__)
