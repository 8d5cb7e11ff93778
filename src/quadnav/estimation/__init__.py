"""Estimators: the delayed-horizon core with its output predictor, and the filters on it."""

from quadnav.errors import EstimationError
from quadnav.estimation.floor import reintegration_floor
from quadnav.estimation.horizon import (
    DelayedFilter,
    DelayedHorizonEstimator,
    Estimator,
    FusionRecord,
    FusionResult,
    HorizonConfig,
    Kinematics,
    NavState,
    SourceStats,
    imu_buffer_length,
)
from quadnav.estimation.planar_ekf import (
    AccelModel,
    PlanarEkf,
    PlanarEkfConfig,
    PlanarKinematics,
    planar_jacobians,
)

__all__ = [
    "AccelModel",
    "DelayedFilter",
    "DelayedHorizonEstimator",
    "EstimationError",
    "Estimator",
    "FusionRecord",
    "FusionResult",
    "HorizonConfig",
    "Kinematics",
    "NavState",
    "PlanarEkf",
    "PlanarEkfConfig",
    "PlanarKinematics",
    "SourceStats",
    "imu_buffer_length",
    "planar_jacobians",
    "reintegration_floor",
]
