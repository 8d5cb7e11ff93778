from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from quadnav.errors import GeometryError
from quadnav.geometry import Pose, geodesic_angle_rad, quat_wxyz_to_xyzw, quat_xyzw_to_wxyz, rot_y
from quadnav.geometry.rotations import compose_quats_xyzw, rot_z, unit_quats_xyzw, yaw_of

finite = st.floats(-100.0, 100.0, allow_nan=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)
quat = (
    st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 4)
    .map(np.array)
    .filter(lambda q: np.linalg.norm(q) > 0.1)
)
poses = st.builds(lambda q, p: Pose(Rotation.from_quat(q), p), quat, vec3)


def assert_pose_close(a: Pose, b: Pose, *, atol: float = 1e-9) -> None:
    assert geodesic_angle_rad(a.R_A_B, b.R_A_B) < 1e-9
    np.testing.assert_allclose(a.p_A_B, b.p_A_B, atol=atol)


@given(poses)
def test_inverse_composes_to_identity(T_A_B: Pose) -> None:
    assert_pose_close(T_A_B @ T_A_B.inverse(), Pose.identity(), atol=1e-9 * 100)


@given(poses, poses, vec3)
def test_composition_maps_points_like_successive_maps(
    T_A_B: Pose, T_B_C: Pose, p_C: np.ndarray
) -> None:
    T_A_C = T_A_B @ T_B_C
    np.testing.assert_allclose(T_A_C @ p_C, T_A_B @ (T_B_C @ p_C), atol=1e-9)


@given(poses, poses, poses)
@settings(max_examples=50)
def test_composition_is_associative(a: Pose, b: Pose, c: Pose) -> None:
    assert_pose_close((a @ b) @ c, a @ (b @ c), atol=1e-8)


@given(poses)
def test_matrix_round_trip(T: Pose) -> None:
    assert_pose_close(Pose.from_matrix(T.matrix()), T)


@given(poses, st.tuples(*[st.floats(-0.5, 0.5)] * 6).map(np.array))
@settings(max_examples=50)
def test_the_adjoint_moves_a_perturbation_from_the_right_to_the_left(
    T: Pose, xi: np.ndarray
) -> None:
    """``T Exp(xi) = Exp(Ad xi) T`` on SE(3) (rotation first), checked on the matrices."""
    from scipy.linalg import expm

    def hat(x: np.ndarray) -> np.ndarray:
        w, v = x[:3], x[3:]
        M = np.zeros((4, 4))
        M[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
        M[:3, 3] = v
        return M

    left = T.matrix() @ expm(hat(xi))
    right = expm(hat(T.adjoint() @ xi)) @ T.matrix()
    np.testing.assert_allclose(left, right, atol=1e-8 * (1 + np.abs(T.p_A_B).max()))


def test_point_mapping_known_value() -> None:
    # B yawed 90 degrees in A and offset by (1, 2, 3): B's x axis points along A's y.
    T_A_B = Pose(Rotation.from_euler("z", 90, degrees=True), np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(T_A_B @ np.array([1.0, 0.0, 0.0]), [1.0, 3.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(
        T_A_B.inverse() @ np.array([1.0, 3.0, 3.0]), [1.0, 0.0, 0.0], atol=1e-12
    )


def test_rot_y_turns_thrust_towards_plus_x() -> None:
    R = rot_y(np.pi / 6)
    np.testing.assert_allclose(R @ [0.0, 0.0, 1.0], [0.5, 0.0, np.sqrt(3) / 2], atol=1e-12)
    np.testing.assert_allclose(
        R, Rotation.from_euler("y", 30, degrees=True).as_matrix(), atol=1e-12
    )


@given(quat)
def test_quaternion_reorder_round_trip(q: np.ndarray) -> None:
    wxyz = quat_xyzw_to_wxyz(q)
    assert wxyz[0] == q[3]
    np.testing.assert_array_equal(quat_wxyz_to_xyzw(wxyz), q)


@pytest.mark.parametrize(
    "bad",
    [
        np.eye(3),
        np.diag([1.0, 1.0, -1.0, 1.0]),
        np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], dtype=float),
        np.full((4, 4), np.nan),
    ],
)
def test_bad_pose_matrices_are_refused(bad: np.ndarray) -> None:
    with pytest.raises(GeometryError):
        Pose.from_matrix(bad)


def test_bad_translation_is_refused() -> None:
    with pytest.raises(GeometryError, match="finite"):
        Pose(Rotation.identity(), np.array([0.0, np.inf, 0.0]))
    with pytest.raises(GeometryError, match="shape"):
        Pose(Rotation.identity(), np.zeros(2))


@given(vec3.map(lambda v: v / 40.0))  # rotation vectors up to |v| ~ 4.3 rad
def test_so3_exp_log_and_quaternion_helpers_match_scipy(rv: np.ndarray) -> None:
    from quadnav.geometry import quat_xyzw_from_matrix, so3_exp, so3_log

    R = Rotation.from_rotvec(rv)
    np.testing.assert_allclose(so3_exp(rv), R.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(so3_exp(rv[None, :])[0], R.as_matrix(), atol=1e-12)  # batched path
    if np.linalg.norm(rv) < np.pi - 1e-3:
        np.testing.assert_allclose(so3_log(R.as_matrix()), rv, atol=1e-9)
    q = quat_xyzw_from_matrix(R.as_matrix())
    assert geodesic_angle_rad(Rotation.from_quat(q), R) < 1e-9


def test_composed_quaternions_are_scipys_to_the_bit() -> None:
    """compose_quats_xyzw stands in for Rotation.__mul__ where its results feed an estimate
    (the time offset's prefix scan): it must round as SciPy does, near the identity too, and
    broadcast one rotation over many."""
    rng = np.random.default_rng(7)
    for scale in (1.0, 1e-4):
        a, b = rng.normal(size=(5000, 4)), rng.normal(size=(5000, 4))
        a[:, :3] *= scale
        b[:, :3] *= scale * 3.0
        want = (Rotation.from_quat(a) * Rotation.from_quat(b)).as_quat()
        got = compose_quats_xyzw(unit_quats_xyzw(a), unit_quats_xyzw(b))
        assert np.array_equal(got, want)
        assert np.array_equal(unit_quats_xyzw(a), Rotation.from_quat(a).as_quat())
    one = (Rotation.from_quat(a[0]) * Rotation.from_quat(b)).as_quat()
    assert np.array_equal(compose_quats_xyzw(unit_quats_xyzw(a[0]), unit_quats_xyzw(b)), one)


@given(st.floats(-3.1, 3.1), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1))
@settings(max_examples=50, deadline=None)
def test_rot_z_and_yaw_of_agree_with_scipy_zyx(yaw: float, pitch: float, roll: float) -> None:
    R = Rotation.from_euler("ZYX", [yaw, pitch, roll])
    np.testing.assert_allclose(rot_z(yaw), Rotation.from_euler("z", yaw).as_matrix(), atol=1e-12)
    assert yaw_of(R.as_matrix()) == pytest.approx(yaw, abs=1e-9)
