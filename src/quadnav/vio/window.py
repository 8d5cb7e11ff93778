"""The sliding window (thesis 003 §3.3): keyframe states ``X(k)`` (``T_W_B``), ``V(k)`` and
``B(k)`` joined by GTSAM's ``CombinedImuFactor``; explicit landmarks ``L(j)`` (world points) seen
through ``GenericProjectionFactorCal3_S2`` on undistorted normalised coordinates
(``Cal3_S2(1, 1, 0, 0, 0)``, sigma = pixel sigma / focal, the camera's ``T_B_C`` as
``body_P_sensor``) under a Huber loss; zero-velocity and no-motion constraints between keyframes
taken at rest.

The window is split by role, as OpenVINS splits its state, propagator and updater:

- :mod:`quadnav.vio.landmarks` decides the landmark life cycle (which tracks enter, with which
  point, which go bad, what a marginalised landmark becomes);
- :mod:`quadnav.vio.graph` holds the factor graph and its fixed-lag smoother;
- this module keeps the keyframe states, turns the landmark decisions into factors, and takes
  extra factors (GPS, loop-closure priors) from hooks (:meth:`SlidingWindow.add_hook`);
- the IMU between frames is :mod:`quadnav.vio.propagator`'s.

The smoother's clock is the keyframe number: a state has its keyframe's, a landmark that of the
keyframe it is anchored in, so it is marginalised with that keyframe and the marginal factor
ties states only. The first state has a tight Gaussian prior (no ``NonlinearEquality``: it
forces a slow QR path). Each landmark has a weak bearing-range prior from its anchor keyframe
(:data:`LANDMARK_PRIOR_M`, :data:`LANDMARK_PRIOR_RAD`), so that a point the Huber loss has all
but let go of, or whose projections were taken out, stays determinate; relative to a state, it
says nothing about the window's position and yaw (a prior in the world would: one per landmark
adds up).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, L, V, X
from numpy.typing import NDArray

from quadnav.errors import VioError
from quadnav.geometry import Pose
from quadnav.geometry.gtsam_bridge import pose3
from quadnav.vio.config import VioConfig
from quadnav.vio.frontend import FeatureManager
from quadnav.vio.graph import GTSAM_ERRORS, WindowGraph
from quadnav.vio.landmarks import Admission, LandmarkBook

__all__ = [
    "FactorHook",
    "Keyframe",
    "SlidingWindow",
    "SolveResult",
    "StatePrior",
    "state_keys",
]

FloatArray = NDArray[np.float64]

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


#: Extra factors for a keyframe as it enters the window (a GPS fix at its time, a loop
#: closure's prior): keys from :func:`state_keys`.
FactorHook = Callable[[Keyframe], Sequence[gtsam.NonlinearFactor]]


def state_keys(index: int) -> tuple[int, int, int]:
    """The GTSAM keys of keyframe ``index``'s pose ``T_W_B``, velocity and IMU bias."""
    return X(index), V(index), B(index)


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
    return {k: T_W_B.compose(T_B_C).inverse().matrix()[:3, :] for k, T_W_B in kfs.items()}


