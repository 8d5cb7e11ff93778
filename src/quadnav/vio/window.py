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
from typing import Any

import gtsam
import gtsam_unstable
import numpy as np
from gtsam.symbol_shorthand import B, C, L, V, X
from gtsam.symbol_shorthand import K as Kc
from numpy.typing import NDArray

from quadnav.errors import VioError
from quadnav.geometry import Pose
from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.gtsam_bridge import pose3, to_pose
from quadnav.geometry.rotations import skew
from quadnav.odometry import KeyframeStep
from quadnav.vio.config import VioConfig
from quadnav.vio.frontend import FeatureManager, normalised
from quadnav.vio.graph import GTSAM_ERRORS, GraphHistory, GraphSolution, WindowGraph
from quadnav.vio.landmarks import Admission, LandmarkBook

__all__ = [
    "FactorHook",
    "Keyframe",
    "SlidingWindow",
    "SolveResult",
    "StatePrior",
    "rest_factor",
    "state_keys",
]

FloatArray = NDArray[np.float64]
#: a camera's intrinsics with its lens, as GTSAM holds them
Lens = gtsam.Cal3DS2 | gtsam.Cal3Fisheye

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
    #: the mean specific force (body, m/s^2) read at rest before the window, and its sigma per
    #: axis: it ties the first state's tilt to its accelerometer bias (see :func:`rest_factor`)
    rest_accel_B: FloatArray | None = None
    rest_accel_sigma_m_s2: float = 0.0


def rest_factor(
    kf: Keyframe, f_B: FloatArray, sigma_m_s2: float, g_norm: float
) -> gtsam.LinearContainerFactor:
    """The accelerometer at rest before the window, ``f_B = R_W_B^T g e_z + b_a``, as a linear
    factor on the first state's pose and bias (at their values in ``kf``): GTSAM's right
    perturbation ``R Exp(d)`` gives ``d f = [w]x d + d b_a`` with ``w = R^T g e_z``. A tilt
    prior centred on the gravity those readings give, beside a bias prior, would count the bias
    prior twice: the readings say ``tilt + b / g``, not the tilt alone."""
    x, _, b = state_keys(kf.index)
    w = kf.pose.rotation().matrix().T @ np.array([0.0, 0.0, g_norm])
    A_x = np.zeros((3, 6))
    A_x[:, :3] = skew(w)
    A_b = np.zeros((3, 6))
    A_b[:, :3] = np.eye(3)
    rhs = np.asarray(f_B, np.float64) - w - kf.bias.accelerometer()
    noise = gtsam.noiseModel.Isotropic.Sigma(3, sigma_m_s2)
    at = gtsam.Values()
    at.insert(x, kf.pose)
    at.insert(b, kf.bias)
    return gtsam.LinearContainerFactor(gtsam.JacobianFactor(x, A_x, b, A_b, rhs, noise), at)


@dataclass(frozen=True, slots=True, kw_only=True)
class SolveResult:
    """How a solve went: ``ok`` and ``reason`` (why not), the newest keyframe's marginal
    covariances (pose, velocity, IMU bias), landmark counts and the final error."""

    ok: bool
    reason: str = ""
    cov_pose: FloatArray = field(default_factory=lambda: np.eye(6))
    cov_v: FloatArray = field(default_factory=lambda: np.eye(3))
    cov_bias: FloatArray = field(default_factory=lambda: np.eye(6))
    landmarks: int = 0
    added: int = 0
    dropped: int = 0
    error: float = 0.0
    #: the newest keyframe's position step from the window's keyframe before it
    step: KeyframeStep | None = None
    #: Cholesky refused the window and QR solved it (see :mod:`quadnav.vio.graph`)
    qr_fallback: bool = False


