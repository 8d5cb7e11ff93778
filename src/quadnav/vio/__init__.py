"""Monocular visual-inertial odometry of the VINS-Mono class (thesis 003): a KLT front end with
keyframes chosen by parallax, GTSAM's IMU preintegration, a static or visual-inertial
initialisation, a sliding-window smoother over explicit landmarks, failure detection and
re-initialisation, and the camera-IMU time offset estimated online."""

from quadnav.vio.config import VioConfig
from quadnav.vio.estimator import VioEstimator
from quadnav.vio.types import (
    FrameFeatures,
    InitResult,
    InitWindow,
    StageTiming,
    VioEvent,
    VioState,
    VisualOdometry,
)

__all__ = [
    "FrameFeatures",
    "InitResult",
    "InitWindow",
    "StageTiming",
    "VioConfig",
    "VioEstimator",
    "VioEvent",
    "VioState",
    "VisualOdometry",
]
