"""The sliding window (thesis 003 §3.3) with GTSAM: keyframe states ``X(k)`` (``T_W_B``),
``V(k)`` and ``B(k)`` joined by ``CombinedImuFactor``; explicit landmarks ``L(j)`` (world
points) seen through ``GenericProjectionFactorCal3_S2`` on undistorted normalised coordinates
(``Cal3_S2(1, 1, 0, 0, 0)``, sigma = pixel sigma / focal, the camera's ``T_B_C`` as
``body_P_sensor``) under a Huber loss; zero-velocity and no-motion constraints between
keyframes taken at rest.

Each keyframe the graph of the window is rebuilt and solved by Levenberg-Marquardt from the
previous estimates (robust where Gauss-Newton flips low-parallax points behind a camera). When
the window is full, its oldest keyframe leaves: the next one's marginal covariance (pose,
velocity, bias) becomes the window's prior, a tight Gaussian prior (no ``NonlinearEquality``).
Landmarks enter once seen in ``landmark_min_observations`` keyframes (or two with enough
parallax), triangulated (DLT) from the current estimates, only with a positive depth in every
view, a sane range and a small reprojection error; after each solve those behind a camera or
with a large error are dropped for good.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, L, V, X
from numpy.typing import NDArray

from quadnav.errors import VioError
from quadnav.geometry import Pose
from quadnav.vio.config import VioConfig
from quadnav.vio.frontend import FeatureManager

__all__ = ["Keyframe", "SlidingWindow", "SolveResult", "StatePrior", "pose3", "to_pose"]

FloatArray = NDArray[np.float64]

#: What GTSAM raises on a singular system or a failed solve.
GTSAM_ERRORS = (RuntimeError, IndexError, ValueError)


def pose3(p: Pose) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(p.R_A_B.as_matrix()), np.asarray(p.p_A_B, np.float64))


def to_pose(p: gtsam.Pose3) -> Pose:
    return Pose.from_matrix(p.matrix())


@dataclass(slots=True)
class Keyframe:
    """A window state: ``pim`` is the IMU from the previous keyframe (None for the first);
    ``still``: the vehicle was at rest since the previous keyframe."""

    index: int
    t_ns: int
    pose: gtsam.Pose3
    velocity: FloatArray
    bias: gtsam.imuBias.ConstantBias
    pim: gtsam.PreintegratedCombinedMeasurements | None = None
    still: bool = False


@dataclass(frozen=True, slots=True)
class StatePrior:
    """A Gaussian on the window's first state: covariances in GTSAM's tangent spaces."""

    cov_pose: FloatArray
    cov_v: FloatArray
    cov_bias: FloatArray


@dataclass(frozen=True, slots=True, kw_only=True)
class SolveResult:
    """How a solve went: ``ok`` and ``reason`` (why not), the newest keyframe's marginal
    covariances, landmark counts and the final error."""

    ok: bool
    reason: str = ""
    cov_pose: FloatArray = field(default_factory=lambda: np.eye(6))
    cov_v: FloatArray = field(default_factory=lambda: np.eye(3))
    landmarks: int = 0
    added: int = 0
    dropped: int = 0
    error: float = 0.0


def _camera_poses(kfs: dict[int, gtsam.Pose3], T_B_C: gtsam.Pose3) -> dict[int, FloatArray]:
    """The 3x4 ``[R_C_W | t_C_W]`` of each keyframe's camera."""
    out = {}
    for k, T_W_B in kfs.items():
        T_C_W = T_W_B.compose(T_B_C).inverse().matrix()
        out[k] = T_C_W[:3, :]
    return out


def triangulate(obs: dict[int, FloatArray], P: dict[int, FloatArray]) -> FloatArray | None:
    """The DLT point of normalised observations in the cameras ``P`` (None if degenerate)."""
    rows = []
    for k, xy in obs.items():
        Pk = P[k]
        rows.append(xy[0] * Pk[2] - Pk[0])
        rows.append(xy[1] * Pk[2] - Pk[1])
    _, _, Vt = np.linalg.svd(np.asarray(rows))
    h = Vt[-1]
    if abs(h[3]) < 1e-12:
        return None
    return np.asarray(h[:3] / h[3], np.float64)


def _project(p_W: FloatArray, Pk: FloatArray) -> tuple[float, FloatArray]:
    c = Pk[:, :3] @ p_W + Pk[:, 3]
    return float(c[2]), c[:2] / c[2] if abs(c[2]) > 1e-9 else np.full(2, np.inf)