#: the projection factors: with a fixed extrinsic (``body_P_sensor``) or with the extrinsic a
#: variable ``C(0)`` (``C(1)`` the second camera's) of the window; with the intrinsics refined,
#: on the raw pixels through the lens model (``Cal3DS2``, ``Cal3Fisheye``)
PROJECTIONS = (
    gtsam.GenericProjectionFactorCal3_S2,
    gtsam_unstable.ProjectionFactorPPPCal3_S2,
    gtsam_unstable.ProjectionFactorPPPCCal3_S2,
    gtsam_unstable.ProjectionFactorPPPCCal3DS2,
    gtsam_unstable.ProjectionFactorPPPCCal3Fisheye,
)
#: a lens model's GTSAM calibration, projection factor and prior
_LENS = {
    "radtan": (
        gtsam.Cal3DS2, gtsam_unstable.ProjectionFactorPPPCCal3DS2, gtsam.PriorFactorCal3DS2,
    ),
    "equidistant": (
        gtsam.Cal3Fisheye, gtsam_unstable.ProjectionFactorPPPCCal3Fisheye,
        gtsam.PriorFactorCal3Fisheye,
    ),
}  # fmt: skip
#: the rows of a calibration's vector a stereo pair's relative intrinsics tie: fx, fy, u0, v0
#: (the same rows in ``Cal3_S2``, ``Cal3DS2`` and ``Cal3Fisheye``)
_PAIR_ROWS = np.array([0, 1, 3, 4])


def pair_intrinsics_factor(
    k0: int, k1: int, stated_gap: FloatArray, sigmas: FloatArray, get: Callable[..., Any]
) -> gtsam.CustomFactor:
    """A stereo pair's two intrinsics tied: the second camera's focal lengths and principal
    point minus the first's, as stated (``stated_gap``), within ``sigmas``. The pair's
    disparity is the depth, so its relative intrinsics fix the stereo scale; each camera's
    own prior leaves the pair free to move together. ``get``: ``Values``' accessor of the
    calibration's type."""
    gap = np.asarray(stated_gap, np.float64)

    def error(
        this: gtsam.CustomFactor, values: gtsam.Values, H: list[FloatArray] | None
    ) -> FloatArray:
        a, b = get(values, this.keys()[0]), get(values, this.keys()[1])
        va, vb = np.asarray(a.vector(), np.float64), np.asarray(b.vector(), np.float64)
        if H is not None:
            S = np.zeros((len(_PAIR_ROWS), len(va)))
            S[np.arange(len(_PAIR_ROWS)), _PAIR_ROWS] = 1.0
            H[0] = -S
            H[1] = S
        return np.asarray((vb - va)[_PAIR_ROWS] - gap, np.float64)

    noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, np.float64))
    return gtsam.CustomFactor(noise, [k0, k1], error)


#: the stamp of a keyframe marginalised out of turn: older than any lag
DROPPED = -1e9
#: the stated extrinsic's prior when only the intrinsics are refined online (held, not refined)
HELD_SIGMA = 1e-4


def _lens_calibration(cam: PinholeCamera) -> Lens | None:
    """A camera's intrinsics and lens as GTSAM's calibration, or None where GTSAM's models do
    not hold it (a radial-tangential lens with ``k3`` or more)."""
    d = np.zeros(4)
    n = min(cam.dist.size, 4)
    d[:n] = cam.dist[:n]
    if cam.model == "radtan" and np.any(cam.dist[4:]):
        return None
    K = cam.K
    lens: Lens = _LENS[cam.model][0](K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2], *d)
    return lens


def _refined_camera(cam: PinholeCamera, k: Lens) -> PinholeCamera:
    """``cam`` with the intrinsics of a refined calibration (its lens coefficients held)."""
    K = np.array([[k.fx(), k.skew(), k.px()], [0.0, k.fy(), k.py()], [0.0, 0.0, 1.0]])
    return PinholeCamera(K, cam.dist, cam.width, cam.height, cam.model)


def _normalised(cam: PinholeCamera, px: FloatArray) -> FloatArray:
    """Undistorted normalised coordinates of raw pixels."""
    return normalised(cam, cam.undistort_pixels(px))


def _camera_poses(kfs: dict[int, gtsam.Pose3], T_B_C: gtsam.Pose3) -> dict[int, FloatArray]:
    """The 3x4 ``[R_C_W | t_C_W]`` of each keyframe's camera."""
    return {k: T_W_B.compose(T_B_C).inverse().matrix()[:3, :] for k, T_W_B in kfs.items()}


