"""Closed-loop experiments: a simulator, its controllers and an estimator wired together."""

from quadnav.errors import ExperimentError
from quadnav.experiments.planar import (
    EXPERIMENTS,
    ExperimentName,
    PlanarConfig,
    PlanarRun,
    run_planar,
)

__all__ = [
    "EXPERIMENTS",
    "ExperimentError",
    "ExperimentName",
    "PlanarConfig",
    "PlanarRun",
    "run_planar",
]
