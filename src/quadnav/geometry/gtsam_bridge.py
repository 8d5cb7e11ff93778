"""The one bridge between quadnav's poses and GTSAM's: ``geometry.Pose`` (``T_A_B``, a SciPy
rotation and a position) to and from ``gtsam.Pose3``. Only code that builds factor graphs imports
this module (``geometry/__init__`` does not), so the maths does not load GTSAM."""

from __future__ import annotations

from typing import Any

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.geometry.rotations import Pose

__all__ = ["pose3", "to_pose"]


def pose3(p: Pose) -> gtsam.Pose3:
    """``p`` as GTSAM's ``Pose3``."""
    return gtsam.Pose3(gtsam.Rot3(p.R_A_B.as_matrix()), np.asarray(p.p_A_B, np.float64))


def to_pose(p: gtsam.Pose3) -> Pose:
    """GTSAM's ``Pose3`` as a ``Pose`` (through the quaternion: no re-orthonormalisation)."""
    q: Any = p.rotation().toQuaternion()  # the stubs leave GTSAM's Quaternion unresolved
    return Pose(
        Rotation.from_quat([q.x(), q.y(), q.z(), q.w()]),
        np.array(p.translation(), dtype=np.float64),
    )