class SlidingWindow:
    """Keyframes, landmarks and the prior of a fixed-size window (see the module)."""

    def __init__(self, config: VioConfig, T_B_C: Pose, focal_px: float) -> None:
        self.config = config
        self.T_B_C = pose3(T_B_C)
        self.focal_px = float(focal_px)
        self.K = gtsam.Cal3_S2(1.0, 1.0, 0.0, 0.0, 0.0)
        sigma = config.pixel_sigma_px / self.focal_px
        self._pixel_noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Huber.Create(config.huber_k),
            gtsam.noiseModel.Isotropic.Sigma(2, sigma),
        )
        self.keyframes: list[Keyframe] = []
        self.landmarks: dict[int, FloatArray] = {}
        self.bad_tracks: set[int] = set()
        self.prior: StatePrior | None = None

    def start(self, kf: Keyframe, prior: StatePrior) -> None:
        self.keyframes = [kf]
        self.landmarks = {}
        self.prior = prior

    def push(self, kf: Keyframe) -> None:
        if not self.keyframes or kf.pim is None:
            raise VioError("a keyframe after the first needs its preintegration")
        self.keyframes.append(kf)

    @property
    def newest(self) -> Keyframe:
        return self.keyframes[-1]

    def _add_states(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
        cfg = self.config
        first = self.keyframes[0]
        assert self.prior is not None
        graph.add(
            gtsam.PriorFactorPose3(
                X(first.index),
                first.pose,
                gtsam.noiseModel.Gaussian.Covariance(self.prior.cov_pose),
            )
        )
        graph.add(
            gtsam.PriorFactorVector(
                V(first.index),
                first.velocity,
                gtsam.noiseModel.Gaussian.Covariance(self.prior.cov_v),
            )
        )
        graph.add(
            gtsam.PriorFactorConstantBias(
                B(first.index),
                first.bias,
                gtsam.noiseModel.Gaussian.Covariance(self.prior.cov_bias),
            )
        )
        s_p, s_v = cfg.static_pose_sigma_m, cfg.static_velocity_sigma_m_s
        still_pose = gtsam.noiseModel.Isotropic.Sigma(6, s_p)
        still_v = gtsam.noiseModel.Isotropic.Sigma(3, s_v)
        prev = None
        for kf in self.keyframes:
            k = kf.index
            values.insert(X(k), kf.pose)
            values.insert(V(k), kf.velocity)
            values.insert(B(k), kf.bias)
            if prev is not None and kf.pim is not None:
                j = prev.index
                graph.add(gtsam.CombinedImuFactor(X(j), V(j), X(k), V(k), B(j), B(k), kf.pim))
                if kf.still:
                    graph.add(gtsam.BetweenFactorPose3(X(j), X(k), gtsam.Pose3(), still_pose))
                    graph.add(gtsam.PriorFactorVector(V(j), np.zeros(3), still_v))
                    graph.add(gtsam.PriorFactorVector(V(k), np.zeros(3), still_v))
            prev = kf

    def _new_landmark(
        self, obs: dict[int, FloatArray], P: dict[int, FloatArray], centres: dict[int, FloatArray]
    ) -> FloatArray | None:
        """A track's point if it may enter: enough views or parallax, in front, near its pixels."""
        cfg = self.config
        if len(obs) < 2:
            return None
        p = triangulate(obs, P)
        if p is None or not np.isfinite(p).all():
            return None
        rays = [p - centres[k] for k in obs]
        norms = [float(np.linalg.norm(r)) for r in rays]
        if min(norms) < 1e-9:
            return None
        cosang = min(
            float(rays[0] @ r) / (norms[0] * n) for r, n in zip(rays[1:], norms[1:], strict=True)
        )
        angle = float(np.arccos(np.clip(cosang, -1.0, 1.0)))
        need = (
            3.0 / cfg.parallax_focal_px
            if len(obs) >= cfg.landmark_min_observations
            else cfg.landmark_min_parallax_px / cfg.parallax_focal_px
        )
        if angle < need:
            return None
        return p if self._landmark_ok(p, obs, P) else None

    def _landmark_ok(
        self, p: FloatArray, obs: dict[int, FloatArray], P: dict[int, FloatArray]
    ) -> bool:
        cfg = self.config
        for k, xy in obs.items():
            z, uv = _project(p, P[k])
            if not cfg.landmark_min_depth_m <= z <= cfg.landmark_max_depth_m:
                return False
            if float(np.linalg.norm(uv - xy)) * self.focal_px > cfg.max_reprojection_px:
                return False
        return True

    def _add_landmarks(
        self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, features: FeatureManager
    ) -> int:
        poses = {kf.index: kf.pose for kf in self.keyframes}
        P = _camera_poses(poses, self.T_B_C)
        centres = {k: -Pk[:, :3].T @ Pk[:, 3] for k, Pk in P.items()}
        added = 0
        for j, obs_all in features.tracks.items():
            if j in self.bad_tracks:
                continue
            obs = {k: xy for k, xy in obs_all.items() if k in P}
            if len(obs) < 2:
                continue
            p = self.landmarks.get(j)
            if p is None:
                p = self._new_landmark(obs, P, centres)
                if p is None:
                    continue
                self.landmarks[j] = p
                added += 1
            values.insert(L(j), p)
            for k, xy in obs.items():
                graph.add(
                    gtsam.GenericProjectionFactorCal3_S2(
                        xy, self._pixel_noise, X(k), L(j), self.K, self.T_B_C
                    )
                )
        return added

    def _read_back(self, result: gtsam.Values, features: FeatureManager) -> int:
        """New estimates in; landmarks behind a camera or far from their pixels out."""
        for kf in self.keyframes:
            kf.pose = result.atPose3(X(kf.index))
            kf.velocity = np.asarray(result.atVector(V(kf.index)), np.float64)
            kf.bias = result.atConstantBias(B(kf.index))
        poses = {kf.index: kf.pose for kf in self.keyframes}
        P = _camera_poses(poses, self.T_B_C)
        dropped = 0
        for j in list(self.landmarks):
            if not result.exists(L(j)):
                continue
            p = np.asarray(result.atPoint3(L(j)), np.float64)
            obs = {k: xy for k, xy in features.observations(j).items() if k in P}
            if self._landmark_ok(p, obs, P):
                self.landmarks[j] = p
            else:
                del self.landmarks[j]
                self.bad_tracks.add(j)
                dropped += 1
        return dropped

    def solve(self, features: FeatureManager) -> SolveResult:
        """Optimise the window; then slide it if it is over-full. Never raises GTSAM's errors."""
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        self._add_states(graph, values)
        added = self._add_landmarks(graph, values, features)
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self.config.optimizer_iterations)
        try:
            result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
            err = float(graph.error(result))
            if not np.isfinite(err):
                return SolveResult(ok=False, reason="the optimisation diverged (non-finite error)")
            dropped = self._read_back(result, features)
            marg = gtsam.Marginals(graph, result)
            k = self.newest.index
            cov_pose = np.asarray(marg.marginalCovariance(X(k)))
            cov_v = np.asarray(marg.marginalCovariance(V(k)))
            self._slide(marg, features)
        except GTSAM_ERRORS as exc:
            return SolveResult(ok=False, reason=f"indeterminate optimisation: {exc}".split("\n")[0])
        return SolveResult(
            ok=True,
            cov_pose=cov_pose,
            cov_v=cov_v,
            landmarks=len(self.landmarks),
            added=added,
            dropped=dropped,
            error=err,
        )

    def _slide(self, marg: gtsam.Marginals, features: FeatureManager) -> None:
        """Drop the oldest keyframe when the window is over-full; its successor's marginal is
        the new prior (symmetrised)."""
        if len(self.keyframes) <= self.config.window_keyframes:
            return
        nxt = self.keyframes[1].index

        def sym(c: FloatArray) -> FloatArray:
            c = np.asarray(c, np.float64)
            return 0.5 * (c + c.T) + 1e-12 * np.eye(len(c))

        self.prior = StatePrior(
            cov_pose=sym(marg.marginalCovariance(X(nxt))),
            cov_v=sym(marg.marginalCovariance(V(nxt))),
            cov_bias=sym(marg.marginalCovariance(B(nxt))),
        )
        old = self.keyframes.pop(0)
        features.drop_keyframe(old.index)
        self.keyframes[0].pim = None
        for j in list(self.landmarks):
            if len([k for k in features.observations(j) if k != old.index]) == 0:
                del self.landmarks[j]
