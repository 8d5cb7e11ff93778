"""Frame conventions at the PX4 boundary: ENU/FLU inside quadnav, NED/FRD outside.

World ``W`` is ENU and body ``B`` is FLU everywhere in the library. PX4, MAVLink and
ULog speak NED (world) and FRD (body); ``io/`` converts with these functions and nothing
else does. Every conversion here is its own inverse, and they act on vectors (..., 3),
on rotations (``R_ENU_FLU`` <-> ``R_NED_FRD``) and on poses.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import GeometryError
from quadnav.geometry.rotations import Pose

__all__ = [
    "R_FLU_FRD",
    "R_NED_ENU",
    "enu_to_ned",
    "flu_to_frd",
    "frd_to_flu",
    "ned_to_enu",
    "pose_enu_flu_to_ned_frd",
    "pose_ned_frd_to_enu_flu",
    "rotation_enu_flu_to_ned_frd",
    "rotation_ned_frd_to_enu_flu",
]

FloatArray = NDArray[np.float64]

#: NED axes expressed from ENU axes: north = y_enu, east = x_enu, down = -z_enu.
R_NED_ENU: FloatArray = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: FLU from FRD (and FRD from FLU): y and z flip.
R_FLU_FRD: FloatArray = np.diag([1.0, -1.0, -1.0])

_ROT_NED_ENU = Rotation.from_matrix(R_NED_ENU)
_ROT_FLU_FRD = Rotation.from_matrix(R_FLU_FRD)


def _vectors(v: ArrayLike) -> FloatArray:
    arr = np.asarray(v, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise GeometryError(f"vectors must have a last axis of length 3, got shape {arr.shape}")
    return arr


def enu_to_ned(v_enu: ArrayLike) -> FloatArray:
    """World vectors (..., 3) from ENU to NED."""
    v = _vectors(v_enu)
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


def ned_to_enu(v_ned: ArrayLike) -> FloatArray:
    """World vectors (..., 3) from NED to ENU (the same swap: the map is an involution)."""
    return enu_to_ned(v_ned)


def flu_to_frd(v_flu: ArrayLike) -> FloatArray:
    """Body vectors (..., 3) from FLU to FRD."""
    v = _vectors(v_flu)
    return np.stack([v[..., 0], -v[..., 1], -v[..., 2]], axis=-1)


def frd_to_flu(v_frd: ArrayLike) -> FloatArray:
    """Body vectors (..., 3) from FRD to FLU."""
    return flu_to_frd(v_frd)


def rotation_enu_flu_to_ned_frd(R_ENU_FLU: Rotation) -> Rotation:
    """Attitude of an FLU body in ENU -> attitude of the same body, as FRD, in NED."""
    return _ROT_NED_ENU * R_ENU_FLU * _ROT_FLU_FRD


def rotation_ned_frd_to_enu_flu(R_NED_FRD: Rotation) -> Rotation:
    """Attitude of an FRD body in NED -> attitude of the same body, as FLU, in ENU."""
    return _ROT_NED_ENU * R_NED_FRD * _ROT_FLU_FRD


def pose_enu_flu_to_ned_frd(T_ENU_FLU: Pose) -> Pose:
    """``T_NED_FRD = T_NED_ENU @ T_ENU_FLU @ T_FLU_FRD`` (both extra transforms are pure rotations)."""
    return Pose(rotation_enu_flu_to_ned_frd(T_ENU_FLU.R_A_B), enu_to_ned(T_ENU_FLU.p_A_B))


def pose_ned_frd_to_enu_flu(T_NED_FRD: Pose) -> Pose:
    """``T_ENU_FLU`` from ``T_NED_FRD``."""
    return Pose(rotation_ned_frd_to_enu_flu(T_NED_FRD.R_A_B), ned_to_enu(T_NED_FRD.p_A_B))
