"""Rotations, poses (``T_A_B``) and frame conversions (ENU/FLU <-> NED/FRD)."""

from quadnav.errors import GeometryError
from quadnav.geometry.frames import (
    R_FLU_FRD,
    R_NED_ENU,
    enu_to_ned,
    flu_to_frd,
    frd_to_flu,
    ned_to_enu,
    pose_enu_flu_to_ned_frd,
    pose_ned_frd_to_enu_flu,
    rotation_enu_flu_to_ned_frd,
    rotation_ned_frd_to_enu_flu,
)
from quadnav.geometry.rotations import (
    Pose,
    cross3,
    geodesic_angle_rad,
    quat_wxyz_to_xyzw,
    quat_xyzw_from_matrix,
    quat_xyzw_to_wxyz,
    rot_y,
    rotation_matrix_xyzw,
    so3_exp,
    so3_log,
)
from quadnav.geometry.trajectory import Trajectory

__all__ = [
    "R_FLU_FRD",
    "R_NED_ENU",
    "GeometryError",
    "Pose",
    "Trajectory",
    "cross3",
    "enu_to_ned",
    "flu_to_frd",
    "frd_to_flu",
    "geodesic_angle_rad",
    "ned_to_enu",
    "pose_enu_flu_to_ned_frd",
    "pose_ned_frd_to_enu_flu",
    "quat_wxyz_to_xyzw",
    "quat_xyzw_from_matrix",
    "quat_xyzw_to_wxyz",
    "rot_y",
    "rotation_enu_flu_to_ned_frd",
    "rotation_matrix_xyzw",
    "rotation_ned_frd_to_enu_flu",
    "so3_exp",
    "so3_log",
]
