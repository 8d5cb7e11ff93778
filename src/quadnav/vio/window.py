"""The sliding window (thesis 003 §3.3) with GTSAM: keyframe states ``X(k)`` (``T_W_B``),
``V(k)`` and ``B(k)`` joined by ``CombinedImuFactor``; explicit landmarks ``L(j)`` (world
points) seen through ``GenericProjectionFactorCal3_S2`` on undistorted normalised coordinates
(``Cal3_S2(1, 1, 0, 0, 0)``, sigma = pixel sigma / focal, the camera's ``T_B_C`` as
``body_P_sensor``) under a Huber loss; zero-velocity and no-motion constraints between
keyframes taken at rest.

GTSAM's ``BatchFixedLagSmoother`` (Levenberg-Marquardt: robust where Gauss-Newton flips
low-parallax points behind a camera) keeps the last ``window_keyframes`` keyframes and
marginalises the older ones (their information stays as a linear factor). Its clock is the
keyframe number: a state has its keyframe's, a landmark that of the first keyframe it was made
with, so it is marginalised with that keyframe, as VINS-Mono marginalises the features anchored
in its oldest frame: the marginal factor then ties states only (a prior renewed with each
landmark would tie every landmark together and grow dense). A track still seen goes on as a
new landmark once the observations the prior does not hold yet would make one (the old
estimate is its starting value only: a prior from it would count those observations twice,
and, fixed in the world, would tie the window's position and yaw, which the data cannot
observe, so that the covariance would stop growing with the drift). The first state has a
tight Gaussian prior (no ``NonlinearEquality``: it forces a slow QR path).
Landmarks enter once seen in ``landmark_min_observations`` keyframes (or two with enough
parallax), triangulated (DLT) from the current estimates, only with a positive depth in every
view, a sane range and a small reprojection error; after each solve those behind a camera or
with a large error lose their projection factors for good (a weak prior keeps each landmark
determinate until it leaves the window: see ``LANDMARK_PRIOR_M``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, L, V, X
from numpy.typing import NDArray

from quadnav.errors import VioError
from quadnav.geometry import Pose
from quadnav.geometry.gtsam_bridge import pose3
from quadnav.geometry.multiview import reprojection_errors, triangulate_track
from quadnav.vio.config import VioConfig
from quadnav.vio.frontend import FeatureManager

__all__ = ["Keyframe", "SlidingWindow", "SolveResult", "StatePrior"]

FloatArray = NDArray[np.float64]

#: What GTSAM raises on a singular system or a failed solve.
GTSAM_ERRORS = (RuntimeError, IndexError, ValueError)
#: The weak prior that keeps each landmark determinate: its range (m) and bearing (rad) from
#: the keyframe it is anchored in, as first estimated. Relative to a state, it says nothing
#: about the window's position and yaw (a prior in the world would: one per landmark adds up).
LANDMARK_PRIOR_M = 10.0
LANDMARK_PRIOR_RAD = 1.0


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


def _bearing_angle(obs: dict[int, FloatArray], P: dict[int, FloatArray]) -> float:
    """The angle (rad) between the world bearings of a track's first and last observations."""
    k0, k1 = min(obs), max(obs)
    b0 = P[k0][:, :3].T @ np.array([obs[k0][0], obs[k0][1], 1.0])
    b1 = P[k1][:, :3].T @ np.array([obs[k1][0], obs[k1][1], 1.0])
    c = float(b0 @ b1) / float(np.linalg.norm(b0) * np.linalg.norm(b1))
    return float(np.arccos(min(1.0, max(-1.0, c))))


