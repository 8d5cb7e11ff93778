"""VINS-Mono's 4-DoF error: analytic Jacobians against central differences, its zero at the poses
it was measured from, the yaw split and wrap, and the GTSAM factor's linearisation."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.geometry.rotations import Pose, rot_z, yaw_of
from quadnav.posegraph import FourDofMeasurement, four_dof_error, four_dof_factor, split_yaw

SEEDS = range(5)


def _random_pose(rng: np.random.Generator) -> Pose:
    ypr = [rng.uniform(-math.pi, math.pi), rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4)]
    return Pose(Rotation.from_euler("ZYX", ypr), rng.normal(0.0, 3.0, 3))


def _x(p: Pose) -> np.ndarray:
    return np.array([*p.p_A_B, yaw_of(p.R_A_B.as_matrix())])


def _numerical(f, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for k in range(len(x)):
        d = np.zeros_like(x)
        d[k] = eps
        cols.append((f(x + d) - f(x - d)) / (2 * eps))
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("seed", SEEDS)
def test_jacobians_match_central_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    m = FourDofMeasurement.between(_random_pose(rng), _random_pose(rng))
    x_i, x_j = rng.normal(0.0, 2.0, 4), rng.normal(0.0, 2.0, 4)
    x_j[3] = x_i[3] + m.dyaw_rad + rng.uniform(-1.0, 1.0)  # the yaw residual away from the wrap
    _, H_i, H_j = four_dof_error(x_i, x_j, m)
    np.testing.assert_allclose(
        H_i, _numerical(lambda x: four_dof_error(x, x_j, m)[0], x_i), atol=1e-7
    )
    np.testing.assert_allclose(
        H_j, _numerical(lambda x: four_dof_error(x_i, x, m)[0], x_j), atol=1e-7
    )


@pytest.mark.parametrize("seed", SEEDS)
def test_error_is_zero_at_the_poses_measured_and_not_elsewhere(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T_i, T_j = _random_pose(rng), _random_pose(rng)
    m = FourDofMeasurement.between(T_i, T_j)
    e, _, _ = four_dof_error(_x(T_i), _x(T_j), m)
    np.testing.assert_allclose(e, 0.0, atol=1e-12)
    # the measured position is j's in i's body frame: the pose's own inverse says so
    np.testing.assert_allclose(m.t_ij, (T_i.inverse() @ T_j).p_A_B, atol=1e-12)
    # moving j 0.1 m along i's body x changes the residual by exactly that
    moved = _x(T_j)
    moved[:3] += T_i.R_A_B.apply([0.1, 0.0, 0.0])
    np.testing.assert_allclose(four_dof_error(_x(T_i), moved, m)[0], [0.1, 0, 0, 0], atol=1e-12)


def test_yaw_residual_wraps() -> None:
    rng = np.random.default_rng(1)
    T_i, T_j = _random_pose(rng), _random_pose(rng)
    m = FourDofMeasurement.between(T_i, T_j)
    x_j = _x(T_j)
    x_j[3] += 2 * math.pi + 0.01
    assert four_dof_error(_x(T_i), x_j, m)[0][3] == pytest.approx(0.01, abs=1e-12)


@pytest.mark.parametrize("seed", SEEDS)
def test_split_yaw_leaves_a_tilt_without_yaw(seed: int) -> None:
    R = _random_pose(np.random.default_rng(seed)).R_A_B
    yaw, tilt = split_yaw(R.as_matrix())
    assert yaw == pytest.approx(R.as_euler("ZYX")[0], abs=1e-12)
    np.testing.assert_allclose(rot_z(yaw) @ tilt, R.as_matrix(), atol=1e-12)
    assert yaw_of(tilt) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("seed", SEEDS)
def test_gtsam_factor_linearises_to_its_numerical_jacobian(seed: int) -> None:
    rng = np.random.default_rng(seed)
    m = FourDofMeasurement.between(_random_pose(rng), _random_pose(rng))
    sigmas = np.array([0.1, 0.2, 0.3, 0.05])
    factor = four_dof_factor(0, 1, m, gtsam.noiseModel.Diagonal.Sigmas(sigmas))
    x = [rng.normal(0.0, 1.0, 4), rng.normal(0.0, 1.0, 4)]
    x[1][3] = x[0][3] + m.dyaw_rad + 0.3

    def unwhitened(x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        v = gtsam.Values()
        v.insert(0, x0)
        v.insert(1, x1)
        return np.asarray(factor.unwhitenedError(v))

    v = gtsam.Values()
    v.insert(0, x[0])
    v.insert(1, x[1])
    A, b = factor.linearize(v).jacobian()  # whitened: divided by the sigmas
    num = np.hstack(
        [
            _numerical(lambda y: unwhitened(y, x[1]), x[0]),
            _numerical(lambda y: unwhitened(x[0], y), x[1]),
        ]
    )
    np.testing.assert_allclose(A * sigmas[:, None], num, atol=1e-7)
    np.testing.assert_allclose(-b * sigmas, unwhitened(*x), atol=1e-12)
