"""Visual-inertial alignment (thesis 003 §3.2, eqs 3.7-3.9; VINS-Mono's ``initial_alignment``):
the gyro bias from the vision-only rotations, then each frame's velocity, gravity and the
metric scale by one linear least-squares solve, then gravity refined to its known magnitude on
its 2-D tangent space.

Frames: ``C0`` is the first window camera's (the structure from motion's frame), ``B_k`` the
body at frame ``k``; ``p_B_C`` is the camera's position in the body (``T_B_C``). The structure
gives camera positions ``p̄_k`` up to the scale ``s``, so a body sits at
``s p̄_k - R_C0_Bk p_B_C``. With the preintegrated ``ΔP, ΔV`` over ``dt`` between frames i and
j = i + 1, velocities ``v_k`` in their own body frame and gravity ``g`` (the acceleration,
pointing down) in ``C0``::

    ΔP - p_B_C + R_Bi_Bj p_B_C = -dt v_i - dt²/2 R_Bi_C0 g + s R_Bi_C0 (p̄_j - p̄_i)
    ΔV                         = -v_i + R_Bi_Bj v_j - dt R_Bi_C0 g

GTSAM's Python wrapper exposes no bias Jacobian of the preintegrated deltas: its
``predict`` applies the first-order bias correction, so the deltas under a new bias are read off
predictions from the identity state (and the rotation's Jacobian is taken numerically).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

__all__ = [
    "AlignmentResult",
    "Deltas",
    "corrected_deltas",
    "gyro_bias_from_rotations",
    "linear_alignment",
    "rotation_residual_deg",
]

FloatArray = NDArray[np.float64]
Pim = gtsam.PreintegratedCombinedMeasurements

#: Step of the numerical Jacobian of the preintegrated rotation in the gyro bias (rad/s).
_BIAS_STEP = 1e-4


@dataclass(frozen=True, slots=True, kw_only=True)
class Deltas:
    """One span's preintegrated rotation, velocity and position deltas (in the span's first
    body frame, gravity not included) under a given bias, and its length."""

    dt_s: float
    dR: Rotation
    dV: FloatArray
    dP: FloatArray


@dataclass(frozen=True, slots=True, kw_only=True)
class AlignmentResult:
    """The linear alignment's answer: each frame's velocity in its own body frame (n, 3), gravity
    (the acceleration, pointing down, ``|g| = g_norm``) in ``C0``, the metric scale of the
    structure, and the RMS residual of the final solve (m/s and m mixed, for the log)."""

    v_B: FloatArray
    gravity_C0: FloatArray
    scale: float
    scale_sigma: float
    residual: float


def _bias(gyro_rad_s: FloatArray) -> gtsam.imuBias.ConstantBias:
    return gtsam.imuBias.ConstantBias(np.zeros(3), np.asarray(gyro_rad_s, dtype=np.float64))


def corrected_deltas(pim: Pim, gyro_bias: FloatArray) -> Deltas:
    """The deltas of ``pim`` under ``gyro_bias`` (accelerometer bias zero), first order, as
    GTSAM corrects them; the difference of two predictions cancels gravity exactly."""
    nav0 = gtsam.NavState()
    hat = pim.predict(nav0, pim.biasHat())
    new = pim.predict(nav0, _bias(gyro_bias))
    return Deltas(
        dt_s=float(pim.deltaTij()),
        dR=Rotation.from_matrix(new.attitude().matrix()),
        dV=np.asarray(new.velocity() - hat.velocity() + pim.deltaVij(), dtype=np.float64),
        dP=np.asarray(new.position() - hat.position() + pim.deltaPij(), dtype=np.float64),
    )


def _rotation_residuals(
    R_Bi_Bj: Sequence[Rotation], pims: Sequence[Pim], gyro_bias: FloatArray
) -> FloatArray:
    """Per span, ``Log(ΔR(b)^T R_Bi_Bj)`` (rad), vision against the gyro."""
    out = np.empty((len(pims), 3))
    for k, (R, pim) in enumerate(zip(R_Bi_Bj, pims, strict=True)):
        dR = Rotation.from_matrix(
            pim.predict(gtsam.NavState(), _bias(gyro_bias)).attitude().matrix()
        )
        out[k] = (dR.inv() * R).as_rotvec()
    return out


def gyro_bias_from_rotations(
    R_C0_B: Sequence[Rotation], pims: Sequence[Pim], *, iterations: int = 2
) -> FloatArray:
    """The gyro bias that makes the preintegrated rotations best match the structure's relative
    body rotations (Gauss-Newton on a 3x3 system; the correction is linear to first order)."""
    R_Bi_Bj = [R_C0_B[k].inv() * R_C0_B[k + 1] for k in range(len(pims))]
    b = np.zeros(3)
    for _ in range(iterations):
        r0 = _rotation_residuals(R_Bi_Bj, pims, b).ravel()
        J = np.empty((r0.size, 3))
        for a in range(3):
            e = np.zeros(3)
            e[a] = _BIAS_STEP
            rp = _rotation_residuals(R_Bi_Bj, pims, b + e).ravel()
            rm = _rotation_residuals(R_Bi_Bj, pims, b - e).ravel()
            J[:, a] = (rp - rm) / (2.0 * _BIAS_STEP)
        b = b - np.linalg.solve(J.T @ J, J.T @ r0)
    return b


def rotation_residual_deg(
    R_C0_B: Sequence[Rotation], pims: Sequence[Pim], gyro_bias: FloatArray
) -> float:
    """The RMS angle between the structure's and the gyro's relative rotations (degrees)."""
    R_Bi_Bj = [R_C0_B[k].inv() * R_C0_B[k + 1] for k in range(len(pims))]
    r = _rotation_residuals(R_Bi_Bj, pims, gyro_bias)
    return float(np.degrees(np.sqrt(np.mean(np.sum(r**2, axis=1)))))


def _solve(
    p_C0_C: FloatArray,
    R_C0_B: Sequence[Rotation],
    deltas: Sequence[Deltas],
    p_B_C: FloatArray,
    g_fixed: FloatArray,
    basis: FloatArray,
    scale: float | None = None,
) -> tuple[FloatArray, float, float]:
    """The stacked linear system with gravity ``g_fixed + basis @ w``: unknowns ``[v_0..v_n, w,
    s]``; returns them, the RMS residual and the scale's standard deviation (the residual's
    spread through the normal equations). A known ``scale`` (a stereo structure's, metric)
    leaves the unknowns ``[v_0..v_n, w]`` (returned with it appended, its deviation 0)."""
    n, m = len(R_C0_B), basis.shape[1]
    A = np.zeros((6 * (n - 1), 3 * n + m + 1))
    y = np.zeros(6 * (n - 1))
    for i, d in enumerate(deltas):
        j, r = i + 1, slice(6 * i, 6 * i + 6)
        R_Bi_C0 = R_C0_B[i].inv().as_matrix()
        R_Bi_Bj = (R_C0_B[i].inv() * R_C0_B[j]).as_matrix()
        dt = d.dt_s
        blk = np.zeros((6, A.shape[1]))
        blk[0:3, 3 * i : 3 * i + 3] = -dt * np.eye(3)
        blk[0:3, 3 * n : 3 * n + m] = -0.5 * dt**2 * R_Bi_C0 @ basis
        blk[0:3, -1] = R_Bi_C0 @ (p_C0_C[j] - p_C0_C[i])
        blk[3:6, 3 * i : 3 * i + 3] = -np.eye(3)
        blk[3:6, 3 * j : 3 * j + 3] = R_Bi_Bj
        blk[3:6, 3 * n : 3 * n + m] = -dt * R_Bi_C0 @ basis
        A[r] = blk
        y[6 * i : 6 * i + 3] = d.dP - p_B_C + R_Bi_Bj @ p_B_C + 0.5 * dt**2 * R_Bi_C0 @ g_fixed
        y[6 * i + 3 : 6 * i + 6] = d.dV + dt * R_Bi_C0 @ g_fixed
    if scale is not None:
        y = y - A[:, -1] * scale
        xs = np.asarray(np.linalg.lstsq(A[:, :-1], y, rcond=None)[0], dtype=np.float64)
        e = A[:, :-1] @ xs - y
        return np.append(xs, scale), float(np.sqrt(np.mean(e**2))), 0.0
    x = np.asarray(np.linalg.lstsq(A, y, rcond=None)[0], dtype=np.float64)
    e = A @ x - y
    dof = max(A.shape[0] - A.shape[1], 1)
    cov_ss = float(np.linalg.pinv(A.T @ A)[-1, -1])
    return x, float(np.sqrt(np.mean(e**2))), float(np.sqrt(max(cov_ss, 0.0) * (e @ e) / dof))


def _tangent_basis(g: FloatArray) -> FloatArray:
    """Two unit vectors orthogonal to ``g`` (3, 2)."""
    u = g / np.linalg.norm(g)
    helper = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    b1 = np.cross(u, helper)
    b1 /= np.linalg.norm(b1)
    return np.column_stack([b1, np.cross(u, b1)])


def linear_alignment(
    p_C0_C: FloatArray,
    R_C0_B: Sequence[Rotation],
    deltas: Sequence[Deltas],
    p_B_C: FloatArray,
    *,
    g_norm: float,
    max_g_norm_error_m_s2: float = 1.0,
    max_scale_sigma: float = 0.05,
    refine_iterations: int = 4,
    scale: float | None = None,
) -> AlignmentResult | str:
    """Velocities, gravity and scale (eqs 3.7-3.9), then gravity refined with ``|g| = g_norm``;
    or why not: a gravity whose magnitude is off by more than ``max_g_norm_error_m_s2``, a
    scale that is not positive, or one whose standard deviation exceeds ``max_scale_sigma`` of
    itself (too little acceleration in the window: at constant velocity the IMU sees only
    gravity and any scale fits, the vision's small errors then pull it towards zero). A known
    ``scale`` (a stereo structure is metric) is held, and only velocities and gravity solved:
    they need no acceleration."""
    n = len(R_C0_B)
    x, res, sigma = _solve(p_C0_C, R_C0_B, deltas, p_B_C, np.zeros(3), np.eye(3), scale)
    g = x[3 * n : 3 * n + 3]
    if not np.isfinite(x).all() or abs(np.linalg.norm(g) - g_norm) > max_g_norm_error_m_s2:
        return f"the linear alignment's gravity is {np.linalg.norm(g):.2f} m/s^2, not {g_norm:g}"
    if x[-1] <= 0.0:
        return f"the linear alignment's scale is not positive ({x[-1]:.3g})"
    g = g / np.linalg.norm(g) * g_norm
    for _ in range(refine_iterations):
        B = _tangent_basis(g)
        x, res, sigma = _solve(p_C0_C, R_C0_B, deltas, p_B_C, g, B, scale)
        g = g + B @ x[3 * n : 3 * n + 2]
        g = g / np.linalg.norm(g) * g_norm
    if not np.isfinite(x).all() or x[-1] <= 0.0:
        return f"the refined alignment's scale is not positive ({x[-1]:.3g})"
    if sigma > max_scale_sigma * x[-1]:
        return (
            f"the scale is not observable in this window ({x[-1]:.3g} +- {sigma / x[-1]:.0%}: "
            "too little acceleration)"
        )
    return AlignmentResult(
        v_B=x[: 3 * n].reshape(n, 3),
        gravity_C0=g,
        scale=float(x[-1]),
        scale_sigma=sigma,
        residual=res,
    )
