"""The accelerometer read at rest before a static start, as one factor on the first state's
tilt and accelerometer bias: its linear model against the nonlinear reading, and the
consistency of what a window makes of it over Monte Carlo draws of tilt, bias and noise."""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, X
from scipy.spatial.transform import Rotation

from quadnav.vio.static_init import gravity_rotation
from quadnav.vio.window import Keyframe, rest_factor

G = 9.81
SIGMA_F = 0.02  # m/s^2, the mean reading's noise
SIGMA_B = 0.2  # m/s^2, the accelerometer bias's prior


def _reading(R_W_B: np.ndarray, b_a: np.ndarray) -> np.ndarray:
    return R_W_B.T @ np.array([0.0, 0.0, G]) + b_a


def _keyframe(R_W_B: np.ndarray, b_a: np.ndarray) -> Keyframe:
    return Keyframe(
        index=0,
        t_ns=0,
        pose=gtsam.Pose3(gtsam.Rot3(R_W_B), np.zeros(3)),
        velocity=np.zeros(3),
        bias=gtsam.imuBias.ConstantBias(b_a, np.zeros(3)),
    )


def test_the_factor_is_the_reading_to_first_order_in_tilt_and_bias() -> None:
    rng = np.random.default_rng(3)
    R0 = Rotation.from_rotvec([0.05, -0.08, 1.2]).as_matrix()
    f = _reading(Rotation.from_rotvec([0.02, 0.03, 1.2]).as_matrix(), np.array([0.1, -0.05, 0.2]))
    factor = rest_factor(_keyframe(R0, np.zeros(3)), f, SIGMA_F, G)
    for _ in range(20):
        d = rng.normal(0.0, 2e-3, 3)  # a small right perturbation (GTSAM's Pose3 chart)
        db = rng.normal(0.0, 0.05, 3)
        R = R0 @ Rotation.from_rotvec(d).as_matrix()
        values = gtsam.Values()
        values.insert(X(0), gtsam.Pose3(gtsam.Rot3(R), np.zeros(3)))
        values.insert(B(0), gtsam.imuBias.ConstantBias(db, np.zeros(3)))
        want = 0.5 * float(np.sum(((_reading(R, db) - f) / SIGMA_F) ** 2))
        # second-order terms in d (2e-3 rad): well under 1e-3 of the error
        assert abs(factor.error(values) - want) < 1e-3 * want + 1e-6


def _posterior(f: np.ndarray, R_told: np.ndarray) -> tuple[gtsam.Values, gtsam.Marginals]:
    """A first state alone: yaw and position fixed, tilt nearly free, the bias prior, and the
    reading at rest."""
    kf = _keyframe(R_told, np.zeros(3))
    graph = gtsam.NonlinearFactorGraph()
    cov = np.diag([0.5**2, 0.5**2, 1e-6, 1e-6, 1e-6, 1e-6])
    graph.add(gtsam.PriorFactorPose3(X(0), kf.pose, gtsam.noiseModel.Gaussian.Covariance(cov)))
    sig_b = np.array([SIGMA_B] * 3 + [0.01] * 3)
    graph.add(gtsam.PriorFactorConstantBias(B(0), kf.bias, gtsam.noiseModel.Diagonal.Sigmas(sig_b)))
    graph.add(rest_factor(kf, f, SIGMA_F, G))
    initial = gtsam.Values()
    initial.insert(X(0), kf.pose)
    initial.insert(B(0), kf.bias)
    est = gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize()
    return est, gtsam.Marginals(graph, est)


def test_tilt_and_bias_from_the_reading_at_rest_are_consistent_over_draws() -> None:
    """Truth: bias from its prior, reading noise as stated. The posterior's NEES over (roll,
    pitch, bias) is about its 5 degrees of freedom; a tilt prior centred on the reading's
    gravity beside the bias prior (the old start) makes the horizontal bias twice as sure."""
    rng = np.random.default_rng(11)
    nees = []
    for _ in range(150):
        yaw = rng.uniform(-np.pi, np.pi)
        R_true = Rotation.from_euler("ZYX", [yaw, *rng.normal(0, 0.05, 2)]).as_matrix()
        b_true = rng.normal(0.0, SIGMA_B, 3)
        f = _reading(R_true, b_true) + rng.normal(0.0, SIGMA_F, 3)
        # the start's rotation: gravity from the reading as if the bias were zero, true yaw
        _, pitch, roll = gravity_rotation(f).as_euler("ZYX")
        R_told = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
        est, marg = _posterior(f, R_told)
        xi_R = Rotation.from_matrix(est.atPose3(X(0)).rotation().matrix().T @ R_true).as_rotvec()
        db = b_true - est.atConstantBias(B(0)).accelerometer()
        C = np.zeros((6, 6))
        C[:3, :3] = marg.marginalCovariance(X(0))[:3, :3]
        C[3:, 3:] = marg.marginalCovariance(B(0))[:3, :3]
        C[:3, 3:] = marg.jointMarginalCovariance([X(0), B(0)]).at(X(0), B(0))[:3, :3]
        C[3:, :3] = C[:3, 3:].T
        e = np.concatenate([xi_R, db])
        keep = [0, 1, 3, 4, 5]  # roll and pitch (yaw is the gauge), bias
        nees.append(float(e[keep] @ np.linalg.solve(C[np.ix_(keep, keep)], e[keep])))
    mean = float(np.mean(nees)) / 5
    assert 0.8 < mean < 1.25, mean
