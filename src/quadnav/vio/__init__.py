"""Monocular visual-inertial odometry of the VINS-Mono class (thesis 003): a KLT front end with
keyframes chosen by parallax, GTSAM's IMU preintegration, a static or visual-inertial
initialisation, a sliding-window smoother over explicit landmarks, failure detection and
re-initialisation, and the camera-IMU time offset estimated online.

Every name loads on first use: importing a submodule (``quadnav.vio.config``, which a scenario's
``vio`` section is validated by) does not import GTSAM or OpenCV."""

from __future__ import annotations

from typing import TYPE_CHECKING

from quadnav.lazy import lazy_getattr

if TYPE_CHECKING:
    from quadnav.vio.config import VioConfig
    from quadnav.vio.estimator import VioEstimator
    from quadnav.vio.types import (
        InitResult,
        InitWindow,
    )

__all__ = [
    "InitResult",
    "InitWindow",
    "VioConfig",
    "VioEstimator",
]

# The module of each name (GTSAM behind the estimator and the types, OpenCV behind the front end).
_WHERE: dict[str, str] = {
    "InitResult": "quadnav.vio.types",
    "InitWindow": "quadnav.vio.types",
    "VioConfig": "quadnav.vio.config",
    "VioEstimator": "quadnav.vio.estimator",
}


__getattr__ = lazy_getattr(__name__, _WHERE)


def __dir__() -> list[str]:
    return sorted(__all__)
