"""The SLAM's pose-only optimisation (ORB-SLAM2's ``PoseOptimization``): a frame's pose from its
matches to map points, by Gauss-Newton on the reprojection error, stereo points measured by
``(u_left, v, u_right)`` and the others by ``(u, v)``, each weighted by its keypoint's level
(sigma = the level's scale, in pixels) under a Huber kernel. Four rounds: after each, the
matches beyond the chi-square gate (95 %: 7.815 for three, 5.991 for two) are left out of the
next (and may come back); the last round has no kernel. A round stops early once a step moves
the pose by less than ``STEP_DONE`` (rad and m together: a micrometre at a metre).

The fit's covariance is the inverse of the last round's information (its inliers at their
stated pixel variance), scaled up by the residuals' variance factor where that exceeds 1: the
median over all matches of each one's chi-square over the median of its chi-square law (1.386
for two, 2.366 for three degrees of freedom), robust to any share of outliers under a half. A
noise larger than stated, or a map whose points are off, shows so (the inliers alone would not
show it: the gate keeps those that agree)."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.geometry.rotations import Pose, so3_exp

if TYPE_CHECKING:  # (GTSAM loads only for a bundle adjustment)
    import gtsam

    from quadnav.vision.stereo import RectificationFix

__all__ = [
    "BundleProblem", "BundleResult", "PoseFit", "local_bundle_adjustment", "optimize_pose",
    "self_calibrating_adjustment",
]  # fmt: skip

FloatArray = NDArray[np.float64]
CHI2_STEREO, CHI2_MONO = 7.815, 5.991
#: a held keyframe's pose prior (rad, m): so tight it does not move, and not GTSAM's
#: ``NonlinearEquality``, whose constrained noise model makes it eliminate by QR (ten times
#: slower on a bundle adjustment holding many keyframes)
HELD_SIGMA = 1e-6
STEP_DONE = 1e-6
#: the medians of chi-square with 3 and 2 degrees of freedom
MEDIAN_STEREO, MEDIAN_MONO = 2.366, 1.386


@dataclass(frozen=True, slots=True, kw_only=True)
class PoseFit:
    """The camera's pose ``T_C_W``, which matches are inliers, and ``cov``: the covariance of
    the camera's pose ``T_W_C`` in the camera frame, GTSAM's (rotation, translation) order
    (None when the last round had too few inliers to give one)."""

    T_C_W: Pose
    inliers: NDArray[np.bool_]
    cov: FloatArray | None = None


def _residuals(
    R: FloatArray, t: FloatArray, X_W: FloatArray, uv: FloatArray, ur: FloatArray,
    cam: tuple[float, float, float, float, float], *, jacobians: bool = True,
) -> tuple[FloatArray, FloatArray | None, FloatArray]:  # fmt: skip
    """Residuals (N, 3; the third 0 for mono), their Jacobians (N, 3, 6) with respect to a
    perturbation ``X_C' = Exp(w) X_C + v`` (w first; None unless ``jacobians``), and the
    points in the camera."""
    fx, fy, cx, cy, bf = cam
    X = X_W @ R.T + t
    X0, X1, X2 = X[:, 0], X[:, 1], X[:, 2]
    z = np.maximum(X2, 1e-6)
    iz = 1.0 / z
    u_hat, v_hat = fx * X0 * iz + cx, fy * X1 * iz + cy
    stereo = ur >= 0
    r = np.empty((len(X), 3))
    r[:, 0], r[:, 1] = uv[:, 0] - u_hat, uv[:, 1] - v_hat
    r[:, 2] = np.where(stereo, ur - (u_hat - bf * iz), 0.0)
    if not jacobians:
        return r, None, X
    # dh/dX_C per row (a0, a1, a2); r = z - h and dX_C/dw = -[X_C]x, dX_C/dv = I, so each row
    # of the Jacobian is (a [X_C]x, -a), with a [X]x = (a1 X2 - a2 X1, a2 X0 - a0 X2, a0 X1 - a1 X0)
    J = np.zeros((len(X), 3, 6))
    a0, a2 = fx * iz, -fx * X0 * iz**2
    J[:, 0, 0], J[:, 0, 1], J[:, 0, 2] = -a2 * X1, a2 * X0 - a0 * X2, a0 * X1
    J[:, 0, 3], J[:, 0, 5] = -a0, -a2
    b1, b2 = fy * iz, -fy * X1 * iz**2
    J[:, 1, 0], J[:, 1, 1], J[:, 1, 2] = b1 * X2 - b2 * X1, b2 * X0, -b1 * X0
    J[:, 1, 4], J[:, 1, 5] = -b1, -b2
    c2 = np.where(stereo, -(fx * X0 - bf) * iz**2, 0.0)
    c0 = np.where(stereo, a0, 0.0)
    J[:, 2, 0], J[:, 2, 1], J[:, 2, 2] = -c2 * X1, c2 * X0 - c0 * X2, c0 * X1
    J[:, 2, 3], J[:, 2, 5] = -c0, -c2
    return r, J, X


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
    H = np.zeros((6, 6))
    for rnd in range(rounds):
        robust = rnd < rounds - 1
        for _ in range(iterations):
            r, J, X = _residuals(R, t, X_W, uv_px, u_right_px, cam)
            assert J is not None
            chi2 = info * (r**2).sum(axis=1)
            w = info * np.where(
                robust & (chi2 > gate), np.sqrt(gate / np.maximum(chi2, 1e-12)), 1.0
            )
            w = np.where(use & (X[:, 2] > 0), w, 0.0)
            WJ = (w[:, None, None] * J).reshape(-1, 6)  # (one matrix product each)
            H = WJ.T @ J.reshape(-1, 6)
            g = WJ.T @ r.reshape(-1)
            if not np.isfinite(H).all() or np.linalg.cond(H) > 1e12:
                break
            dx = -np.linalg.solve(H, g)
            dR = so3_exp(np.asarray(dx[:3], np.float64))
            R, t = dR @ R, dR @ t + dx[3:]
            if np.linalg.norm(dx) < STEP_DONE:
                break
        r, _, X = _residuals(R, t, X_W, uv_px, u_right_px, cam, jacobians=False)
        chi2 = info * (r**2).sum(axis=1)
        use = (chi2 <= gate) & (X[:, 2] > 0)
    ahead = X[:, 2] > 0
    cov = _covariance(H, chi2[ahead] / np.where(stereo, MEDIAN_STEREO, MEDIAN_MONO)[ahead])
    pose = Pose(R_A_B=Rotation.from_matrix(R), p_A_B=t)
    return PoseFit(T_C_W=pose, inliers=use, cov=cov)


def _covariance(H: FloatArray, ratios: FloatArray) -> FloatArray | None:
    """The inverse of the information ``H`` (of the left perturbation of ``T_C_W``, which is
    minus the camera-frame perturbation of ``T_W_C``: the same covariance), scaled by the
    median of ``ratios`` (each match's chi-square over its law's median) where it exceeds 1."""
    if len(ratios) < 4 or not np.isfinite(H).all() or np.linalg.cond(H) > 1e12:
        return None
    factor = max(1.0, float(np.median(ratios)))
    cov = np.linalg.inv(H) * factor
    return np.asarray(0.5 * (cov + cov.T), np.float64)


@dataclass(frozen=True, slots=True, kw_only=True)
class BundleProblem:
    """A local bundle adjustment: the keyframes' camera poses ``T_W_C`` (K), which are held
    (``fixed``: those that see the local points but are not local, ORB-SLAM2's), the points
    ``X_W`` (P, 3), and the observations: keyframe ``obs_kf`` and point ``obs_pt`` (M,) at
    ``obs_uv`` (M, 2) with ``obs_ur`` (M,; negative: no right coordinate) and the pixel
    variance ``obs_sigma2`` (M,)."""

    T_W_C: tuple[Pose, ...]
    fixed: NDArray[np.bool_]
    X_W: FloatArray
    obs_kf: NDArray[np.int64]
    obs_pt: NDArray[np.int64]
    obs_uv: FloatArray
    obs_ur: FloatArray
    obs_sigma2: FloatArray


@dataclass(frozen=True, slots=True, kw_only=True)
class BundleResult:
    """The adjusted poses and points, and which observations were kept (the rest beyond the
    chi-square gate after the first pass, ORB-SLAM2's outliers)."""

    T_W_C: tuple[Pose, ...]
    X_W: FloatArray
    inliers: NDArray[np.bool_]


def local_bundle_adjustment(
    problem: BundleProblem,
    cam: tuple[float, float, float, float, float],
    *,
    passes: int = 2,
    iterations: int = 50,
) -> BundleResult:
    """ORB-SLAM2's ``LocalBundleAdjustment`` in GTSAM: stereo observations as
    ``GenericStereoFactor3D`` and the others as projection factors, each with its level's
    sigma under a Huber kernel (the 95 % chi-square gate's square root), the held keyframes
    fixed; after a pass the observations beyond the gate are dropped and it is solved again
    (``cam`` = (fx, fy, cx, cy, fx b))."""
    import gtsam

    from quadnav.geometry.gtsam_bridge import to_pose

    fx, fy, cx, cy, bf = cam
    Ks = gtsam.Cal3_S2Stereo(fx, fy, 0.0, cx, cy, bf / fx)
    Km = gtsam.Cal3_S2(fx, fy, 0.0, cx, cy)
    p = problem
    keep = np.ones(len(p.obs_kf), bool)
    poses, points = list(p.T_W_C), np.asarray(p.X_W, np.float64).copy()
    for _ in range(passes):
        graph, values = _bundle_graph(p, keep, poses, points, Ks, Km)
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(iterations)
        out = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        poses = [T if p.fixed[k] else to_pose(out.atPose3(gtsam.symbol("x", k)))
                 for k, T in enumerate(poses)]  # fmt: skip
        points = np.array([out.atPoint3(gtsam.symbol("l", j)) for j in range(len(points))]).reshape(
            -1, 3
        )
        keep = _within_gate(p, poses, points, cam)
    return BundleResult(T_W_C=tuple(poses), X_W=points, inliers=keep)


def _bundle_graph(
    p: BundleProblem, keep: NDArray[np.bool_], poses: list[Pose], points: FloatArray,
    Ks: gtsam.Cal3_S2Stereo, Km: gtsam.Cal3_S2,
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:  # fmt: skip
    import gtsam

    from quadnav.geometry.gtsam_bridge import pose3

    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    held = gtsam.noiseModel.Isotropic.Sigma(6, HELD_SIGMA)
    for k, T in enumerate(poses):
        values.insert(gtsam.symbol("x", k), pose3(T))
        if p.fixed[k]:  # (a prior this tight, not an equality: that one makes GTSAM use QR)
            graph.add(gtsam.PriorFactorPose3(gtsam.symbol("x", k), pose3(T), held))
    for j, X in enumerate(points):
        values.insert(gtsam.symbol("l", j), np.asarray(X, np.float64))
    for m in np.flatnonzero(keep):
        k, j, s = int(p.obs_kf[m]), int(p.obs_pt[m]), float(np.sqrt(p.obs_sigma2[m]))
        u, v = p.obs_uv[m]
        if p.obs_ur[m] >= 0:
            base = gtsam.noiseModel.Isotropic.Sigma(3, s)
            noise = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Huber.Create(np.sqrt(CHI2_STEREO)), base
            )
            graph.add(gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(u, float(p.obs_ur[m]), v), noise,
                                                  gtsam.symbol("x", k), gtsam.symbol("l", j), Ks))  # fmt: skip
        else:
            base = gtsam.noiseModel.Isotropic.Sigma(2, s)
            noise = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Huber.Create(np.sqrt(CHI2_MONO)), base
            )
            graph.add(gtsam.GenericProjectionFactorCal3_S2(np.array([u, v]), noise,
                                                           gtsam.symbol("x", k), gtsam.symbol("l", j), Km))  # fmt: skip
    return graph, values