class SlidingWindow:
    """Keyframes and landmarks of a fixed-lag window (see the module)."""

    def __init__(
        self, config: VioConfig, T_B_C: Pose, focal_px: float, T_B_R: Pose | None = None
    ) -> None:
        self.config = config
        self.T_B_C = pose3(T_B_C)
        #: a stereo rig's second camera: its observations are projection factors too, and a
        #: track seen by both in one keyframe near enough may enter at once
        self.T_B_R = None if T_B_R is None else pose3(T_B_R)
        self._baseline_m = (
            0.0 if T_B_R is None else float(np.linalg.norm((T_B_C.inverse() @ T_B_R).p_A_B))
        )
        self._seen_r: dict[int, set[int]] = {}  # track -> keyframes with its right factor in
        self._used_r: dict[int, set[int]] = {}  # track -> right views in the prior
        self.focal_px = float(focal_px)
        self.K = gtsam.Cal3_S2(1.0, 1.0, 0.0, 0.0, 0.0)
        sigma = config.pixel_sigma_px / self.focal_px
        self._pixel_noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Huber.Create(config.huber_k),
            gtsam.noiseModel.Isotropic.Sigma(2, sigma),
        )
        #: a weak prior on every landmark: a point the Huber loss has all but let go of, or
        #: whose projections were taken out, stays determinate
        self._landmark_prior = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([LANDMARK_PRIOR_RAD, LANDMARK_PRIOR_RAD, LANDMARK_PRIOR_M])
        )
        self.keyframes: list[Keyframe] = []
        self.landmarks: dict[int, FloatArray] = {}
        self.bad_tracks: set[int] = set()
        self._seen: dict[int, set[int]] = {}  # track -> keyframes with its factor in
        self._key: dict[int, int] = {}  # track -> the number of its landmark's key L(n)
        self._used: dict[
            int, set[int]
        ] = {}  # track -> keyframes already marginalised into the prior
        self._next_key = 0
        self._seed: dict[int, FloatArray] = {}
        self._remove: list[int] = []
        self._smoother: gtsam.BatchFixedLagSmoother | None = None
        self._new = self._pending()

    @staticmethod
    def _pending() -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, dict[int, float]]:
        return gtsam.NonlinearFactorGraph(), gtsam.Values(), {}

    def start(self, kf: Keyframe, prior: StatePrior) -> None:
        """A new window from ``kf`` with a Gaussian ``prior`` on its state."""
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self.config.optimizer_iterations)
        params.setRelativeErrorTol(1e-3)
        params.setlambdaUpperBound(1e6)
        self._smoother = gtsam.BatchFixedLagSmoother(self.config.window_keyframes - 0.5, params)
        self.keyframes, self.landmarks, self._remove = [kf], {}, []
        self._seen, self._key, self._used = {}, {}, {}
        self._seen_r, self._used_r = {}, {}
        self._new = graph, _, _ = self._pending()
        k = kf.index
        gauss = gtsam.noiseModel.Gaussian.Covariance
        graph.add(gtsam.PriorFactorPose3(X(k), kf.pose, gauss(prior.cov_pose)))
        graph.add(gtsam.PriorFactorVector(V(k), kf.velocity, gauss(prior.cov_v)))
        graph.add(gtsam.PriorFactorConstantBias(B(k), kf.bias, gauss(prior.cov_bias)))
        self._insert_state(kf)

    def seed_landmarks(self, points_W: dict[int, FloatArray]) -> None:
        """Points (an initialisation's) to start tracks from instead of triangulating them."""
        self._seed.update({int(j): np.asarray(p, np.float64) for j, p in points_W.items()})

    def _insert_state(self, kf: Keyframe) -> None:
        _, values, ts = self._new
        for key, value in ((X(kf.index), kf.pose), (V(kf.index), kf.velocity)):
            values.insert(key, value)
            ts[key] = float(kf.index)
        values.insert(B(kf.index), kf.bias)
        ts[B(kf.index)] = float(kf.index)

    def push(self, kf: Keyframe) -> None:
        """The next keyframe, joined to the newest by its preintegrated IMU (and, at rest, by
        zero-velocity and no-motion constraints)."""
        if not self.keyframes or kf.pim is None:
            raise VioError("a keyframe after the first needs its preintegration")
        prev = self.keyframes[-1]
        graph = self._new[0]
        j, k = prev.index, kf.index
        graph.add(gtsam.CombinedImuFactor(X(j), V(j), X(k), V(k), B(j), B(k), kf.pim))
        if kf.still:
            cfg = self.config
            still_pose = gtsam.noiseModel.Isotropic.Sigma(6, cfg.static_pose_sigma_m)
            still_v = gtsam.noiseModel.Isotropic.Sigma(3, cfg.static_velocity_sigma_m_s)
            graph.add(gtsam.BetweenFactorPose3(X(j), X(k), gtsam.Pose3(), still_pose))
            graph.add(gtsam.PriorFactorVector(V(j), np.zeros(3), still_v))
            graph.add(gtsam.PriorFactorVector(V(k), np.zeros(3), still_v))
        self.keyframes.append(kf)
        self._insert_state(kf)

    @property
    def newest(self) -> Keyframe:
        return self.keyframes[-1]

    def _parallax_needed(self, views: int) -> float:
        """The angle (rad) between a track's first and last views it needs to enter."""
        cfg = self.config
        px = 3.0 if views >= cfg.landmark_min_observations else cfg.landmark_min_parallax_px
        return px / cfg.parallax_focal_px

    def _enough_parallax(self, obs: dict[int, FloatArray], P: dict[int, FloatArray]) -> bool:
        return len(obs) >= 2 and _bearing_angle(obs, P) >= self._parallax_needed(len(obs))

    def _new_landmark(
        self, obs: dict[int, FloatArray], P: dict[int, FloatArray], centres: dict[int, FloatArray]
    ) -> FloatArray | None:
        """A track's point if it may enter: enough views or parallax, in front, near its pixels."""
        if not self._enough_parallax(obs, P):  # not worth a triangulation
            return None
        need = self._parallax_needed(len(obs))
        p = triangulate_track(obs, P)
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
        if angle < need:
            return None
        return p if self._landmark_ok(p, obs, P) else None

    def _landmark_ok(
        self, p: FloatArray, obs: dict[int, FloatArray], P: dict[int, FloatArray]
    ) -> bool:
        """In front of every camera at a sane range and near every pixel it was seen at."""
        cfg = self.config
        Ps = np.array([P[k] for k in obs])
        err, z = reprojection_errors(Ps, p, np.array(list(obs.values())))
        if not (np.all(z >= cfg.landmark_min_depth_m) and np.all(z <= cfg.landmark_max_depth_m)):
            return False
        return bool(np.all(err * self.focal_px <= cfg.max_reprojection_px))

    def _add_landmarks(self, features: FeatureManager) -> int:
        """Projection factors of the new observations of landmarks, and new landmarks."""
        graph, values, ts = self._new
        poses = {kf.index: kf.pose for kf in self.keyframes}
        P = _camera_poses(poses, self.T_B_C)
        PR = _camera_poses(poses, self.T_B_R) if self.T_B_R is not None else {}
        centres = {k: -Pk[:, :3].T @ Pk[:, 3] for k, Pk in P.items()}
        added = 0
        for j, obs_all in features.tracks.items():
            if j in self.bad_tracks:
                continue
            obs = {k: xy for k, xy in obs_all.items() if k in P}
            robs = {k: xy for k, xy in features.right.get(j, {}).items() if k in PR}
            if j not in self.landmarks:
                used = self._used.get(j, set())
                used_r = self._used_r.get(j, set())
                # a track whose landmark was marginalised enters again from the views the
                # prior does not hold, as a new track would: no prior from the old estimate
                fresh = {k: xy for k, xy in obs.items() if k not in used}
                rfresh = {k: xy for k, xy in robs.items() if k not in used_r}
                mono = len(fresh) >= 2 and (not used or self._enough_parallax(fresh, P))
                if not mono and not rfresh:
                    continue
                p = self._seed.get(j)
                if p is None or not fresh or not self._landmark_ok(p, fresh, P):
                    p = self._new_landmark(fresh, P, centres) if mono else None
                if p is None and rfresh:
                    p = self._stereo_landmark(fresh, rfresh, P, PR)
                if p is None:
                    continue
                self._seed.pop(j, None)
                self._seen_r[j] = set(used_r)
                self.landmarks[j] = p
                self._seen[j] = set(used)  # already in the prior: not again
                self._key[j] = self._next_key
                self._next_key += 1
                values.insert(L(self._key[j]), p)
                anchor = min(fresh)  # it leaves with its first keyframe
                ts[L(self._key[j])] = float(anchor)
                T_W_B = poses[anchor]
                graph.add(
                    gtsam.BearingRangeFactor3D(
                        X(anchor), L(self._key[j]), T_W_B.bearing(p), T_W_B.range(p),
                        self._landmark_prior,
                    )
                )  # fmt: skip
                added += 1
            seen, key = self._seen[j], L(self._key[j])
            for k, xy in obs.items():
                if k not in seen:
                    graph.add(
                        gtsam.GenericProjectionFactorCal3_S2(
                            xy, self._pixel_noise, X(k), key, self.K, self.T_B_C
                        )
                    )
                    seen.add(k)
            if robs:
                self._add_right(j, robs, key)
        return added

    def _add_right(self, j: int, robs: dict[int, FloatArray], key: int) -> None:
        """The projection factors of a landmark's new observations in the second camera."""
        graph, T_B_R = self._new[0], self.T_B_R
        assert T_B_R is not None
        seen = self._seen_r.setdefault(j, set())
        for k, xy in robs.items():
            if k not in seen:
                graph.add(
                    gtsam.GenericProjectionFactorCal3_S2(
                        xy, self._pixel_noise, X(k), key, self.K, T_B_R
                    )
                )
                seen.add(k)

    def _stereo_landmark(
        self,
        obs: dict[int, FloatArray],
        robs: dict[int, FloatArray],
        P: dict[int, FloatArray],
        PR: dict[int, FloatArray],
    ) -> FloatArray | None:
        """A track's point from its views in both cameras (a stereo pair is enough), if it is
        within ``stereo_max_depth_baselines`` of a camera that sees it in stereo, in front of
        every view and near every pixel."""
        cfg = self.config
        views: dict[tuple[int, int], FloatArray] = {(k, 0): xy for k, xy in obs.items()}
        views.update({(k, 1): xy for k, xy in robs.items()})
        Pv = {(k, 0): P[k] for k in obs} | {(k, 1): PR[k] for k in robs}
        p = triangulate_track(views, Pv)
        if p is None:
            return None
        err, z = reprojection_errors(
            np.array([Pv[v] for v in views]), p, np.array(list(views.values()))
        )
        far = min(cfg.landmark_max_depth_m, cfg.stereo_max_depth_baselines * self._baseline_m)
        near_pair = any(
            zz <= far for (k, c), zz in zip(views, z, strict=True) if c == 1 and (k, 0) in views
        )
        if not near_pair or not np.all(z >= cfg.landmark_min_depth_m):
            return None
        return p if bool(np.all(err * self.focal_px <= cfg.max_reprojection_px)) else None

    def _read_back(self, est: gtsam.Values, features: FeatureManager) -> int:
        """The smoother's estimates in; marginalised keyframes and landmarks out; landmarks
        behind a camera or far from their pixels lose their projections."""
        gone = [kf for kf in self.keyframes if not est.exists(X(kf.index))]
        for kf in gone:
            features.drop_keyframe(kf.index)
        self.keyframes = [kf for kf in self.keyframes if est.exists(X(kf.index))]
        for kf in self.keyframes:
            kf.pose = est.atPose3(X(kf.index))
            kf.velocity = np.asarray(est.atVector(V(kf.index)), np.float64)
            kf.bias = est.atConstantBias(B(kf.index))
        for j in list(self.landmarks):
            key = L(self._key[j])
            if est.exists(key):
                self.landmarks[j] = np.asarray(est.atPoint3(key), np.float64)
                continue
            # marginalised with its first keyframe: the track goes on as a new landmark, from
            # the observations the prior does not hold yet
            self._seed[j] = self.landmarks.pop(j)
            self._used[j] = self._seen.pop(j)
            self._used_r[j] = self._seen_r.pop(j, set())
            del self._key[j]
        for j in [j for j in self._used if j not in features.tracks]:
            del self._used[j]
            self._used_r.pop(j, None)
            self._seed.pop(j, None)
        self.bad_tracks.intersection_update(features.tracks)  # an ended track's verdict goes
        poses = {kf.index: kf.pose for kf in self.keyframes}
        P = _camera_poses(poses, self.T_B_C)
        PR = _camera_poses(poses, self.T_B_R) if self.T_B_R is not None else {}
        live = [j for j in self.landmarks if j not in self.bad_tracks]
        bad = self._bad_landmarks(live, features, P, PR)
        if bad:
            self.bad_tracks.update(bad)
            self._remove = self._projection_slots({L(self._key[j]) for j in bad})
        return len(bad)

    def _projection_slots(self, keys: set[int]) -> list[int]:
        """Where in the smoother the projection factors of these landmarks are."""
        assert self._smoother is not None
        fs = self._smoother.getFactors()
        out = []
        for i in range(fs.size()):
            f = fs.at(i)
            if isinstance(f, gtsam.GenericProjectionFactorCal3_S2) and f.keys()[1] in keys:
                out.append(i)
        return out

    def _bad_landmarks(
        self,
        js: list[int],
        features: FeatureManager,
        P: dict[int, FloatArray],
        PR: dict[int, FloatArray],
    ) -> list[int]:
        """The landmarks behind or too near or far from a camera, or too far from a pixel, in
        the views they have projection factors in (either camera of a stereo rig)."""
        cfg = self.config
        owner, cams, meas = [], [], []
        for j in js:
            used, used_r = self._used.get(j, ()), self._used_r.get(j, ())  # held by the prior
            for book, views, held in (
                (features.observations(j), P, used),
                (features.right.get(j, {}), PR, used_r),
            ):
                for k, xy in book.items():
                    if k in views and k not in held:
                        owner.append(j)
                        cams.append(views[k])
                        meas.append(xy)
        if not owner:
            return []
        pts = np.array([self.landmarks[j] for j in owner])
        e, z = reprojection_errors(np.array(cams), pts, np.array(meas))
        err = e * self.focal_px
        wrong = ~(
            (z >= cfg.landmark_min_depth_m)
            & (z <= cfg.landmark_max_depth_m)
            & (err <= cfg.max_reprojection_px)
        )
        return sorted({owner[i] for i in np.flatnonzero(wrong)})

    def solve(self, features: FeatureManager) -> SolveResult:
        """Add what is new and let the smoother optimise and marginalise. Never raises
        GTSAM's errors: a failed solve is a result that says why."""
        if self._smoother is None:
            raise VioError("the window has not been started")
        added = self._add_landmarks(features)
        graph, values, ts = self._new
        self._new = self._pending()
        remove, self._remove = self._remove, []
        try:
            self._smoother.update(graph, values, dict(ts.items()), remove)
            est = self._smoother.calculateEstimate()
            dropped = self._read_back(est, features)
            factors = self._smoother.getFactors()
            err = float(factors.error(est))
            if not np.isfinite(err):
                return SolveResult(ok=False, reason="the optimisation diverged (non-finite error)")
            marg = gtsam.Marginals(factors, est)
            k = self.newest.index
            cov_pose = np.asarray(marg.marginalCovariance(X(k)))
            cov_v = np.asarray(marg.marginalCovariance(V(k)))
        except GTSAM_ERRORS as exc:
            line = next((ln for ln in str(exc).splitlines() if ln.strip()), type(exc).__name__)
            return SolveResult(ok=False, reason=f"optimisation failed: {line.strip()}")
        return SolveResult(
            ok=True, cov_pose=cov_pose, cov_v=cov_v, landmarks=len(self.landmarks),
            added=added, dropped=dropped, error=err,
        )  # fmt: skip

    def landmark_position(self, track: int) -> FloatArray | None:
        """Where the window puts a track's landmark (in ``W``): its estimate, or the last one
        it had when its first keyframe was marginalised; None if it has none (or a bad one)."""
        if track in self.bad_tracks:
            return None
        p = self.landmarks.get(track)
        return p if p is not None else self._seed.get(track)
