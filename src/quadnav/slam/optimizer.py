"""The SLAM's pose-only optimisation (ORB-SLAM2's ``PoseOptimization``): a frame's pose from its
matches to map points, by Gauss-Newton on the reprojection error, stereo points measured by
``(u_left, v, u_right)`` and the others by ``(u, v)``, each weighted by its keypoint's level
(sigma = the level's scale, in pixels) under a Huber kernel. Four rounds: after each, the
matches beyond the chi-square gate (95 %: 7.815 for three, 5.991 for two) are left out of the
next (and may come back); the last round has no kernel."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.geometry.rotations import Pose

__all__ = ["PoseFit", "optimize_pose"]

FloatArray = NDArray[np.float64]
CHI2_STEREO, CHI2_MONO = 7.815, 5.991


@dataclass(frozen=True, slots=True, kw_only=True)
class PoseFit:
    """The camera's pose ``T_C_W`` and which matches are inliers."""

    T_C_W: Pose
    inliers: NDArray[np.bool_]


def _residuals(
    R: FloatArray, t: FloatArray, X_W: FloatArray, uv: FloatArray, ur: FloatArray,
    cam: tuple[float, float, float, float, float],
) -> tuple[FloatArray, FloatArray, FloatArray]:  # fmt: skip
    """Residuals (N, 3; the third 0 for mono), their Jacobians (N, 3, 6) with respect to a
    perturbation ``X_C' = Exp(w) X_C + v`` (w first), and the points in the camera."""
    fx, fy, cx, cy, bf = cam
    X = X_W @ R.T + t
    x, y, z = X[:, 0], X[:, 1], np.maximum(X[:, 2], 1e-6)
    u_hat, v_hat = fx * x / z + cx, fy * y / z + cy
    stereo = ur >= 0
    r = np.column_stack(
        [uv[:, 0] - u_hat, uv[:, 1] - v_hat, np.where(stereo, ur - (u_hat - bf / z), 0.0)]
    )
    J_X = np.zeros((len(X), 3, 3))
    J_X[:, 0, 0], J_X[:, 0, 2] = fx / z, -fx * x / z**2
    J_X[:, 1, 1], J_X[:, 1, 2] = fy / z, -fy * y / z**2
    J_X[:, 2, 0], J_X[:, 2, 2] = fx / z, -(fx * x - bf) / z**2
    J_X[~stereo, 2, :] = 0.0
    S = np.zeros((len(X), 3, 3))  # [X_C]x
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -X[:, 2], X[:, 1], -X[:, 0]
    S[:, 1, 0], S[:, 2, 0], S[:, 2, 1] = X[:, 2], -X[:, 1], X[:, 0]
    # dX_C/dw = -[X_C]x, dX_C/dv = I; r = z - h, so its Jacobian is -dh
    J_xi = np.concatenate([np.einsum("nij,njk->nik", J_X, S), -J_X], axis=2)
    return r, J_xi, X


def optimize_pose(
    T_C_W: Pose, X_W: FloatArray, uv_px: FloatArray, u_right_px: FloatArray,
    sigma2: FloatArray, cam: tuple[float, float, float, float, float],
    *, rounds: int = 4, iterations: int = 10,
) -> PoseFit:  # fmt: skip
    """``T_C_W`` refined from matches to points ``X_W`` (N, 3) seen at ``uv_px`` (N, 2), with
    ``u_right_px`` (N,; negative: no stereo) and each match's pixel variance ``sigma2`` (N,);
    ``cam`` = (fx, fy, cx, cy, fx b)."""
    R, t = T_C_W.R_A_B.as_matrix(), np.asarray(T_C_W.p_A_B, np.float64)
    stereo = u_right_px >= 0
    gate = np.where(stereo, CHI2_STEREO, CHI2_MONO)
    use = np.ones(len(X_W), bool)
    info = 1.0 / np.asarray(sigma2, np.float64)
    chi2 = np.zeros(len(X_W))
    for rnd in range(rounds):
        robust = rnd < rounds - 1
        for _ in range(iterations):
            r, J, X = _residuals(R, t, X_W, uv_px, u_right_px, cam)
            chi2 = info * (r**2).sum(axis=1)
            w = info * np.where(
                robust & (chi2 > gate), np.sqrt(gate / np.maximum(chi2, 1e-12)), 1.0
            )
            w = np.where(use & (X[:, 2] > 0), w, 0.0)
            H = np.einsum("n,nij,nik->jk", w, J, J)
            g = np.einsum("n,nij,ni->j", w, J, r)
            if not np.isfinite(H).all() or np.linalg.cond(H) > 1e12:
                break
            dx = -np.linalg.solve(H, g)
            dR = Rotation.from_rotvec(dx[:3]).as_matrix()
            R, t = dR @ R, dR @ t + dx[3:]
            if np.linalg.norm(dx) < 1e-8:
                break
        r, _, X = _residuals(R, t, X_W, uv_px, u_right_px, cam)
        chi2 = info * (r**2).sum(axis=1)
        use = (chi2 <= gate) & (X[:, 2] > 0)
    pose = Pose(R_A_B=Rotation.from_matrix(R), p_A_B=t)
    return PoseFit(T_C_W=pose, inliers=use)
