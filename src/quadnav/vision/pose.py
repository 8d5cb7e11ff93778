"""Pose from markers: PnP with a covariance, and the frame chain of thesis 000 (eqs 3.1-3.6).

Frames: ``C`` camera (x right, y down, z along the optical axis), ``O`` a planar object (a
marker or diamond: origin at its centre, x right, y up, z out of the printed face; a board:
the same axes from the bottom-left corner of its pattern), ``W`` the world, ``B`` the body (FLU). PnP gives ``T_C_O``; the camera mount is
``T_B_C``; the vehicle is ``T_W_B = T_W_O T_C_O^-1 T_B_C^-1``.

The covariance of a PnP pose is ``s^2 (J^T J)^-1`` with ``J`` the Jacobian of the reprojected
pixels with respect to the pose (from ``cv2.projectPoints``) and ``s^2`` the pixel noise: the
residuals' variance pooled with a prior (``prior_sigma_px``, worth ``prior_dof`` residuals),
because a single marker leaves only 2 degrees of freedom to estimate it from. A far, grazing
marker gets a large covariance, a close, frontal one a small one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import VisionError
from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose, so3_log

__all__ = [
    "DegeneratePoseError",
    "PnpResult",
    "VehiclePose",
    "chain_jacobian",
    "check_point_set",
    "marker_corners_3d",
    "mount_pose",
    "refine_pnp",
    "solve_pnp",
    "vehicle_pose",
]

FloatArray = NDArray[np.float64]


def marker_corners_3d(length_m: float) -> FloatArray:
    """A square marker's corners (4, 3) in its own frame, in OpenCV's detection order
    (top-left, top-right, bottom-right, bottom-left), as ``SOLVEPNP_IPPE_SQUARE`` wants."""
    h = 0.5 * length_m
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def mount_pose(rpy_deg: tuple[float, float, float], xyz_m: tuple[float, float, float]) -> Pose:
    """``T_B_C`` of a camera: its roll/pitch/yaw (deg, extrinsic x-y-z... as ``ZYX`` yaw, pitch,
    roll) from the body, and its position in the body (m).

    The thesis's downward camera, turned 180 degrees about the vertical from the body (its eq. 3.4
    in FRD), is roll 180, pitch 0, yaw 180 in FLU: optical axis down, image x towards the tail.
    """
    r, p, y = rpy_deg
    return Pose(Rotation.from_euler("ZYX", [y, p, r], degrees=True), np.asarray(xyz_m, float))


@dataclass(frozen=True, slots=True)
class PnpResult:
    """``T_C_O`` with the covariance (6x6) of its rotation vector and translation (OpenCV's
    ``rvec``, ``tvec``), the RMS reprojection error (px), the pixel noise used and, for an
    ambiguous planar pose, the other solution."""

    T_C_O: Pose
    rvec: FloatArray
    tvec: FloatArray
    cov_rt: FloatArray
    rms_px: float
    sigma_px: float
    n_points: int
    alternative: FloatArray | None = None  # (rvec, tvec) of a second pose that fits almost as well


class DegeneratePoseError(VisionError):
    """A point set that fixes no pose, or a PnP result that is not one: ``reason`` is a short
    key (``too_few_points``, ``collinear``, ``non_finite``, ``pnp_failed``, ``behind_camera``)
    for counting; the message says what was wrong."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def _count_distinct(points: FloatArray, enough: int = 4) -> int:
    """How many distinct points (to the nanometre), counting up to ``enough``."""
    seen: set[tuple[float, ...]] = set()
    for row in np.round(points, 9).tolist():
        seen.add(tuple(row))
        if len(seen) >= enough:
            break
    return len(seen)


def check_point_set(obj: FloatArray, img: FloatArray, *, collinear_tol: float = 1e-3) -> None:
    """Refuse what no PnP can pose: fewer than 4 pairs or distinct points, a non-finite value,
    object points on one line (one column of a board in view) or pixels on one line (a plane
    seen edge-on). ``collinear_tol``: the second singular value over the first."""
    if len(obj) != len(img):
        raise DegeneratePoseError(
            "too_few_points", f"PnP got {len(obj)} object points and {len(img)} pixels"
        )
    if not (np.isfinite(obj).all() and np.isfinite(img).all()):
        raise DegeneratePoseError("non_finite", "PnP input holds a non-finite value")
    n_distinct = _count_distinct(obj[:16])
    n_distinct = n_distinct if n_distinct >= 4 else _count_distinct(obj)
    if n_distinct < 4:
        raise DegeneratePoseError(
            "too_few_points", f"PnP needs at least 4 distinct points, got {n_distinct}"
        )
    for name, pts in (("object points", obj), ("pixels", img)):
        s = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
        if s[1] <= collinear_tol * s[0]:
            raise DegeneratePoseError("collinear", f"the {len(pts)} {name} lie on one line")


