"""VINS-Mono's 4-DoF relative pose error (``FourDOFError`` of its ``pose_graph.h``), ours.

A keyframe's variable is ``x = (x, y, z, yaw)`` in the map; its roll and pitch stay what the
odometry gave (gravity makes them observable), as the tilt ``R_tilt`` with
``R = rot_z(yaw) @ R_tilt``. An edge from keyframe i to keyframe j measures the position of j
in i's frame, ``t_ij`` (i's full rotation, its tilt held), and the yaw difference ``dyaw``:

    e_p   = R_i^T (p_j - p_i) - t_ij,   R_i = rot_z(yaw_i) R_tilt_i
    e_yaw = wrap(yaw_j - yaw_i - dyaw)

The Jacobians are analytic (tested against central differences). :func:`four_dof_factor` makes
it a ``gtsam.CustomFactor`` on two ``Vector4`` variables: a plain vector (its retraction is an
addition, the residual wraps the yaw) keeps the factor's Jacobians exact and the variable free of
roll and pitch, which a Pose3 variable would have to be held to by stiff priors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.rotations import Pose, rot_z, yaw_of

__all__ = ["FourDofMeasurement", "four_dof_error", "four_dof_factor", "split_yaw"]

FloatArray = NDArray[np.float64]


def split_yaw(R: FloatArray) -> tuple[float, FloatArray]:
    """``R`` as its z-y-x yaw and the tilt (pitch and roll) left: ``R = rot_z(yaw) @ R_tilt``."""
    yaw = yaw_of(R)
    return yaw, rot_z(-yaw) @ R


@dataclass(frozen=True, slots=True, kw_only=True)
class FourDofMeasurement:
    """A 4-DoF edge's measurement: ``t_ij`` (j's position in i's frame), ``dyaw_rad`` (j's yaw
    minus i's) and i's tilt ``R_tilt_i``, held."""

    t_ij: FloatArray
    dyaw_rad: float
    R_tilt_i: FloatArray

    @classmethod
    def between(cls, T_W_i: Pose, T_W_j: Pose) -> FourDofMeasurement:
        """The measurement two poses in one frame make (an odometry's sequential edge; a loop
        edge is ``between(T_O_old, T_O_old @ T_old_new)``)."""
        R_i = T_W_i.R_A_B.as_matrix()
        yaw_i, tilt_i = split_yaw(R_i)
        yaw_j = yaw_of(T_W_j.R_A_B.as_matrix())
        t = R_i.T @ (T_W_j.p_A_B - T_W_i.p_A_B)
        return cls(t_ij=t, dyaw_rad=math.remainder(yaw_j - yaw_i, 2 * math.pi), R_tilt_i=tilt_i)


def four_dof_error(
    x_i: FloatArray, x_j: FloatArray, m: FourDofMeasurement
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The residual (4,) of ``m`` at ``x_i``, ``x_j`` (each ``(x, y, z, yaw)``) and its
    Jacobians (4, 4) with respect to each."""
    c, s = math.cos(x_i[3]), math.sin(x_i[3])
    d = x_j[:3] - x_i[:3]
    RzT = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    dRzT = np.array([[-s, c, 0.0], [-c, -s, 0.0], [0.0, 0.0, 0.0]])
    RiT = m.R_tilt_i.T @ RzT
    e = np.empty(4)
    e[:3] = RiT @ d - m.t_ij
    e[3] = math.remainder(x_j[3] - x_i[3] - m.dyaw_rad, 2 * math.pi)
    H_i = np.zeros((4, 4))
    H_j = np.zeros((4, 4))
    H_i[:3, :3] = -RiT
    H_j[:3, :3] = RiT
    H_i[:3, 3] = m.R_tilt_i.T @ (dRzT @ d)
    H_i[3, 3] = -1.0
    H_j[3, 3] = 1.0
    return e, H_i, H_j


def four_dof_factor(
    key_i: int, key_j: int, m: FourDofMeasurement, noise: gtsam.noiseModel.Base
) -> gtsam.CustomFactor:
    """The 4-DoF edge as a ``gtsam.CustomFactor`` on ``Vector4`` variables ``key_i``, ``key_j``."""

    def error(_: Any, values: gtsam.Values, H: list[FloatArray] | None) -> FloatArray:
        e, H_i, H_j = four_dof_error(values.atVector(key_i), values.atVector(key_j), m)
        if H is not None:
            H[0] = H_i
            H[1] = H_j
        return e

    return gtsam.CustomFactor(noise, gtsam.KeyVector([key_i, key_j]), error)