Intrinsics = tuple[float, float, float, float, float]


class SelfCalibration(NamedTuple):
    """What a self-calibrating adjustment found: the left rectified camera's pinhole ``(fx, fy,
    cx, cy, fx b)``, the right one's ``(fx, fy, cx, cy)`` (its fy and cy the left one's: its rows
    are not measured), the distortion left in each rectified
    image of the pair (OpenCV's ``k1, k2, p1, p2``, left then right) and the right camera's pose
    from the left one (``T_L_R``), and how many keyframes it was found from (a few, as in a
    short flight down a hall, determine it poorly)."""

    intrinsics: Intrinsics
    right: tuple[float, float, float, float]
    distortion: tuple[tuple[float, float, float, float], tuple[float, float, float, float]]
    T_L_R: Pose
    keyframes: int = 0  # (the views it was found from, held ones too)

    def fix(self) -> RectificationFix:
        """What was found, as a fix a rectification folds in (the next run's)."""
        from quadnav.vision.stereo import RectificationFix

        turn = self.T_L_R.R_A_B.as_rotvec()
        return RectificationFix.of(self.intrinsics[:4], self.right, *self.distortion, turn)


def self_calibrating_adjustment(
    problem: BundleProblem,
    cam: Intrinsics,
    *,
    passes: int = 2,
    iterations: int = 50,
    focal_sigma: float = 0.02,
    centre_sigma_px: float = 5.0,
    distortion_sigma: tuple[float, float, float, float] = (0.01, 0.01, 0.001, 0.001),
    rig_sigma: float = 1e-3,
) -> tuple[BundleResult, SelfCalibration]:
    """The bundle adjustment with the rectified pair's calibration estimated as well
    (self-calibration). Each camera of the pair has its own pinhole (fx, fy, cx, cy) with a prior
    at ``cam`` of ``focal_sigma`` (relative) and ``centre_sigma_px``, and the distortion its
    images were rectified without (a calibration's error in focal length or principal point
    undistorts them wrongly: up to 3 px at the edges on EuRoC's lens for 1.3 % and 2 px): OpenCV's
    ``k1, k2, p1, p2`` (GTSAM's ``Cal3DS2``) about zero within ``distortion_sigma``. The right
    camera is one pose from the left for the whole rig (its rotation and its offset across
    the baseline within ``rig_sigma``, rad and m; the baseline's length held: the map's
    scale). Each observation is a projection (GTSAM's ``GeneralSFMFactor2``, the right one
    through the rig) under a Huber kernel of its level's sigma, the held keyframes held by a
    micro-prior; observations of points behind their camera are left out, and after a pass
    those beyond the gate. The result, and what was found (:class:`SelfCalibration`)."""
    import gtsam

    from quadnav.geometry.gtsam_bridge import to_pose

    fx, fy, cx, cy, bf = cam
    b = bf / fx
    stated = gtsam.Cal3DS2(fx, fy, 0.0, cx, cy, 0.0, 0.0, 0.0, 0.0)
    K = (stated, stated)
    T_L_R = gtsam.Pose3(gtsam.Rot3(), np.array([b, 0.0, 0.0]))
    poses, points = list(problem.T_W_C), np.asarray(problem.X_W, np.float64).copy()
    keep = _in_front(problem, poses, points)
    prior = gtsam.noiseModel.Diagonal.Sigmas(
        np.array(
            [
                focal_sigma * fx,
                focal_sigma * fy,
                1e-6,
                centre_sigma_px,
                centre_sigma_px,
                *distortion_sigma,
            ]
        )
    )
    for _ in range(passes):
        graph, values = _self_calibrating_graph(
            problem, keep, poses, points, K, T_L_R, b, rig_sigma
        )
        for side in (0, 1):
            graph.add(gtsam.PriorFactorCal3DS2(gtsam.symbol("k", side), stated, prior))
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(iterations)
        with _c_stdout_silenced():  # (GTSAM prints each landmark it finds behind a camera)
            out = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        poses = [to_pose(out.atPose3(gtsam.symbol("x", k))) for k in range(len(poses))]
        points = np.array([out.atPoint3(gtsam.symbol("l", j)) for j in range(len(points))])
        points = points.reshape(-1, 3)
        K = (out.atCal3DS2(gtsam.symbol("k", 0)), out.atCal3DS2(gtsam.symbol("k", 1)))
        T_L_R = out.atPose3(gtsam.symbol("b", 0))
        keep = _within_gate_calibrated(problem, poses, points, K, to_pose(T_L_R))
    k0, k1 = (np.asarray(k.vector(), np.float64) for k in K)  # (fx, fy, s, u0, v0, ...)
    found = SelfCalibration(
        intrinsics=(float(k0[0]), float(k0[1]), float(k0[3]), float(k0[4]), float(k0[0]) * b),
        # (the right image's rows are not measured: its fy and cy are the left one's)
        right=(float(k1[0]), float(k0[1]), float(k1[3]), float(k0[4])),
        distortion=(_distortion(K[0]), _distortion(K[1])), T_L_R=to_pose(T_L_R),
        keyframes=len(poses),
    )  # fmt: skip
    return BundleResult(T_W_C=tuple(poses), X_W=points, inliers=keep), found


