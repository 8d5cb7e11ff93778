"""The exception hierarchy: one root, one subclass per package.

The command line maps every :class:`QuadnavError` to exit code 2 and a one-line message;
anything else escaping to the user is a bug.
"""

from __future__ import annotations

__all__ = [
    "ConfigError",
    "ControlError",
    "EstimationError",
    "EvalError",
    "ExperimentError",
    "GeometryError",
    "IoError",
    "LoopError",
    "PlaceError",
    "PoseGraphError",
    "QuadnavError",
    "SampleError",
    "SimError",
    "SlamError",
    "VioError",
    "VisionError",
    "VizError",
]


class QuadnavError(Exception):
    """Root of every error quadnav raises on purpose."""


class GeometryError(QuadnavError):
    """Bad rotation, pose or frame input."""


class SampleError(QuadnavError):
    """A sample with a wrong shape, a non-finite value or a bad timestamp."""


class SimError(QuadnavError):
    """The simulator was given an impossible setting or reached an invalid state."""


class EstimationError(QuadnavError):
    """An estimator was misconfigured or fed something it cannot use."""


class ControlError(QuadnavError):
    """A controller was misconfigured."""


class ExperimentError(QuadnavError):
    """A scenario or experiment could not be assembled."""


class IoError(QuadnavError):
    """A file, folder or link could not be read or written."""


class ConfigError(IoError):
    """A configuration file or override is malformed or holds an impossible value."""


class EvalError(QuadnavError):
    """Evaluation inputs do not fit together."""


class VisionError(QuadnavError):
    """A camera model, dictionary, marker map or image the vision code cannot use."""


class VioError(QuadnavError):
    """Visual-inertial odometry was misconfigured or fed a camera or IMU it cannot use."""


class PlaceError(QuadnavError):
    """Place recognition was given descriptors it cannot use, or a vocabulary file that is
    missing, corrupt or not a quadnav vocabulary."""


class PoseGraphError(QuadnavError):
    """A pose graph was misconfigured or given a pose, an edge or a covariance it cannot use."""


class LoopError(QuadnavError):
    """Loop closure was misconfigured, or given a map it cannot use."""


class SlamError(QuadnavError):
    """The visual SLAM (``slam/``): a bad setting, an unusable frame."""


class VizError(QuadnavError):
    """A recording (rerun) could not be built: the extra is missing, or the folder is not one
    it can show."""
