from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from quadnav.errors import GeometryError
from quadnav.geometry import (
    Pose,
    enu_to_ned,
    flu_to_frd,
    frd_to_flu,
    geodesic_angle_rad,
    ned_to_enu,
    pose_enu_flu_to_ned_frd,
    pose_ned_frd_to_enu_flu,
    rotation_enu_flu_to_ned_frd,
    rotation_ned_frd_to_enu_flu,
)

finite = st.floats(-1e3, 1e3, allow_nan=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)
rotations = (
    st.tuples(*[st.floats(-1.0, 1.0)] * 4)
    .filter(lambda q: np.linalg.norm(q) > 0.1)
    .map(lambda q: Rotation.from_quat(q))
)
poses = st.builds(Pose, rotations, vec3)


@given(vec3)
def test_vector_conversions_round_trip(v: np.ndarray) -> None:
    np.testing.assert_array_equal(ned_to_enu(enu_to_ned(v)), v)
    np.testing.assert_array_equal(frd_to_flu(flu_to_frd(v)), v)


def test_vector_conversion_known_values() -> None:
    # 1 m east, 2 m north, 3 m up is 2 m north, 1 m east, 3 m *down*-negative in NED.
    np.testing.assert_array_equal(enu_to_ned([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    # Forward stays forward; left becomes minus right; up becomes minus down.
    np.testing.assert_array_equal(flu_to_frd([1.0, 2.0, 3.0]), [1.0, -2.0, -3.0])
    # Batched input keeps its shape.
    assert enu_to_ned(np.zeros((5, 2, 3))).shape == (5, 2, 3)


@given(rotations)
def test_rotation_conversion_round_trip(R: Rotation) -> None:
    back = rotation_ned_frd_to_enu_flu(rotation_enu_flu_to_ned_frd(R))
    assert geodesic_angle_rad(back, R) < 1e-9


@given(poses, vec3)
def test_pose_conversion_agrees_with_point_conversion(T_ENU_FLU: Pose, p_FLU: np.ndarray) -> None:
    """Mapping a body point and then converting equals converting first and mapping in NED/FRD."""
    T_NED_FRD = pose_enu_flu_to_ned_frd(T_ENU_FLU)
    np.testing.assert_allclose(
        T_NED_FRD @ flu_to_frd(p_FLU), enu_to_ned(T_ENU_FLU @ p_FLU), atol=1e-9
    )
    back = pose_ned_frd_to_enu_flu(T_NED_FRD)
    assert geodesic_angle_rad(back.R_A_B, T_ENU_FLU.R_A_B) < 1e-9
    np.testing.assert_allclose(back.p_A_B, T_ENU_FLU.p_A_B, atol=1e-12)


@given(poses, poses)
def test_conversion_commutes_with_composition(T_W_B: Pose, T_B_C: Pose) -> None:
    """Converting a composed pose equals composing in NED when the inner pose is FRD-to-FRD."""
    lhs = pose_enu_flu_to_ned_frd(T_W_B @ T_B_C)
    # T_FRD_FRD' = T_FRD_FLU @ T_FLU_FLU' @ T_FLU'_FRD'
    flip = Pose(Rotation.from_matrix(np.diag([1.0, -1.0, -1.0])), np.zeros(3))
    rhs = pose_enu_flu_to_ned_frd(T_W_B) @ (flip @ T_B_C @ flip)
    assert geodesic_angle_rad(lhs.R_A_B, rhs.R_A_B) < 1e-9
    np.testing.assert_allclose(lhs.p_A_B, rhs.p_A_B, atol=1e-9)


@pytest.mark.parametrize(
    ("yaw_enu_deg", "yaw_ned_deg"), [(0.0, 90.0), (90.0, 0.0), (180.0, -90.0), (-90.0, 180.0)]
)
def test_heading_known_values(yaw_enu_deg: float, yaw_ned_deg: float) -> None:
    """ENU yaw is from east, counter-clockwise; NED yaw is from north, clockwise."""
    R = rotation_enu_flu_to_ned_frd(Rotation.from_euler("z", yaw_enu_deg, degrees=True))
    expected = Rotation.from_euler("z", yaw_ned_deg, degrees=True)
    assert geodesic_angle_rad(R, expected) < 1e-9


def test_bad_vectors_are_refused() -> None:
    with pytest.raises(GeometryError):
        enu_to_ned([1.0, 2.0])
    with pytest.raises(GeometryError):
        flu_to_frd(3.0)