class SlidingWindow:
    """Keyframes and landmarks of a fixed-lag window (see the module)."""

    def __init__(
        self,
        config: VioConfig,
        T_B_C: Pose,
        focal_px: float,
        T_B_R: Pose | None = None,
        cameras: Sequence[PinholeCamera] = (),
    ) -> None:
        """``cameras``: the stated intrinsics and lens of the camera (and the second camera):
        given, the intrinsics are refined on the raw pixels through the lens model; without
        them, as a correction of the undistorted normalised coordinates (an approximation: a
        focal length 1 % off leaves up to 3 px through EuRoC's lens)."""
        self.config = config
        #: the camera-IMU extrinsic: as stated, then as estimated online
        #: (``estimate_extrinsic``), kept from one window to the next
        self.T_B_C = pose3(T_B_C)
        #: a stereo rig's second camera: its observations are projection factors too
        self.T_B_R = None if T_B_R is None else pose3(T_B_R)
        self._T_L_R = None if self.T_B_R is None else self.T_B_C.between(self.T_B_R)
        #: each camera's intrinsics correction on the normalised coordinates its stated
        #: intrinsics give (identity: as stated; refined online with ``estimate_intrinsics``)
        self.K_fix = [gtsam.Cal3_S2(1.0, 1.0, 0.0, 0.0, 0.0) for _ in range(2)]
        #: refine the intrinsics: as configured; by default with a stereo pair only (alone, a
        #: camera's focal length trades against the scale, and a wrong correction can diverge)
        self._intrinsics = (
            config.estimate_intrinsics
            if config.estimate_intrinsics is not None
            else self.T_B_R is not None
        )
        self._online = config.estimate_extrinsic or self._intrinsics
        #: the intrinsics refined through the lens: each camera as stated, and its calibration
        #: as the window has it (GTSAM's ``Cal3DS2`` or ``Cal3Fisheye``)
        self._cams = list(cameras)
        lens = [_lens_calibration(c) for c in self._cams]
        self.K_lens: list[Lens] = [k for k in lens if k is not None]
        self._lens = bool(self._intrinsics and lens and len(self.K_lens) == len(lens))
        baseline = 0.0 if T_B_R is None else float(np.linalg.norm((T_B_C.inverse() @ T_B_R).p_A_B))
        self.focal_px = float(focal_px)
        self.K = gtsam.Cal3_S2(1.0, 1.0, 0.0, 0.0, 0.0)
        sigma = config.pixel_sigma_px / (1.0 if self._lens else self.focal_px)
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
        #: the run's finished segments' graphs (``final_smoothing``): see :meth:`close_segment`
        self.segments: list[GraphHistory] = []
        #: each keyframe's time (ns, the IMU's clock) by its number (``final_smoothing``)
        self.kf_times: dict[int, int] = {}
        #: each track's landmark keys, with the keyframe each was anchored in, in order
        #: (``final_smoothing``: a loop's observations of old landmarks go to these keys)
        self.track_keys: dict[int, list[tuple[int, int]]] = {}
        self._clock = 0.0
        self._stamp_of: dict[int, float] = {}
        self._anchored: dict[int, list[int]] = {}  # keyframe -> its landmarks' key numbers
        self._dropping: int | None = None  # the keyframe the next solve drops

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

    @property
    def extrinsic(self) -> Pose:
        """The camera's ``T_B_C`` as the window has it (the stated one, refined online with
        ``estimate_extrinsic``)."""
        return to_pose(self.T_B_C)

    def intrinsics(self, side: int, stated: PinholeCamera) -> tuple[float, float, float, float]:
        """``fx, fy, cx, cy`` (px) of camera ``side`` (0: the camera, 1: its stereo partner) as
        the window has them: refined through the lens, or the stated ones under the refined
        correction of their normalised coordinates (unchanged without
        ``estimate_intrinsics``)."""
        if self._lens:
            k = self.K_lens[side]
            return float(k.fx()), float(k.fy()), float(k.px()), float(k.py())
        K = stated.K
        c = self.K_fix[side] if self._intrinsics else gtsam.Cal3_S2(1.0, 1.0, 0.0, 0.0, 0.0)
        # a stated normalised x = c.fx x' + c.px of the refined x': u = cx + fx x
        return (
            float(K[0, 0] * c.fx()),
            float(K[1, 1] * c.fy()),
            float(K[0, 2] + K[0, 0] * c.px()),
            float(K[1, 2] + K[1, 1] * c.py()),
        )

    def calibration_sigmas(
        self, side: int, stated: PinholeCamera
    ) -> tuple[FloatArray | None, FloatArray | None]:
        """The standard deviations of camera ``side``'s extrinsic (rotation in rad, then
        translation in m, about and along the camera's axes) and of its ``fx, fy, cx, cy`` (px)
        at the last solve; None where not estimated or not to be had."""
        if self.graph is None:
            return None, None
        ext = self.graph.marginal(C(side)) if self.config.estimate_extrinsic else None
        intr = None
        k_cov = self.graph.marginal(Kc(side)) if self._intrinsics else None
        if k_cov is not None:  # (fx, fy, skew, u0, v0, ...): in px through the lens
            sig = np.sqrt(np.clip(np.diag(k_cov)[[0, 1, 3, 4]], 0.0, None))
            intr = sig if self._lens else sig * stated.K[[0, 1, 0, 1], [0, 1, 0, 1]]
        return (None if ext is None else np.sqrt(np.clip(np.diag(ext), 0.0, None))), intr

    def corrected_xy(self, xy: FloatArray, side: int = 0) -> FloatArray:
        """Normalised coordinates (from the stated intrinsics) as the window's refined
        intrinsics have them (unchanged without ``estimate_intrinsics``)."""
        if not self._intrinsics:
            return xy
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        if self._lens:
            cam = self._cams[side]
            return _normalised(_refined_camera(cam, self.K_lens[side]), self._pixels(xy, side))
        k = self.K_fix[side]
        y = (xy[:, 1] - k.py()) / k.fy()
        x = (xy[:, 0] - k.px() - k.skew() * y) / k.fx()
        return np.column_stack([x, y])

    def _affine_fix(self, side: int) -> gtsam.Cal3_S2:
        """The refined lens as the nearest correction of the stated normalised coordinates
        (least squares over the image): what the landmark book's checks use."""
        cam = self._cams[side]
        u, v = np.meshgrid(np.linspace(0, cam.width, 9), np.linspace(0, cam.height, 7))
        px = np.column_stack([u.ravel(), v.ravel()])
        stated = _normalised(cam, px)
        true = _normalised(_refined_camera(cam, self.K_lens[side]), px)
        fx, px_ = np.polyfit(true[:, 0], stated[:, 0], 1)
        fy, py = np.polyfit(true[:, 1], stated[:, 1], 1)
        return gtsam.Cal3_S2(float(fx), float(fy), 0.0, float(px_), float(py))

    def close_segment(self) -> None:
        """The graph so far kept as a finished segment of the run's history (with
        ``final_smoothing``; a restart or a reset begins the next)."""
        if self.graph is not None and self.config.final_smoothing:
            hist = self.graph.history()
            if hist.factors.size():
                self.segments.append(hist)
        self.graph = None

    def commit(self) -> None:
        """The last solve accepted (the history takes its estimate; see ``WindowGraph``)."""
        if self.graph is not None:
            self.graph.commit()

    def rollback(self) -> None:
        """What came since the last accepted solve leaves the history."""
        if self.graph is not None:
            self.graph.rollback()

    def discard(self) -> None:
        """The graph dropped without keeping it as a segment (a restart that failed)."""
        self.graph = None

    def add_hook(self, hook: FactorHook) -> None:
        """Call ``hook`` for each keyframe entering the window (the first included) and add
        the factors it returns (a GPS fix, a loop-closure prior)."""
        self._hooks.append(hook)

    # -- building ---------------------------------------------------------------------------
    def start(self, kf: Keyframe, prior: StatePrior) -> None:
        """A new window from ``kf`` with a Gaussian ``prior`` on its state."""
        self.close_segment()
        self.graph = WindowGraph(
            self.config, self.config.window_keyframes - 0.5, history=self.config.final_smoothing
        )
        self.keyframes = [kf]
        self.book.clear()
        #: the smoother's clock: one tick per keyframe kept (a keyframe that replaces the
        #: newest takes its tick), so the oldest leaves when the window is full
        self._clock = 0.0
        self._stamp_of = {}
        self._anchored = {}
        x, v, b = state_keys(kf.index)
        gauss = gtsam.noiseModel.Gaussian.Covariance
        self.graph.add_all([
            gtsam.PriorFactorPose3(x, kf.pose, gauss(prior.cov_pose)),
            gtsam.PriorFactorVector(v, kf.velocity, gauss(prior.cov_v)),
            gtsam.PriorFactorConstantBias(b, kf.bias, gauss(prior.cov_bias)),
        ])  # fmt: skip
        if prior.rest_accel_B is not None:
            self.graph.add(
                rest_factor(kf, prior.rest_accel_B, prior.rest_accel_sigma_m_s2, self.config.g_norm)
            )
        if self._online:
            self._start_calibration()
        self._insert_state(kf)

    def _cameras_used(self) -> range:
        return range(1 if self.T_B_R is None else 2)

    def _start_calibration(self) -> None:
        """The extrinsic as a variable: a prior around the window's value (the stated one,
        or the last window's estimate), and a stereo pair's second camera tied to the first by
        the stated camera-to-camera pose; each camera's intrinsics correction likewise."""
        assert self.graph is not None
        cfg = self.config
        diag = gtsam.noiseModel.Diagonal.Sigmas
        sig = np.array([np.radians(cfg.extrinsic_sigma_deg)] * 3 + [cfg.extrinsic_sigma_m] * 3)
        if not cfg.estimate_extrinsic:
            sig = np.full(6, HELD_SIGMA)
        for n in self._cameras_used() if self._intrinsics else ():
            f, c = cfg.intrinsics_focal_sigma, cfg.intrinsics_principal_sigma_px / self.focal_px
            if self._lens:  # in pixels; the lens's coefficients held
                k = self.K_lens[n]
                lens_sig = np.array(
                    [f * k.fx(), f * k.fy(), HELD_SIGMA, c * self.focal_px, c * self.focal_px]
                    + [HELD_SIGMA] * 4,
                    np.float64,
                )
                self.graph.insert(Kc(n), k, 0.0)
                self.graph.add(_LENS[self._cams[n].model][2](Kc(n), k, diag(lens_sig)))
                continue
            self.graph.insert(Kc(n), self.K_fix[n], 0.0)
            k_sig = np.array([f, f, HELD_SIGMA, c, c])  # (no skew)
            self.graph.add(gtsam.PriorFactorCal3_S2(Kc(n), self.K_fix[n], diag(k_sig)))
        self._tie_pair_intrinsics()
        self.graph.insert(C(0), self.T_B_C, 0.0)
        self.graph.add(gtsam.PriorFactorPose3(C(0), self.T_B_C, diag(sig)))
        if self.T_B_R is not None and self._T_L_R is not None:
            pair = np.array(
                [np.radians(cfg.stereo_extrinsic_sigma_deg)] * 3
                + [cfg.stereo_extrinsic_sigma_m] * 3
            )
            self.graph.insert(C(1), self.T_B_C.compose(self._T_L_R), 0.0)
            self.graph.add(gtsam.BetweenFactorPose3(C(0), C(1), self._T_L_R, diag(pair)))

    def _tie_pair_intrinsics(self) -> None:
        """A stereo pair refining its intrinsics: the two tied by their stated difference
        (:func:`pair_intrinsics_factor`, ``stereo_intrinsics_*_sigma``)."""
        cfg = self.config
        if not (self._intrinsics and len(self._cameras_used()) == 2 and cfg.stereo_tie_intrinsics):
            return
        if self._lens and self._cams[0].model != self._cams[1].model:
            return  # (two lens models: two calibration types the tie cannot difference)
        assert self.graph is not None
        f, c = cfg.stereo_intrinsics_focal_sigma, cfg.stereo_intrinsics_principal_sigma_px
        stated: list[Any]
        get: Callable[..., Any]
        if self._lens:
            stated = [k for cam in self._cams[:2] if (k := _lens_calibration(cam)) is not None]
            scale = 1.0
            get = (
                gtsam.Values.atCal3DS2 if self._cams[0].model == "radtan"
                else gtsam.Values.atCal3Fisheye
            )  # fmt: skip
        else:  # corrections of the normalised coordinates: both stated as identity (not
            # K_fix, the last window's estimate: a restart would tie the pair to it)
            identity = gtsam.Cal3_S2(1.0, 1.0, 0.0, 0.0, 0.0)
            stated, scale, get = [identity, identity], 1.0 / self.focal_px, gtsam.Values.atCal3_S2
        v0, v1 = (np.asarray(k.vector(), np.float64)[_PAIR_ROWS] for k in stated)
        focal = np.array([v0[0], v0[1]]) if self._lens else np.ones(2)
        sig = np.r_[f * focal, [c * scale] * 2]
        self.graph.add(pair_intrinsics_factor(Kc(0), Kc(1), v1 - v0, sig, get))

    def seed_landmarks(self, points_W: dict[int, FloatArray]) -> None:
        """Points (an initialisation's) to start tracks from instead of triangulating them."""
        self.book.seed(points_W)

    def _insert_state(self, kf: Keyframe) -> None:
        assert self.graph is not None
        x, v, b = state_keys(kf.index)
        self._stamp_of[kf.index] = self._clock
        if self.config.final_smoothing:
            self.kf_times[kf.index] = int(kf.t_ns)
        for key, value in ((x, kf.pose), (v, kf.velocity), (b, kf.bias)):
            self.graph.insert(key, value, self._clock)
        if self._online:  # never marginalised: always as new as the newest
            for n in self._cameras_used():
                self.graph.restamp(C(n), self._clock)
                if self._intrinsics:
                    self.graph.restamp(Kc(n), self._clock)
        for hook in self._hooks:
            self.graph.add_all(hook(kf))

    @property
    def dropping(self) -> int | None:
        """The keyframe the next solve drops (``push``'s ``drop_previous``), if any."""
        return self._dropping

    def push(self, kf: Keyframe, *, drop_previous: bool = False) -> None:
        """The next keyframe, joined to the newest by its preintegrated IMU (and, at rest, by
        zero-velocity and no-motion constraints). ``drop_previous``: the newest keyframe so far
        leaves at the next solve instead of the oldest, unless the window is too short for it:
        its projections are dropped and its state marginalised (its IMU stays, as a prior
        joining its neighbours)."""
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
        if drop_previous and len(self.keyframes) >= 3:
            # its visual measurements are discarded, as VINS-Mono does: marginalised, they would
            # tie every landmark it saw to every other (a dense prior that grows with each drop)
            xj = X(j)
            self.graph.remove_where(
                lambda f: not (isinstance(f, PROJECTIONS) and not {xj}.isdisjoint(f.keys())),
                touching=(xj,),
                forget=False,  # (a smoothing of the whole run can afford them)
            )
            # and the landmarks anchored in it leave with it (the clock stands still: they
            # would stay for as long as the vehicle hovers)
            keys = [*state_keys(j), *(L(n) for n in self._anchored.pop(j, ()))]
            for key in keys:
                self.graph.restamp(key, DROPPED)  # out at the next solve
            self._dropping = j
        else:
            self._clock += 1.0
        self.keyframes.append(kf)
        self._insert_state(kf)

    def _cameras(self) -> tuple[dict[int, FloatArray], dict[int, FloatArray]]:
        """The window's camera matrices: the camera's and (stereo) the second camera's."""
        poses = {kf.index: kf.pose for kf in self.keyframes}
        P = _camera_poses(poses, self.T_B_C)
        PR = _camera_poses(poses, self.T_B_R) if self.T_B_R is not None else {}
        if self._intrinsics:  # in the stated intrinsics' normalised coordinates
            K0, K1 = (np.asarray(k.K(), np.float64) for k in self.K_fix)
            P = {k: K0 @ Pk for k, Pk in P.items()}
            PR = {k: K1 @ Pk for k, Pk in PR.items()}
        return P, PR

    def _add_landmarks(self, features: FeatureManager) -> int:
        """The landmark book's decisions as values and factors: new landmarks with their
        bearing-range prior from the anchor keyframe, and projection factors."""
        assert self.graph is not None
        adm: Admission = self.book.admit(features, *self._cameras())
        poses = {kf.index: kf.pose for kf in self.keyframes}
        for new in adm.new:
            key = L(new.key)
            self.graph.insert(key, new.point_W, self._stamp_of[new.anchor])  # leaves with it
            self._anchored.setdefault(new.anchor, []).append(new.key)
            if self.config.final_smoothing:
                self.track_keys.setdefault(new.track, []).append((new.anchor, new.key))
            T_W_B = poses[new.anchor]
            self.graph.add(
                gtsam.BearingRangeFactor3D(
                    X(new.anchor), key, T_W_B.bearing(new.point_W), T_W_B.range(new.point_W),
                    self._landmark_prior,
                )
            )  # fmt: skip
        if self._lens:
            self._add_lens_projections(adm)
            return len(adm.new)
        project = [self._projection(0), self._projection(1)]
        add = self.graph.add
        for ob in adm.observations:
            add(project[ob.side == 1](ob.xy, X(ob.keyframe), L(ob.key)))
        return len(adm.new)

    def _pixels(self, xy: FloatArray, side: int) -> FloatArray:
        """The raw pixels of normalised coordinates of the stated intrinsics (the front end's
        undistortion inverted: its features' own pixels)."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        return self._cams[side].project(np.column_stack([xy, np.ones(len(xy))]))

    def _add_lens_projections(self, adm: Admission) -> None:
        """Projection factors on the raw pixels through each camera's refined lens model."""
        assert self.graph is not None
        obs = adm.observations
        if not obs:
            return
        sides = np.array([1 if o.side == 1 and self.T_B_R is not None else 0 for o in obs])
        px = np.zeros((len(obs), 2))
        for n in self._cameras_used():
            at = np.flatnonzero(sides == n)
            if at.size:
                px[at] = self._pixels(np.array([obs[i].xy for i in at]), n)
        for ob, side, uv in zip(obs, sides.tolist(), px, strict=True):
            factor = _LENS[self._cams[side].model][1]
            self.graph.add(
                factor(uv, self._pixel_noise, X(ob.keyframe), C(side), L(ob.key), Kc(side))
            )

    def loop_observations(
        self, xy: FloatArray, keyframe: int, keys: Sequence[int]
    ) -> list[gtsam.NonlinearFactor]:
        """Keyframe ``keyframe``'s first camera seeing landmarks ``keys`` again at normalised
        ``xy`` (a loop's matches): projection factors as the window's own (the same noise,
        lens and calibration variables), for the final smoothing."""
        if self._lens:
            factor = _LENS[self._cams[0].model][1]
            px = self._pixels(xy, 0)
            return [
                factor(uv, self._pixel_noise, X(keyframe), C(0), L(k), Kc(0))
                for uv, k in zip(px, keys, strict=True)
            ]
        project = self._projection(0)
        return [project(p, X(keyframe), L(k)) for p, k in zip(xy, keys, strict=True)]

    def _projection(self, side: int) -> Callable[[FloatArray, int, int], gtsam.NonlinearFactor]:
        """The factor of an observation (normalised point, pose key, landmark key) in camera
        ``side`` (the second camera's with a stereo rig only): with the extrinsic (and the
        intrinsics correction) as variables of the window, or fixed."""
        side = side if self.T_B_R is not None else 0
        noise, K, c, k = self._pixel_noise, self.K, C(side), Kc(side)
        T = self.T_B_R if side == 1 and self.T_B_R is not None else self.T_B_C
        PPPC, PPP = (
            gtsam_unstable.ProjectionFactorPPPCCal3_S2,
            gtsam_unstable.ProjectionFactorPPPCal3_S2,
        )

        def with_intrinsics(xy: FloatArray, x: int, lm: int) -> gtsam.NonlinearFactor:
            return PPPC(xy, noise, x, c, lm, k)

        def with_extrinsic(xy: FloatArray, x: int, lm: int) -> gtsam.NonlinearFactor:
            return PPP(xy, noise, x, c, lm, K)

        def fixed(xy: FloatArray, x: int, lm: int) -> gtsam.NonlinearFactor:
            return gtsam.GenericProjectionFactorCal3_S2(xy, noise, x, lm, K, T)

        if self._online:
            return with_intrinsics if self._intrinsics else with_extrinsic
        return fixed

    # -- solving ----------------------------------------------------------------------------
    def _read_back(self, est: gtsam.Values, features: FeatureManager) -> int:
        """The smoother's estimates in; marginalised keyframes and landmarks out; landmarks
        behind a camera or far from their pixels lose their projections."""
        assert self.graph is not None
        for kf in self.keyframes:
            if not est.exists(X(kf.index)):
                features.drop_keyframe(kf.index)
        self.keyframes = [kf for kf in self.keyframes if est.exists(X(kf.index))]
        inside = {kf.index for kf in self.keyframes}
        self._stamp_of = {k: t for k, t in self._stamp_of.items() if k in inside}
        self._anchored = {k: v for k, v in self._anchored.items() if k in inside}
        for kf in self.keyframes:
            kf.pose = est.atPose3(X(kf.index))
            kf.velocity = np.asarray(est.atVector(V(kf.index)), np.float64)
            kf.bias = est.atConstantBias(B(kf.index))
        if est.exists(C(0)):
            self.T_B_C = est.atPose3(C(0))
        if est.exists(C(1)):
            self.T_B_R = est.atPose3(C(1))
        for n in self._cameras_used():
            if est.exists(Kc(n)) and self._lens:
                get = est.atCal3DS2 if self._cams[n].model == "radtan" else est.atCal3Fisheye
                self.K_lens[n] = get(Kc(n))
                self.K_fix[n] = self._affine_fix(n)
            elif est.exists(Kc(n)):
                self.K_fix[n] = est.atCal3_S2(Kc(n))

        def point(n: int) -> FloatArray | None:
            key = L(n)
            return np.asarray(est.atPoint3(key), np.float64) if est.exists(key) else None

        self.book.read_back(point, features)
        bad = self.book.mark_bad(features, *self._cameras())
        if bad:
            keys = {L(n) for n in bad}
            self.graph.remove_where(
                lambda f: not (isinstance(f, PROJECTIONS) and not keys.isdisjoint(f.keys())),
                touching=keys,
            )
        return len(bad)

    def solve(self, features: FeatureManager) -> SolveResult:
        """Add what is new and let the smoother optimise and marginalise. Never raises
        GTSAM's errors: a failed solve is a result that says why."""
        if self.graph is None:
            raise VioError("the window has not been started")
        added = self._add_landmarks(features)
        x, v, b = state_keys(self.newest.index)
        before = [kf.index for kf in self.keyframes[:-1] if kf.index != self._dropping]
        pairs = [(X(before[-1]), x)] if before else []
        self._dropping = None
        try:
            sol = self.graph.solve(covariance_of=(x, v, b), cross_of=pairs)
            if not np.isfinite(sol.error):
                return SolveResult(ok=False, reason="the optimisation diverged (non-finite error)")
            dropped = self._read_back(sol.estimate, features)
        except GTSAM_ERRORS as exc:
            line = next((ln for ln in str(exc).splitlines() if ln.strip()), type(exc).__name__)
            return SolveResult(ok=False, reason=f"optimisation failed: {line.strip()}")
        return SolveResult(
            ok=True, cov_pose=sol.covariances[x], cov_v=sol.covariances[v],
            cov_bias=sol.covariances[b], qr_fallback=sol.qr_fallback, landmarks=len(self.landmarks), added=added, dropped=dropped, error=sol.error,
            step=self._step(sol, pairs),
        )  # fmt: skip

    def _step(self, sol: GraphSolution, pairs: list[tuple[int, int]]) -> KeyframeStep | None:
        """The newest keyframe's position step from the keyframe before it in the window, and
        its covariance in ``W`` (m^2) from their joint marginal: ``R_j S_jj R_j^T + R_i S_ii
        R_i^T - R_i S_ij R_j^T - (R_i S_ij R_j^T)^T`` with GTSAM's right perturbation of a
        pose's translation (``p + R dt``). None when the solve gave no cross-covariance."""
        if not pairs or pairs[0] not in sol.cross:
            return None
        xi, xj = pairs[0]
        cov_i = sol.covariances.get(xi)
        if cov_i is None:
            return None
        est = sol.estimate
        Ri = est.atPose3(xi).rotation().matrix()
        Rj = est.atPose3(xj).rotation().matrix()
        Sjj = sol.covariances[xj][3:, 3:]
        Sii = cov_i[3:, 3:]
        Sij = sol.cross[pairs[0]][3:, 3:]
        c = Ri @ Sij @ Rj.T
        cov = Rj @ Sjj @ Rj.T + Ri @ Sii @ Ri.T - c - c.T
        cov = 0.5 * (cov + cov.T)
        if not np.isfinite(cov).all():
            return None
        return KeyframeStep(after=int(gtsam.Symbol(xi).index()), cov_W=cov)