def _matrix_and_distortion(K: gtsam.Cal3DS2) -> tuple[FloatArray, FloatArray]:
    """The camera matrix and OpenCV's ``k1, k2, p1, p2`` of GTSAM's ``Cal3DS2``."""
    return np.asarray(K.K(), np.float64), np.array(_distortion(K))


def _distortion(K: gtsam.Cal3DS2) -> tuple[float, float, float, float]:
    v = np.asarray(K.vector(), np.float64)  # (fx, fy, s, u0, v0, k1, k2, p1, p2)
    return float(v[5]), float(v[6]), float(v[7]), float(v[8])


def _self_calibrating_graph(
    p: BundleProblem, keep: NDArray[np.bool_], poses: list[Pose], points: FloatArray,
    K: tuple[gtsam.Cal3DS2, gtsam.Cal3DS2], T_L_R: gtsam.Pose3, baseline_m: float,
    rig_sigma: float,
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:  # fmt: skip
    import gtsam
    from gtsam_unstable import ProjectionFactorPPPCCal3DS2

    from quadnav.geometry.gtsam_bridge import pose3

    def x(k: int) -> int:
        return int(gtsam.symbol("x", k))

    def lm(j: int) -> int:
        return int(gtsam.symbol("l", j))

    rig_key = int(gtsam.symbol("b", 0))
    held = gtsam.noiseModel.Isotropic.Sigma(6, HELD_SIGMA)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    # (one right camera for the whole rig: its rotation and its offset across the baseline
    # within rig_sigma of the rectified one; the baseline's length held, the map's scale)
    values.insert(rig_key, T_L_R)
    rig = gtsam.noiseModel.Diagonal.Sigmas(np.array([rig_sigma] * 3 + [1e-7, rig_sigma, rig_sigma]))
    stated = gtsam.Pose3(gtsam.Rot3(), np.array([baseline_m, 0.0, 0.0]))
    graph.add(gtsam.PriorFactorPose3(rig_key, stated, rig))
    for k, T in enumerate(poses):
        values.insert(x(k), pose3(T))
        if p.fixed[k]:
            graph.add(gtsam.PriorFactorPose3(x(k), pose3(T), held))
    for j, X in enumerate(points):
        values.insert(lm(j), np.asarray(X, np.float64))
    for side in (0, 1):
        values.insert(gtsam.symbol("k", side), K[side])
    kernel = gtsam.noiseModel.mEstimator.Huber.Create(np.sqrt(CHI2_MONO))
    k0, k1 = gtsam.symbol("k", 0), gtsam.symbol("k", 1)
    for m in np.flatnonzero(keep):
        k, j = int(p.obs_kf[m]), int(p.obs_pt[m])
        noise = gtsam.noiseModel.Robust.Create(
            kernel, gtsam.noiseModel.Isotropic.Sigma(2, float(np.sqrt(p.obs_sigma2[m])))
        )
        u, v = p.obs_uv[m]
        graph.add(gtsam.GeneralSFMFactor2Cal3DS2(np.array([u, v]), noise, x(k), lm(j), k0))
        if p.obs_ur[m] >= 0:
            # (the right image's row is not measured: the pair's match is searched along the
            # left one's; a turn of the rig about its axis shifts it, and is found from u_R)
            right = np.array([float(p.obs_ur[m]), v])
            sigma = float(np.sqrt(p.obs_sigma2[m]))
            noise = gtsam.noiseModel.Robust.Create(
                kernel, gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma, _UNMEASURED * sigma]))
            )
            graph.add(ProjectionFactorPPPCCal3DS2(right, noise, x(k), rig_key, lm(j), k1,
                                                  False, False))  # fmt: skip
    return graph, values