def _check_result(rvec: FloatArray, tvec: FloatArray, obj: FloatArray | None, what: str) -> None:
    """A finite pose; with ``obj``, one that puts every point in front of the camera (the
    object's origin itself may be behind it: a board's corner seen close up and tilted)."""
    if not (np.isfinite(rvec).all() and np.isfinite(tvec).all()):
        raise DegeneratePoseError("non_finite", f"PnP {what} is not finite")
    if obj is not None:
        R, _ = cv2.Rodrigues(rvec)
        if not np.all(obj @ R[2] + tvec[2] > 0):
            raise DegeneratePoseError("behind_camera", f"PnP {what} puts points behind the camera")


def _is_planar(obj: FloatArray) -> bool:
    c = obj - obj.mean(axis=0)
    s = np.linalg.svd(c, compute_uv=False)
    return bool(s[-1] <= 1e-6 * max(s[0], 1e-12))


def solve_pnp(
    obj_pts: FloatArray,
    img_pts: FloatArray,
    camera: PinholeCamera,
    *,
    square: bool = False,
    prior_sigma_px: float = 0.5,
    prior_dof: float = 4.0,
    refine: bool = True,
    ambiguity_ratio: float = 3.0,
) -> PnpResult:
    """Pose of the object points in the camera from their pixels (N >= 4).

    ``square``: the 4 points are a marker's corners from :func:`marker_corners_3d`
    (``SOLVEPNP_IPPE_SQUARE``); otherwise IPPE for planar points, SQPnP for others. The result
    is refined with Levenberg-Marquardt.
    """
    obj = np.asarray(obj_pts, dtype=np.float64).reshape(-1, 3)
    img = np.asarray(img_pts, dtype=np.float64).reshape(-1, 2)
    check_point_set(obj, img)
    if square:
        flag = cv2.SOLVEPNP_IPPE_SQUARE
    elif _is_planar(obj):
        flag = cv2.SOLVEPNP_IPPE
    else:
        flag = cv2.SOLVEPNP_SQPNP
    try:
        n_sol, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, camera.K, camera.dist, flags=flag)
    except cv2.error as exc:
        raise DegeneratePoseError(
            "pnp_failed", f"PnP failed: {str(exc).strip().splitlines()[-1]}"
        ) from None
    if not n_sol:
        raise DegeneratePoseError("pnp_failed", "PnP found no pose")
    order = np.argsort(np.asarray(errs).ravel()) if errs is not None else np.arange(n_sol)
    rvec, tvec = rvecs[order[0]], tvecs[order[0]]
    # A planar target seen small or nearly head-on has two poses that fit almost equally well
    # (IPPE returns both): when the second is close, it is kept so the covariance can say so.
    alternative = None
    if n_sol > 1 and errs is not None:
        e = np.asarray(errs).ravel()
        if e[order[1]] < ambiguity_ratio * max(e[order[0]], 0.05):
            alternative = np.concatenate([np.ravel(rvecs[order[1]]), np.ravel(tvecs[order[1]])])
            alternative = alternative if np.isfinite(alternative).all() else None
    _check_result(np.ravel(rvec), np.ravel(tvec), None, "pose")
    return refine_pnp(
        obj,
        img,
        camera,
        np.ravel(rvec),
        np.ravel(tvec),
        prior_sigma_px=prior_sigma_px,
        prior_dof=prior_dof,
        refine=refine,
        alternative=alternative,
    )


def refine_pnp(
    obj: FloatArray,
    img: FloatArray,
    camera: PinholeCamera,
    rvec: FloatArray,
    tvec: FloatArray,
    *,
    prior_sigma_px: float = 0.5,
    prior_dof: float = 4.0,
    refine: bool = True,
    alternative: FloatArray | None = None,
) -> PnpResult:
    """The pose ``(rvec, tvec)`` of the object points (N, 3) seen at ``img`` (N, 2), refined
    with Levenberg-Marquardt, with its covariance (see :func:`solve_pnp`); ``alternative``: the
    other solution of an ambiguous planar pose, to keep with it."""
    obj = np.asarray(obj, dtype=np.float64).reshape(-1, 3)
    img = np.asarray(img, dtype=np.float64).reshape(-1, 2)
    n = len(obj)
    r0 = np.asarray(rvec, dtype=np.float64).reshape(3, 1)
    t0 = np.asarray(tvec, dtype=np.float64).reshape(3, 1)
    rt = cv2.solvePnPRefineLM(obj, img, camera.K, camera.dist, r0, t0) if refine else (r0, t0)
    rvec = np.asarray(rt[0], dtype=np.float64).ravel()
    tvec = np.asarray(rt[1], dtype=np.float64).ravel()
    _check_result(rvec, tvec, obj, "refined pose")
    proj, jac = cv2.projectPoints(obj, rvec, tvec, camera.K, camera.dist)
    res = (proj.reshape(-1, 2) - img).ravel()
    J = jac[:, 0:6]
    dof = 2 * n - 6
    s2 = (float(res @ res) + prior_dof * prior_sigma_px**2) / max(dof + prior_dof, 1e-9)
    # Corner errors are partly systematic (blur, the refinement window, the print): they do
    # not average away over many corners, so the prior is also a floor.
    s2 = max(s2, prior_sigma_px**2)
    JtJ = J.T @ J
    try:
        cov = s2 * np.linalg.inv(JtJ)
    except np.linalg.LinAlgError:
        raise DegeneratePoseError(
            "degenerate", "PnP pose is degenerate (singular Jacobian)"
        ) from None
    if not np.isfinite(cov).all():
        raise DegeneratePoseError("non_finite", "PnP covariance is not finite")
    T = Pose(Rotation.from_rotvec(rvec), tvec)
    rms = float(math.sqrt(float(res @ res) / n))
    return PnpResult(T, rvec, tvec, 0.5 * (cov + cov.T), rms, math.sqrt(s2), n, alternative)


