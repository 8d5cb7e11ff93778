"""Evaluation: association, alignment, APE/RPE/NEES, plots, run reports and the planar study."""

from quadnav.errors import EvalError
from quadnav.eval.align import Alignment, AlignMethod, align, umeyama, yaw_translation
from quadnav.eval.associate import associate
from quadnav.eval.evaluate import (
    EstimateResult,
    EvalOptions,
    EvalRun,
    compare_runs,
    evaluate_pair,
    format_table,
    run_eval,
)
from quadnav.eval.metrics import (
    PoseRelation,
    RpeUnit,
    ape,
    error_stats,
    nees,
    nis,
    position_nees,
    rpe,
    rpe_pairs,
)
from quadnav.eval.planar import (
    PlanarStudy,
    planar_metrics,
    planar_trajectory,
    plot_monte_carlo,
    plot_planar_run,
    run_planar_study,
    summarize_seeds,
)
from quadnav.eval.plots import plot_errors, plot_trajectories, plot_xyz
from quadnav.eval.report import ReportSection, ReportTable, write_report

__all__ = [
    "AlignMethod",
    "Alignment",
    "EstimateResult",
    "EvalError",
    "EvalOptions",
    "EvalRun",
    "PlanarStudy",
    "PoseRelation",
    "ReportSection",
    "ReportTable",
    "RpeUnit",
    "align",
    "ape",
    "associate",
    "compare_runs",
    "error_stats",
    "evaluate_pair",
    "format_table",
    "nees",
    "nis",
    "planar_metrics",
    "planar_trajectory",
    "plot_errors",
    "plot_monte_carlo",
    "plot_planar_run",
    "plot_trajectories",
    "plot_xyz",
    "position_nees",
    "rpe",
    "rpe_pairs",
    "run_eval",
    "run_planar_study",
    "summarize_seeds",
    "umeyama",
    "write_report",
    "yaw_translation",
]
