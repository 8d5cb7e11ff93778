"""Aligning an estimate to its reference: SE(3), Sim(3) (Umeyama) and position + yaw (4-DoF)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import EvalError
from quadnav.geometry.trajectory import Trajectory

__all__ = ["AlignMethod", "Alignment", "align", "umeyama", "yaw_translation"]

FloatArray = NDArray[np.float64]
AlignMethod = Literal["none", "se3", "sim3", "4dof"]


@dataclass(frozen=True, slots=True)
class Alignment:
    """``p_ref ~ s R p_est + t``: the similarity applied to the estimate."""

    method: AlignMethod
    R: Rotation
    t: FloatArray
    s: float
    n_used: int


def umeyama(
    src: FloatArray, dst: FloatArray, *, with_scale: bool
) -> tuple[Rotation, FloatArray, float]:
    """Least-squares ``dst ~ s R src + t`` (Umeyama 1991) for point sets (N, 3)."""
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise EvalError(f"alignment needs two (N, 3) point sets, got {src.shape} and {dst.shape}")
    n = len(src)
    if n < 3:
        raise EvalError(f"alignment needs at least 3 matched poses, got {n}")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / n
    U, D, Vt = np.linalg.svd(cov)
    if np.linalg.matrix_rank(cov) < 2:
        raise EvalError("alignment is degenerate: the matched positions are (nearly) collinear")
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / (np.sum(xs**2) / n)) if with_scale else 1.0
    t = mu_d - s * R @ mu_s
    return Rotation.from_matrix(R), t, s


def yaw_translation(src: FloatArray, dst: FloatArray) -> tuple[Rotation, FloatArray]:
    """Least-squares ``dst ~ Rz(yaw) src + t``: the 4 unobservable DoF of visual-inertial odometry."""
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 2:
        raise EvalError("4-DoF alignment needs at least 2 matched (N, 3) positions")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    # Maximise sum b_xy . Rz a_xy: the optimum yaw is the angle of sum(a x b, a . b) in the plane.
    yaw = np.arctan2(
        np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])
    )
    R = Rotation.from_euler("z", yaw)
    return R, mu_d - R.apply(mu_s)


def align(
    ref: Trajectory, est: Trajectory, method: AlignMethod, *, first_n: int | None = None
) -> tuple[Trajectory, Alignment]:
    """The estimate aligned to the matched reference, estimated on all or the first N pairs."""
    if len(ref) != len(est):
        raise EvalError("align matched trajectories (equal length); associate them first")
    n = len(est) if first_n is None else min(first_n, len(est))
    if first_n is not None and first_n < 1:
        raise EvalError(f"--align-first must be >= 1, got {first_n}")
    if method == "none":
        return est, Alignment("none", Rotation.identity(), np.zeros(3), 1.0, 0)
    src, dst = est.p_W_B[:n], ref.p_W_B[:n]
    if method in ("se3", "sim3"):
        R, t, s = umeyama(src, dst, with_scale=method == "sim3")
    elif method == "4dof":
        R, t = yaw_translation(src, dst)
        s = 1.0
    else:
        raise EvalError(f"unknown alignment {method!r}; choose none, se3, sim3 or 4dof")
    return est.transformed(R, t, s), Alignment(method, R, t, s, n)