@dataclass(frozen=True, slots=True)
class VehiclePose:
    """``T_W_B`` with the covariance (6x6) of its position and its attitude error (a small
    rotation in the world frame: ``R_true = Exp(dtheta) R``), in that order."""

    T_W_B: Pose
    cov: FloatArray

    @property
    def cov_position(self) -> FloatArray:
        return self.cov[0:3, 0:3]

    @property
    def sigma_yaw_rad(self) -> float:
        return float(math.sqrt(max(self.cov[5, 5], 0.0)))


def _chain(rt: FloatArray, T_W_O: FloatArray, T_C_B: FloatArray) -> FloatArray:
    R_C_O, _ = cv2.Rodrigues(rt[0:3])
    T_C_O = np.eye(4)
    T_C_O[:3, :3] = R_C_O
    T_C_O[:3, 3] = rt[3:6]
    T_O_C = np.linalg.inv(T_C_O)
    return np.asarray(T_W_O @ T_O_C @ T_C_B, dtype=np.float64)


def _skew(v: FloatArray) -> FloatArray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _left_jacobian(phi: FloatArray) -> FloatArray:
    """SO(3)'s left Jacobian: ``Exp(phi + d) = Exp(J_l(phi) d) Exp(phi)`` to first order."""
    th = float(np.linalg.norm(phi))
    K = _skew(phi)
    if th < 1e-8:
        return np.eye(3) + 0.5 * K
    return np.eye(3) + (1.0 - math.cos(th)) / th**2 * K + (th - math.sin(th)) / th**3 * (K @ K)


def chain_jacobian(rt: FloatArray, T_W_O: FloatArray, T_C_B: FloatArray) -> FloatArray:
    """d(p_W_B, dtheta_W) / d(rvec, tvec) of ``T_W_B = T_W_O T_C_O(rvec, tvec)^-1 T_C_B``.

    With ``R = Exp(r)``: ``R_W_B = R_W_O R^T R_C_B`` and ``p_W_B = R_W_O R^T (p_C_B - t) +
    p_W_O``; ``Exp(r + d)^T = Exp(r)^T Exp(-J_l d)`` gives, with ``M = R_W_O R^T``,
    ``dp = M [p_C_B - t]x J_l dr - M dt`` and ``dtheta = -M J_l dr``."""
    r, t = rt[0:3], rt[3:6]
    R, _ = cv2.Rodrigues(r)
    M = T_W_O[:3, :3] @ R.T
    Jl = _left_jacobian(r)
    J = np.zeros((6, 6))
    J[0:3, 0:3] = M @ _skew(T_C_B[:3, 3] - t) @ Jl
    J[0:3, 3:6] = -M
    J[3:6, 0:3] = -M @ Jl
    return J


def vehicle_pose(pnp: PnpResult, T_W_O: Pose, T_B_C: Pose) -> VehiclePose:
    """The body in the world from a PnP pose of an object at ``T_W_O`` seen by a camera mounted
    at ``T_B_C``, with the PnP covariance carried through the chain (analytic Jacobian,
    :func:`chain_jacobian`)."""
    T_C_B = T_B_C.inverse()
    T_W_B = T_W_O @ pnp.T_C_O.inverse() @ T_C_B
    TWO, TCB = T_W_O.matrix(), T_C_B.matrix()
    rt = np.concatenate([pnp.rvec, pnp.tvec])
    J = chain_jacobian(rt, TWO, TCB)
    cov = J @ pnp.cov_rt @ J.T
    if pnp.alternative is not None:
        # Either pose may be the true one: the covariance of the two-point mixture (equal
        # weights) adds a quarter of the outer product of their difference.
        T0, T1 = T_W_B.matrix(), _chain(pnp.alternative, TWO, TCB)
        delta = np.concatenate([T1[:3, 3] - T0[:3, 3], so3_log(T1[:3, :3] @ T0[:3, :3].T)])
        cov = cov + 0.25 * np.outer(delta, delta)
    return VehiclePose(T_W_B, 0.5 * (cov + cov.T))
