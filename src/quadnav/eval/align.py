"""Aligning an estimate to its reference: SE(3), Sim(3) (Umeyama) and position + yaw (4-DoF)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import EvalError
from quadnav.geometry.multiview import kabsch
from quadnav.geometry.trajectory import Trajectory

__all__ = ["AlignMethod", "Alignment", "GravityAxis", "align", "umeyama", "yaw_translation"]

FloatArray = NDArray[np.float64]
AlignMethod = Literal["none", "se3", "sim3", "4dof"]
GravityAxis = Literal["x", "y", "z"]


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
    R, sv = kabsch(xs, xd)
    if np.sum(np.abs(sv) > 1e-9 * max(float(np.abs(sv).max()), 1e-300)) < 2:
        raise EvalError("alignment is degenerate: the matched positions are (nearly) collinear")
    s = float(np.sum(sv) / np.sum(xs**2)) if with_scale else 1.0
    t = mu_d - s * R @ mu_s
    return Rotation.from_matrix(R), t, s


# The plane of a rotation about each axis, in the order it turns (x -> y about z, z -> x about y).
_PLANE: dict[str, tuple[int, int]] = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}


def yaw_translation(
    src: FloatArray, dst: FloatArray, *, gravity_axis: GravityAxis = "z"
) -> tuple[Rotation, FloatArray]:
    """Least-squares ``dst ~ R(yaw about gravity_axis) src + t``: the 4 unobservable DoF of
    visual-inertial odometry. ``z`` is up in an ENU world; KITTI's camera frame has ``y`` down."""
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 2:
        raise EvalError("4-DoF alignment needs at least 2 matched (N, 3) positions")
    if gravity_axis not in _PLANE:
        raise EvalError(f"unknown gravity axis {gravity_axis!r}; choose x, y or z")
    u, v = _PLANE[gravity_axis]
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    # Maximise sum b_uv . R a_uv: the optimum yaw is the angle of sum(a x b, a . b) in the plane.
    yaw = np.arctan2(
        np.sum(a[:, u] * b[:, v] - a[:, v] * b[:, u]), np.sum(a[:, u] * b[:, u] + a[:, v] * b[:, v])
    )
    R = Rotation.from_euler(gravity_axis, yaw)
    return R, mu_d - R.apply(mu_s)


def align(
    ref: Trajectory,
    est: Trajectory,
    method: AlignMethod,
    *,
    first_n: int | None = None,
    gravity_axis: GravityAxis = "z",
) -> tuple[Trajectory, Alignment]:
    """The estimate aligned to the matched reference, estimated on all or the first N pairs
    (4dof: yaw about ``gravity_axis`` of the reference frame)."""
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
        R, t = yaw_translation(src, dst, gravity_axis=gravity_axis)
        s = 1.0
    else:
        raise EvalError(f"unknown alignment {method!r}; choose none, se3, sim3 or 4dof")
    return est.transformed(R, t, s), Alignment(method, R, t, s, n)
