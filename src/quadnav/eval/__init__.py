"""Evaluation: error metrics, plots and run reports."""

from quadnav.errors import EvalError
from quadnav.eval.metrics import nees, position_rmse
from quadnav.eval.planar import (
    PlanarStudy,
    planar_metrics,
    plot_monte_carlo,
    plot_planar_run,
    run_planar_study,
    summarize_seeds,
)

__all__ = [
    "EvalError",
    "PlanarStudy",
    "nees",
    "planar_metrics",
    "plot_monte_carlo",
    "plot_planar_run",
    "position_rmse",
    "run_planar_study",
    "summarize_seeds",
]