def _within_gate_calibrated(
    p: BundleProblem, poses: list[Pose], points: FloatArray,
    K: tuple[gtsam.Cal3DS2, gtsam.Cal3DS2], T_L_R: Pose,
) -> NDArray[np.bool_]:  # fmt: skip
    """:func:`_within_gate` through the calibration found: each camera's distortion, the right
    camera through the rig."""
    from quadnav.geometry.camera import project_radtan

    Ks = [_matrix_and_distortion(k) for k in K]

    def errors(m: NDArray[np.int64], X: FloatArray) -> tuple[NDArray[np.bool_], FloatArray]:
        XR = T_L_R.inverse() @ X
        ok = (X[:, 2] > 0) & (XR[:, 2] > 0)
        X[~ok, 2], XR[~ok, 2] = 1.0, 1.0  # (their chi-square does not count)
        uv, ur = project_radtan(*Ks[0], X), project_radtan(*Ks[1], XR)
        e2 = np.sum((p.obs_uv[m] - uv) ** 2, axis=1)
        stereo = p.obs_ur[m] >= 0  # (u_R only: the right row is not measured)
        return ok, e2 + np.where(stereo, (p.obs_ur[m] - ur[:, 0]) ** 2, 0.0)

    return _gate(p, poses, points, errors)