class SlidingWindow:
    """Keyframes and landmarks of a fixed-lag window (see the module)."""

    def __init__(
        self, config: VioConfig, T_B_C: Pose, focal_px: float, T_B_R: Pose | None = None
    ) -> None:
        self.config = config
        self.T_B_C = pose3(T_B_C)
        #: a stereo rig's second camera: its observations are projection factors too
        self.T_B_R = None if T_B_R is None else pose3(T_B_R)
        baseline = 0.0 if T_B_R is None else float(np.linalg.norm((T_B_C.inverse() @ T_B_R).p_A_B))
        self.focal_px = float(focal_px)
        self.K = gtsam.Cal3_S2(1.0, 1.0, 0.0, 0.0, 0.0)
        sigma = config.pixel_sigma_px / self.focal_px
        self._pixel_noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Huber.Create(config.huber_k),
            gtsam.noiseModel.Isotropic.Sigma(2, sigma),
        )
        self._landmark_prior = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([LANDMARK_PRIOR_RAD, LANDMARK_PRIOR_RAD, LANDMARK_PRIOR_M])
        )
        self.keyframes: list[Keyframe] = []
        self.book = LandmarkBook(config, focal_px, baseline)
        self._hooks: list[FactorHook] = []
        self.graph: WindowGraph | None = None

    # -- what the rest of the VIO reads -----------------------------------------------------
    @property
    def landmarks(self) -> dict[int, FloatArray]:
        return self.book.landmarks

    @property
    def bad_tracks(self) -> set[int]:
        return self.book.bad_tracks

    @property
    def newest(self) -> Keyframe:
        return self.keyframes[-1]

    def landmark_position(self, track: int) -> FloatArray | None:
        """Where the window puts a track's landmark (in ``W``), or None (see
        :meth:`LandmarkBook.position`)."""
        return self.book.position(track)

    def add_hook(self, hook: FactorHook) -> None:
        """Call ``hook`` for each keyframe entering the window (the first included) and add
        the factors it returns (a GPS fix, a loop-closure prior)."""
        self._hooks.append(hook)

    # -- building ---------------------------------------------------------------------------
    def start(self, kf: Keyframe, prior: StatePrior) -> None:
        """A new window from ``kf`` with a Gaussian ``prior`` on its state."""
        self.graph = WindowGraph(self.config, self.config.window_keyframes - 0.5)
        self.keyframes = [kf]
        self.book.clear()
        x, v, b = state_keys(kf.index)
        gauss = gtsam.noiseModel.Gaussian.Covariance
        self.graph.add_all([
            gtsam.PriorFactorPose3(x, kf.pose, gauss(prior.cov_pose)),
            gtsam.PriorFactorVector(v, kf.velocity, gauss(prior.cov_v)),
            gtsam.PriorFactorConstantBias(b, kf.bias, gauss(prior.cov_bias)),
        ])  # fmt: skip
        self._insert_state(kf)

    def seed_landmarks(self, points_W: dict[int, FloatArray]) -> None:
        """Points (an initialisation's) to start tracks from instead of triangulating them."""
        self.book.seed(points_W)

    def _insert_state(self, kf: Keyframe) -> None:
        assert self.graph is not None
        x, v, b = state_keys(kf.index)
        for key, value in ((x, kf.pose), (v, kf.velocity), (b, kf.bias)):
            self.graph.insert(key, value, kf.index)
        for hook in self._hooks:
            self.graph.add_all(hook(kf))

    def push(self, kf: Keyframe) -> None:
        """The next keyframe, joined to the newest by its preintegrated IMU (and, at rest, by
        zero-velocity and no-motion constraints)."""
        if not self.keyframes or kf.pim is None or self.graph is None:
            raise VioError("a keyframe after the first needs its preintegration")
        j, k = self.keyframes[-1].index, kf.index
        graph = self.graph
        graph.add(gtsam.CombinedImuFactor(X(j), V(j), X(k), V(k), B(j), B(k), kf.pim))
        if kf.still:
            cfg = self.config
            still_pose = gtsam.noiseModel.Isotropic.Sigma(6, cfg.static_pose_sigma_m)
            still_v = gtsam.noiseModel.Isotropic.Sigma(3, cfg.static_velocity_sigma_m_s)
            graph.add_all([
                gtsam.BetweenFactorPose3(X(j), X(k), gtsam.Pose3(), still_pose),
                gtsam.PriorFactorVector(V(j), np.zeros(3), still_v),
                gtsam.PriorFactorVector(V(k), np.zeros(3), still_v),
            ])  # fmt: skip
        self.keyframes.append(kf)
        self._insert_state(kf)

    def _cameras(self) -> tuple[dict[int, FloatArray], dict[int, FloatArray]]:
        """The window's camera matrices: the camera's and (stereo) the second camera's."""
        poses = {kf.index: kf.pose for kf in self.keyframes}
        P = _camera_poses(poses, self.T_B_C)
        PR = _camera_poses(poses, self.T_B_R) if self.T_B_R is not None else {}
        return P, PR

    def _add_landmarks(self, features: FeatureManager) -> int:
        """The landmark book's decisions as values and factors: new landmarks with their
        bearing-range prior from the anchor keyframe, and projection factors."""
        assert self.graph is not None
        adm: Admission = self.book.admit(features, *self._cameras())
        poses = {kf.index: kf.pose for kf in self.keyframes}
        for new in adm.new:
            key = L(new.key)
            self.graph.insert(key, new.point_W, new.anchor)  # it leaves with its anchor
            T_W_B = poses[new.anchor]
            self.graph.add(
                gtsam.BearingRangeFactor3D(
                    X(new.anchor), key, T_W_B.bearing(new.point_W), T_W_B.range(new.point_W),
                    self._landmark_prior,
                )
            )  # fmt: skip
        for ob in adm.observations:
            T = self.T_B_R if ob.side == 1 and self.T_B_R is not None else self.T_B_C
            self.graph.add(
                gtsam.GenericProjectionFactorCal3_S2(
                    ob.xy, self._pixel_noise, X(ob.keyframe), L(ob.key), self.K, T
                )
            )
        return len(adm.new)

    # -- solving ----------------------------------------------------------------------------
    def _read_back(self, est: gtsam.Values, features: FeatureManager) -> int:
        """The smoother's estimates in; marginalised keyframes and landmarks out; landmarks
        behind a camera or far from their pixels lose their projections."""
        assert self.graph is not None
        for kf in self.keyframes:
            if not est.exists(X(kf.index)):
                features.drop_keyframe(kf.index)
        self.keyframes = [kf for kf in self.keyframes if est.exists(X(kf.index))]
        for kf in self.keyframes:
            kf.pose = est.atPose3(X(kf.index))
            kf.velocity = np.asarray(est.atVector(V(kf.index)), np.float64)
            kf.bias = est.atConstantBias(B(kf.index))

        def point(n: int) -> FloatArray | None:
            key = L(n)
            return np.asarray(est.atPoint3(key), np.float64) if est.exists(key) else None

        self.book.read_back(point, features)
        bad = self.book.mark_bad(features, *self._cameras())
        if bad:
            keys = {L(n) for n in bad}
            self.graph.remove_where(
                lambda f: (
                    not (
                        isinstance(f, gtsam.GenericProjectionFactorCal3_S2) and f.keys()[1] in keys
                    )
                )
            )
        return len(bad)

    def solve(self, features: FeatureManager) -> SolveResult:
        """Add what is new and let the smoother optimise and marginalise. Never raises
        GTSAM's errors: a failed solve is a result that says why."""
        if self.graph is None:
            raise VioError("the window has not been started")
        added = self._add_landmarks(features)
        x, v, _ = state_keys(self.newest.index)
        try:
            sol = self.graph.solve(covariance_of=(x, v))
            if not np.isfinite(sol.error):
                return SolveResult(ok=False, reason="the optimisation diverged (non-finite error)")
            dropped = self._read_back(sol.estimate, features)
        except GTSAM_ERRORS as exc:
            line = next((ln for ln in str(exc).splitlines() if ln.strip()), type(exc).__name__)
            return SolveResult(ok=False, reason=f"optimisation failed: {line.strip()}")
        return SolveResult(
            ok=True, cov_pose=sol.covariances[x], cov_v=sol.covariances[v],
            landmarks=len(self.landmarks), added=added, dropped=dropped, error=sol.error,
        )  # fmt: skip
