"""Pose graphs in GTSAM: VINS-Mono's 4-DoF graph (x, y, z, yaw; roll and pitch held at the
odometry's) with our 4-DoF factor, SE(3) and Sim(3) graphs, and a background optimiser that takes
keyframes and loop edges as they come and publishes the drift correction ``T_M_O``.

GTSAM loads with this package (its modules build factor graphs); nothing below ``loop/`` and
``slam/`` imports it."""

from quadnav.errors import PoseGraphError
from quadnav.posegraph.background import BackgroundPoseGraph, Executor
from quadnav.posegraph.fourdof import (
    FourDofMeasurement,
    four_dof_error,
    four_dof_factor,
    split_yaw,
)
from quadnav.posegraph.graphs import (
    anchors,
    build_graph,
    levenberg_marquardt,
    sequential_covariances,
    sequential_pairs,
    solve,
)
from quadnav.posegraph.types import (
    DriftCorrection,
    FourDofFactor,
    GraphKind,
    LoopEdge,
    PoseGraphConfig,
    PoseGraphProblem,
    PoseGraphResult,
    RobustKernel,
)

__all__ = [
    "BackgroundPoseGraph",
    "DriftCorrection",
    "Executor",
    "FourDofFactor",
    "FourDofMeasurement",
    "GraphKind",
    "LoopEdge",
    "PoseGraphConfig",
    "PoseGraphError",
    "PoseGraphProblem",
    "PoseGraphResult",
    "RobustKernel",
    "anchors",
    "build_graph",
    "four_dof_error",
    "four_dof_factor",
    "levenberg_marquardt",
    "sequential_covariances",
    "sequential_pairs",
    "solve",
    "split_yaw",
]