def _gate(
    p: BundleProblem, poses: list[Pose], points: FloatArray,
    errors: Callable[[NDArray[np.int64], FloatArray], tuple[NDArray[np.bool_], FloatArray]],
) -> NDArray[np.bool_]:  # fmt: skip
    """Each observation's chi-square under its level's sigma against its gate (stereo or mono),
    its point in front: ``errors(observations, points in the camera)`` gives which are in
    front and their squared errors (px^2)."""
    keep = np.zeros(len(p.obs_kf), bool)
    for k, T in enumerate(poses):
        m = np.flatnonzero(p.obs_kf == k)
        if len(m) == 0:
            continue
        ok, e2 = errors(m, T.inverse() @ points[p.obs_pt[m]])
        chi2 = e2 / p.obs_sigma2[m]
        keep[m] = ok & (chi2 <= np.where(p.obs_ur[m] >= 0, CHI2_STEREO, CHI2_MONO))
    return keep


_UNMEASURED = 1e3  # (a residual's sigma, in its level's: a coordinate not measured)


def _in_front(p: BundleProblem, poses: list[Pose], points: FloatArray) -> NDArray[np.bool_]:
    """The observations whose point is at least 5 cm in front of its camera."""
    keep = np.zeros(len(p.obs_kf), bool)
    for k, T in enumerate(poses):
        m = np.flatnonzero(p.obs_kf == k)
        if len(m):
            keep[m] = (T.inverse() @ points[p.obs_pt[m]])[:, 2] > 0.05
    return keep


@contextmanager
def _c_stdout_silenced() -> Iterator[None]:
    """C's standard output (file descriptor 1) sent to the null device meanwhile, Python's
    streams flushed first; nothing done where it cannot be duplicated."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError):
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def _within_gate(
    p: BundleProblem,
    poses: list[Pose],
    points: FloatArray,
    cam: tuple[float, float, float, float, float],
) -> NDArray[np.bool_]:
    """Each observation's chi-square under its level's sigma against its gate, in front."""
    fx, fy, cx, cy, bf = cam

    def errors(m: NDArray[np.int64], X: FloatArray) -> tuple[NDArray[np.bool_], FloatArray]:
        z = X[:, 2]
        ok = z > 0
        zz = np.where(ok, z, 1.0)
        u, v = fx * X[:, 0] / zz + cx, fy * X[:, 1] / zz + cy
        e2 = (p.obs_uv[m, 0] - u) ** 2 + (p.obs_uv[m, 1] - v) ** 2
        stereo = p.obs_ur[m] >= 0
        return ok, e2 + np.where(stereo, (p.obs_ur[m] - (u - bf / zz)) ** 2, 0.0)

    return _gate(p, poses, points, errors)
