"""``VioEstimator``: the monocular visual-inertial odometry (thesis 003, VINS-Mono class) behind
the odometry interface (:class:`~quadnav.odometry.VisualOdometry`): ``push`` an IMU sample or a
camera frame, read ``keyframes()`` as they leave the window.

IMU samples go into a buffer (and, once initialised, propagate the last optimised keyframe at
the IMU's rate: status ``propagated``). Each image is tracked; before the start the estimator
waits for the vehicle at rest (the static start) or, moving, calls the visual-inertial
initialisation over a window of keyframes; then each frame is predicted by the IMU from the
newest keyframe, and a keyframe (by parallax, few tracks or time) is added to the sliding
window and optimised. A window too ill-conditioned for Cholesky is solved with QR
(:mod:`quadnav.vio.graph`; event ``recovered``). A solve that does not go through even so
(GTSAM throws, or the error is not finite) restarts the window in place from the last good
state (``restart_in_place``): the newest keyframe solved, its marginal covariances inflated, and
the new keyframe joined to it by its IMU; the landmarks start from their last estimates; the
output goes on from where it was, so ``reset_counter`` stays (event ``recovered``). A failure
(too few tracks, an implausible state, a restart that does not go through either, or a second
one within a window) resets the window and re-initialises, with ``reset_counter`` + 1. Bad
input (a non-finite IMU sample, time going backwards, an image that cannot be read or tracked,
a frame of a camera it does not use) is rejected and counted in
:attr:`VioEstimator.rejected`, never raised.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import SampleError, VioError, VisionError
from quadnav.geometry.gtsam_bridge import pose3, to_pose
from quadnav.geometry.multiview import essential_pose, parallax_rad
from quadnav.geometry.rotations import Pose
from quadnav.geometry.trajectory import Trajectory
from quadnav.messages import ImageFrame, ImuSample
from quadnav.odometry import (
    CameraCalibration,
    FrameFeatures,
    KeyframeRecord,
    KeyframeStep,
    LoopConstraint,
    OdometryEvent,
    OdometryState,
    StageTiming,
)
from quadnav.rig import Rig
from quadnav.units import NS_PER_S, ns_to_s, s_to_ns
from quadnav.vio.config import VioConfig
from quadnav.vio.failure import InputLog, SolvedState, state_failure, tracking_failure
from quadnav.vio.final import FrameTrail, ImuLog, SmoothingReport, reweighed, smooth_segments
from quadnav.vio.frontend import FeatureManager, Frontend, median_motion_px
from quadnav.vio.imu_noise import ImuNoiseMonitor, MeasuredNoise
from quadnav.vio.initialization import InitFailure, try_visual_inertial_init
from quadnav.vio.preintegration import imu_params, zero_bias
from quadnav.vio.propagator import ImuPropagator
from quadnav.vio.static_init import (
    StaticStart,
    heading_of,
    imu_stillness,
    is_still,
    static_start,
)
from quadnav.vio.stereo import PendingFrame, StereoFrontend
from quadnav.vio.time_offset import TimeOffsetEstimator
from quadnav.vio.types import InitResult, InitWindow
from quadnav.vio.window import Keyframe, SlidingWindow, SolveResult, StatePrior
from quadnav.vision.descriptors import orb_at

__all__ = ["VioEstimator"]

FloatArray = NDArray[np.float64]

#: The first state's yaw and position priors: the estimate's gauge (a VIO cannot observe its
#: yaw and position in the world; they are where it started).
GAUGE_YAW_SIGMA_RAD = 1e-3
GAUGE_POSITION_SIGMA_M = 1e-3
#: The first state's roll and pitch prior: weak, for the solve's conditioning only (the IMU's
#: factors place them; see ``VioEstimator._first_pose_cov``).
FREE_TILT_SIGMA_RAD = 0.5
#: how often an estimator that cannot start (or re-start) says so, and why (s)
WAITING_REPORT_S = 5.0
#: the fewest of a loop's matches whose landmarks the final smoothing must hold to take the
#: loop as observations (fewer: as a relative pose; verification asks 25 PnP inliers)
LOOP_MIN_OBSERVATIONS = 12


@dataclass(slots=True)
class _KeyframeInfo:
    """What a window keyframe is published with when it leaves: its features, the frame its
    pixels come from, their descriptors, the window's state object (whose pose the solves keep
    up to date while it stays) and its covariance when it was the newest."""

    features: FrameFeatures
    image: ImageFrame | None
    descriptors: NDArray[np.uint8] | None
    described: NDArray[np.bool_] | None
    keyframe: Keyframe | None = None
    cov_pose: FloatArray | None = None
    step: KeyframeStep | None = None


def _three(v: FloatArray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])


def _four(v: FloatArray) -> tuple[float, float, float, float]:
    return float(v[0]), float(v[1]), float(v[2]), float(v[3])


def _time_offset_estimator(R_B_C: Rotation, cfg: VioConfig) -> TimeOffsetEstimator:
    """The online camera-IMU time-offset estimator, told the camera's mount. Its window is
    long (30 s by default): it compares rotations between keyframes, a few a second, and over
    6 s its answer on realistic corridor1 wandered between -1.8 and 3.8 ms (true: 3.9)."""
    return TimeOffsetEstimator(
        R_B_C=R_B_C,
        window_s=cfg.td_window_s,
        min_rate_slope_rad_s2=cfg.td_min_rate_change_rad_s2,
    )


def _vehicle_in_body(T_V_B: Pose) -> tuple[FloatArray | None, FloatArray]:
    """The vehicle's forward axis in the body frame, when the rig's body is mounted turned on
    it (None otherwise: a static start puts the world's heading on it), and the body's origin
    from the vehicle's in the body's axes (the first static start puts the world's origin on
    the vehicle's, as it puts its heading on the vehicle's nose)."""
    R_V_B = T_V_B.R_A_B
    turned = not np.allclose(R_V_B.as_matrix(), np.eye(3))
    forward = np.asarray(R_V_B.inv().apply([1.0, 0.0, 0.0]), np.float64) if turned else None
    return forward, np.asarray(R_V_B.inv().apply(np.asarray(T_V_B.p_A_B, np.float64)), np.float64)


class VioEstimator:
    """Monocular VIO on a rig's camera (``cam0``) and IMU; see the module."""

    def __init__(self, rig: Rig, config: VioConfig | None = None, *, camera: str = "cam0") -> None:
        if rig.imu is None:
            raise VioError(f"rig {rig.name!r} has no IMU: visual-inertial odometry needs one")
        self.config = cfg = config or VioConfig()
        spec = self.camera_spec = rig.camera(camera)
        self.camera = camera
        self._R_BC = spec.T_B_C.R_A_B.as_matrix()  # the camera's mount (stated: it is fixed)
        self._forward_B, self._p_V_B_in_B = _vehicle_in_body(rig.T_V_B)
        n, a, w = rig.imu.noise, cfg.imu_noise_scale, cfg.imu_walk_scale
        noise = dataclasses.replace(
            n, gyro_noise_density=a * n.gyro_noise_density, accel_noise_density=a * n.accel_noise_density,
            gyro_random_walk=w * n.gyro_random_walk, accel_random_walk=w * n.accel_random_walk,
        )  # fmt: skip
        self._noise = noise  # stated, times the user's scales
        self._params = imu_params(
            noise, g_norm=cfg.g_norm, accel_inflation=cfg.accel_noise_inflation
        )
        self.noise_monitor = (
            ImuNoiseMonitor(cfg.imu_noise_window_s, rig.imu.rate_hz)
            if cfg.imu_noise_online
            else None
        )
        self._noise_checked_ns = 0
        self.imu_noise: MeasuredNoise | None = None  # the in-flight noise in use, if measured
        self._noise_reported: FloatArray | None = None  # gyro and accel RMS last reported
        self.frontend = Frontend(spec.camera, cfg)
        self.features = FeatureManager()
        self.input = InputLog()
        self.imu = ImuPropagator(self._params)
        self._events: list[OdometryEvent] = []
        self._stages: dict[str, list[float]] = {}
        self._recent: deque[FrameFeatures] = deque()
        self._init_frames: list[FrameFeatures] = []
        self._last_features: FrameFeatures | None = None
        self._initialized = False
        self._failures = 0
        self._reset_counter = 0
        self._next_kf = 0
        self._cov_pose = np.eye(6) * 1e-6
        self._step: KeyframeStep | None = None  # the last solve's (see SolveResult.step)
        self._cov_v = np.eye(3) * 1e-6
        self._cov_bias = np.eye(6) * 1e-6
        self._restarted_kf: int | None = None  # the keyframe of the last restart in place
        self._last_p = np.zeros(3)
        self._td_s = ns_to_s(spec.time_offset_ns) if cfg.td_s is None else cfg.td_s
        self._td_stated_s = self._td_s  # what the online estimate is weighed against
        self._td_sigma_s = cfg.td_prior_sigma_s  # the offset's sigma: the stated one's at first
        self._td = (
            _time_offset_estimator(rig.camera(camera).T_B_C.R_A_B, cfg) if cfg.estimate_td else None
        )
        self._td_applied_ns: dict[int, int] = {}  # keyframe stamp -> the offset it was given
        self._td_settled = False
        self._td_reported_s: float | None = None  # the estimate the last ``td`` event gave
        self._td_observable: bool | None = None  # whether the last estimate was usable
        # the visual-inertial initialisation (a start or re-start while moving)
        self._visual_init: Callable[[InitWindow], InitResult | InitFailure] = (
            try_visual_inertial_init
        )
        # since when it has waited to start (or re-start), and its last report of it
        self._waiting_since_ns: int | None = None
        self._waiting_reported_ns: int | None = None
        # the window's keyframes as the interface publishes them once they leave it
        self._kf_info: dict[int, _KeyframeInfo] = {}  # by keyframe index
        self._candidates: dict[int, _KeyframeInfo] = {}  # an initialisation window, by stamp
        self._done: list[KeyframeRecord] = []
        self._image: ImageFrame | None = None  # the frame being pushed
        self._image_px: NDArray[np.uint8] | None = None
        self._right_px: NDArray[np.uint8] | None = None  # its stereo partner's pixels
        self.stereo = StereoFrontend(rig, camera, cfg) if cfg.stereo else None
        self.window = self._new_window()
        self._trail = FrameTrail()  # what the final trajectory is made of
        reweigh = cfg.final_smoothing and cfg.final_smoothing_accel_inflation != 1.0
        self._imu_log = ImuLog() if reweigh else None  # and its IMU, to weigh it again
        if self._imu_log is not None:
            self._imu_log.use_params(0, self._params)
        #: the last smoothing's trajectory, by the frames and loops it was made from
        self._final: tuple[tuple[int, tuple[tuple[int, int, bytes], ...]], Trajectory] | None = None
        self._final_keyframes: dict[int, Pose] = {}  # (the last smoothing's keyframes)
        #: the final smoothing's outcome (None: not run)
        self.smoothing: SmoothingReport | None = None

    # -- the protocol -----------------------------------------------------------------------
    @property
    def events(self) -> tuple[OdometryEvent, ...]:
        return tuple(self._events)

    @property
    def last_features(self) -> FrameFeatures | None:
        return self._last_features

    @property
    def rejected(self) -> dict[str, int]:
        """Input rejected so far, by kind."""
        return dict(self.input.counts)

    @property
    def initialized(self) -> bool:
        return self._initialized

    def timing(self) -> StageTiming:
        return StageTiming(stages=tuple((k, v[0], int(v[1])) for k, v in self._stages.items()))

    @contextmanager
    def _stage(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            acc = self._stages.setdefault(name, [0.0, 0.0])
            acc[0] += time.perf_counter() - t0
            acc[1] += 1

    @property
    def cameras(self) -> tuple[str, ...]:
        """The rig's cameras this odometry uses (frames of another are rejected and counted)."""
        return (self.camera,) if self.stereo is None else (self.camera, self.stereo.right.name)

    def push(self, sample: ImuSample | ImageFrame) -> OdometryState | None:
        """An IMU sample (the state propagated to it once initialised) or a camera frame (the
        state at it once initialised); bad input rejected and counted, never raised."""
        if isinstance(sample, ImageFrame):
            return self._push_frame(sample)
        return self._push_imu(sample)

    def keyframes(self, *, final: bool = False) -> list[KeyframeRecord]:
        """The keyframes that left the window since the last call, each handed out once;
        ``final`` (at the end of a run) the window's own too."""
        if final:
            self._retire(everything=True)
        done, self._done = self._done, []
        return done

    def _commit(self) -> None:
        """A solve accepted: the run's history takes it, and the final trajectory the window's
        keyframes where it put them (a refused solve's poses never reach either)."""
        self.window.commit()
        for kf in self.window.keyframes:
            self._trail.keyframe(kf.index, kf.pose)

    def final_trajectory(self) -> Trajectory:
        """Every tracked frame through its reference keyframe's last pose: the window's when
        it left, or (``final_smoothing``) a smoothing of the whole run's graph, done here once
        (see :mod:`quadnav.vio.final`). Not causal."""
        return self.final_trajectory_with((), {})

    def final_trajectory_with(
        self, loops: Sequence[LoopConstraint], keyframe_poses: Mapping[int, Pose]
    ) -> Trajectory:
        """The final trajectory a loop closer refines (:class:`~quadnav.odometry.
        LoopRefinedTrajectory`): with ``final_smoothing``, the smoothing with the ``loops`` as
        factors; without, every frame through the ``keyframe_poses`` its pose graph found
        (a keyframe it has not, through its last pose)."""
        if not self.config.final_smoothing:
            return self._trail.trajectory({k: pose3(p) for k, p in keyframe_poses.items()})
        key = (len(self._trail), tuple((lp.old, lp.new, lp.landmark_ids.tobytes()) for lp in loops))
        if self._final is not None and self._final[0] == key:
            return self._final[1]  # (nothing new since: the smoothing is not redone)
        segments = list(self.window.segments)
        if self.window.graph is not None:
            hist = self.window.graph.history()
            if hist.factors.size():
                segments.append(hist)
        cfg = self.config
        with self._stage("final_smoothing"):
            a = cfg.final_smoothing_accel_inflation
            if a != 1.0 and self._imu_log is not None:
                times, log, hold = self.window.kf_times, self._imu_log, self._hold_ns()
                segments = [reweighed(g, times, log, a, hold_ns=hold)[0] for g in segments]
            anchor = {k: pose3(p) for k, p in keyframe_poses.items()}
            poses, self.smoothing = smooth_segments(
                segments, cfg.final_smoothing_iterations, loops, anchor,
                self._loop_observations if cfg.loops_as_observations else None,
            )  # fmt: skip
        final = self._trail.trajectory(poses)
        self._final = (key, final)
        self._final_keyframes = {k: to_pose(p) for k, p in poses.items()}
        return final

    def _loop_observations(
        self, loop: LoopConstraint, held: set[int]
    ) -> list[gtsam.NonlinearFactor]:
        """A loop's matches as the new keyframe's observations of the old landmarks (see
        :mod:`quadnav.vio.final`): each match's track to the key of its landmark anchored last
        at or before the old keyframe (a track whose landmark left the window and came back
        has several), where the segment's factors hold it; none if fewer than
        ``LOOP_MIN_OBSERVATIONS`` are."""
        keys: list[int] = []
        at: list[int] = []
        for n, j in enumerate(loop.landmark_ids.tolist()):
            cands = self.window.track_keys.get(j)
            if not cands:
                continue
            before = [k for a, k in cands if a <= loop.old]
            key = before[-1] if before else cands[0][1]
            if L(key) in held:
                keys.append(key)
                at.append(n)
        if len(keys) < LOOP_MIN_OBSERVATIONS:
            return []
        return self.window.loop_observations(loop.xy[at], loop.new, keys)

    def final_keyframe_poses(self) -> dict[int, Pose]:
        """The keyframes' poses the last final smoothing gave (by keyframe number; none
        without ``final_smoothing`` or before it ran)."""
        return dict(self._final_keyframes)

    def calibration(self) -> tuple[CameraCalibration, ...]:
        """Each camera used as the window has it now: the extrinsic and intrinsics refined
        online (``estimate_extrinsic``, ``estimate_intrinsics``), the time offset estimated
        (``estimate_td``); the stated ones where not refined (a re-start begins from them)."""
        w = self.window
        specs = [self.camera_spec] + ([] if self.stereo is None else [self.stereo.right])
        poses = [w.extrinsic] + ([] if w.T_B_R is None else [to_pose(w.T_B_R)])
        out = []
        for side, (spec, T_B_C) in enumerate(zip(specs, poses, strict=False)):
            fx, fy, cx, cy = w.intrinsics(side, spec.camera)
            ext, intr = w.calibration_sigmas(side, spec.camera)
            out.append(
                CameraCalibration(
                    camera=spec.name, T_B_C=T_B_C, fx=fx, fy=fy, cx=cx, cy=cy,
                    time_offset_s=self._td_s,
                    sigma_rotation_deg=None if ext is None else _three(np.degrees(ext[:3])),
                    sigma_translation_m=None if ext is None else _three(ext[3:]),
                    sigma_intrinsics_px=None if intr is None else _four(intr),
                    sigma_time_offset_s=self._td_sigma_s if self._td is not None else None,
                )
            )  # fmt: skip
        return tuple(out)

    def newest_keyframe(self) -> KeyframeRecord | None:
        """The window's newest keyframe as it stands (its pose and landmarks still change
        until it leaves; :meth:`keyframes` hands it out then), or None before a start."""
        if not self._initialized or not self.window.keyframes:
            return None
        k = self.window.keyframes[-1].index
        info = self._kf_info.get(k)
        return None if info is None or info.keyframe is None else self._record(k, info)

    def _push_imu(self, sample: ImuSample) -> OdometryState | None:
        """Buffer an IMU sample; once initialised, the state propagated to its time."""
        if not self.input.imu_ok(sample):
            return None
        self.imu.push(sample)  # (the running propagation carried to it)
        if self._imu_log is not None:
            self._imu_log.push(sample)
        if self.noise_monitor is not None:
            self.noise_monitor.push(sample.t_ns, sample.gyro_rad_s, sample.accel_m_s2)
        if self.stereo is not None and self.stereo.overdue(sample.t_ns):
            return self._unpaired()  # the stream moved past a left frame: it goes on as mono
        if self._td is not None:  # the online time offset compares the gyro with vision
            self._td.push_gyro(sample.t_ns, np.asarray(sample.gyro_rad_s))
        run = self.imu.running
        if not self._initialized or run is None:
            return None
        return self._predicted_state(sample.t_ns, run, "propagated", tracked=0)

    def _push_frame(self, frame: ImageFrame) -> OdometryState | None:
        """A camera frame stamped in the camera's clock (``td_s`` moves it to the IMU's)."""
        if frame.camera not in self.cameras:
            self.input.counts["other_camera"] += 1
            return None
        if self.stereo is not None and frame.camera == self.stereo.right.name:
            return self._push_right(frame)
        if not self.input.image_time_ok(frame.t_ns):
            return None
        done = self._unpaired() if self.stereo is not None and self.stereo.pending else None
        image = self._pixels(frame)
        features = None if image is None else self._front(int(frame.t_ns), image)
        if features is None or image is None:
            return done
        if self.stereo is None:
            return self._estimate_with(features, image, frame)
        right = self.stereo.take_right(int(frame.t_ns))
        if right is None:  # its partner has not come yet
            self.stereo.pending = PendingFrame(
                t_ns=int(frame.t_ns), features=features, image=image, source=frame
            )
            return done
        return self._estimate_pair(features, image, right, frame)

    def _pixels(self, frame: ImageFrame) -> NDArray[np.uint8] | None:
        try:
            return frame.image()
        except SampleError:
            self.input.counts["image"] += 1
            return None

    def _push_right(self, frame: ImageFrame) -> OdometryState | None:
        """The second camera's frame: paired with the left one waiting, or kept for it."""
        st = self.stereo
        assert st is not None
        if st.last_right_ns is not None and frame.t_ns <= st.last_right_ns:
            self.input.counts["image_time"] += 1
            return None
        st.last_right_ns = int(frame.t_ns)
        right = self._pixels(frame)
        if right is None:
            return None
        pending = st.pending
        if pending is not None and st.pairs_with_pending(frame.t_ns):
            st.pending = None
            return self._estimate_pair(pending.features, pending.image, right, pending.source)
        st.put_right(int(frame.t_ns), right)
        return None

    def _unpaired(self) -> OdometryState | None:
        """The waiting left frame, its partner missing or late: used as mono, counted."""
        st = self.stereo
        assert st is not None and st.pending is not None
        p, st.pending = st.pending, None
        self.input.counts["stereo_unpaired"] += 1
        return self._estimate_with(p.features, p.image, p.source)

    def _estimate_pair(
        self, features: FrameFeatures, left: NDArray[np.uint8], right: NDArray[np.uint8],
        source: ImageFrame,
    ) -> OdometryState | None:  # fmt: skip
        """A stereo pair: the right image is matched only if the frame becomes a keyframe
        (the window takes the second camera's observations at keyframes only)."""
        self._right_px = right
        try:
            return self._estimate_with(features, left, source)
        finally:
            self._right_px = None

    def _with_stereo(self, frame: FrameFeatures) -> FrameFeatures:
        """A keyframe's features with its corners found in the right image (as they are
        without a stereo partner)."""
        if self.stereo is None or self._right_px is None or self._image_px is None:
            return frame
        with self._stage("stereo"):
            frame = self.stereo.match(frame, self._image_px, self._right_px)
        self._last_features = frame
        return frame

    def _estimate_with(
        self, features: FrameFeatures, image: NDArray[np.uint8], source: ImageFrame
    ) -> OdometryState | None:
        """The estimate at a tracked frame, its pixels and source at hand for a keyframe."""
        self._image, self._image_px = source, image
        try:
            return self._estimate(features)
        finally:
            self._image, self._image_px = None, None

    def _front(self, t_ns: int, image: NDArray[np.uint8]) -> FrameFeatures | None:
        """The front end on a left image (None if it cannot be used, counted)."""
        t = int(t_ns) + s_to_ns(self._td_s)
        if self._td is not None:
            self._td_applied_ns[t] = t - int(t_ns)
        try:
            with self._stage("track"):
                frame = self.frontend.track(t, image, self._camera_rotation(t))
        except VisionError:
            self.input.counts["image"] += 1
            return None
        self._last_features = frame
        return frame

    def _camera_rotation(self, t_ns: int) -> FloatArray | None:
        """The camera's rotation since the last frame by the gyro (the newest keyframe's bias
        taken off once initialised), when ``predict_flow`` is on and the IMU covers it."""
        t0 = self.frontend.last_t_ns
        if not self.config.predict_flow or t0 is None:
            return None
        bias = np.asarray(self.window.newest.bias.gyroscope()) if self._initialized else np.zeros(3)
        R_B = self.imu.gyro_rotation(t0, t_ns, bias, hold_ns=self._hold_ns())
        if R_B is None:
            return None
        R_BC = self._R_BC
        out: FloatArray = R_BC.T @ R_B @ R_BC
        return out

    def _estimate(self, frame: FrameFeatures) -> OdometryState | None:
        t = frame.t_ns
        self._recent.append(frame)
        while self._recent and self._recent[0].t_ns < t - s_to_ns(self.config.static_window_s):
            self._recent.popleft()
        if not self._initialized:
            self._prune_imu()
            with self._stage("initialize"):
                return self._try_init(frame)
        return self._track(frame)

    # -- starting ---------------------------------------------------------------------------
    def _image_still(self, frame: FrameFeatures, since_ns: int) -> bool:
        """Features moved less than ``static_image_motion_px`` since ``since_ns``."""
        ref = next((f for f in self._recent if f.t_ns >= since_ns), None)
        return ref is not None and ref is not frame and self._stood(ref, frame)

    def _stood(
        self, ref: FrameFeatures, frame: FrameFeatures, most_px: float | None = None
    ) -> bool:
        """The features of ``frame`` are where they were in ``ref`` (median, >= 10 of them,
        within ``most_px``; by default ``static_image_motion_px``)."""
        motion, n = median_motion_px(ref, frame)
        limit = self.config.static_image_motion_px if most_px is None else most_px
        return n >= 10 and motion < limit

    def _try_init(self, frame: FrameFeatures) -> OdometryState | None:
        cfg = self.config
        span_ns = s_to_ns(cfg.static_window_s)
        if tracking_failure(len(frame.ids), cfg) is not None:
            return None
        start = static_start(self.imu.samples, frame.t_ns, cfg)
        if start is not None and self._forward_B is not None:
            start = dataclasses.replace(start, R_W_B=heading_of(start.R_W_B, self._forward_B))
        if start is not None and self._image_still(frame, frame.t_ns - span_ns // 2):
            return self._start_static(frame, start)
        return self._try_visual_init(frame)

    def _start_static(self, frame: FrameFeatures, start: StaticStart) -> OdometryState:
        cfg = self.config
        frame = self._with_stereo(frame)
        k = self._new_kf_index()
        if k == 0:  # (the first start: later ones go on from the last position)
            self._last_p = start.R_W_B.apply(self._p_V_B_in_B)
        pose = gtsam.Pose3(gtsam.Rot3(start.R_W_B.as_matrix()), self._last_p)
        bias = gtsam.imuBias.ConstantBias(np.zeros(3), start.gyro_bias)
        kf = Keyframe(index=k, t_ns=frame.t_ns, pose=pose, velocity=np.zeros(3), bias=bias)
        prior = StatePrior(
            cov_pose=self._first_pose_cov(start.R_W_B.as_matrix(), GAUGE_POSITION_SIGMA_M),
            cov_v=np.eye(3) * cfg.static_velocity_sigma_m_s**2,
            cov_bias=np.diag(
                [cfg.init_accel_bias_sigma_m_s2**2] * 3 + [cfg.init_gyro_bias_sigma_rad_s**2] * 3
            ),
            rest_accel_B=start.stillness.accel_mean,
            rest_accel_sigma_m_s2=cfg.init_attitude_sigma_rad * cfg.g_norm,
        )
        self.window.start(kf, prior)
        # until the first solve, the first state's marginal: its tilt is off by b / g too
        tilt = math.hypot(cfg.init_attitude_sigma_rad, cfg.init_accel_bias_sigma_m_s2 / cfg.g_norm)
        self._cov_pose = self._first_pose_cov(start.R_W_B.as_matrix(), GAUGE_POSITION_SIGMA_M, tilt)
        self._cov_v, self._cov_bias = prior.cov_v, prior.cov_bias
        self._add_features(kf, frame)
        self._commit()
        self._begin(frame, "static")
        return self._keyframe_state(frame)

    def _first_pose_cov(
        self, R_W_B: FloatArray, sigma_p_m: float, tilt: float = FREE_TILT_SIGMA_RAD
    ) -> FloatArray:
        """The first state's pose prior (GTSAM's body-frame tangent space): yaw and position
        are the gauge (:data:`GAUGE_YAW_SIGMA_RAD`, ``sigma_p_m``); roll and pitch only a weak
        :data:`FREE_TILT_SIGMA_RAD`. The accelerometer that gave the start's gravity says
        where they are, with its bias: a visual start's IMU is in the window, a static start's
        readings join it as one factor (:func:`~quadnav.vio.window.rest_factor`). A tilt prior
        from the same readings beside the bias prior counted them twice (on realistic MH_01
        stereo the pose NEES / 6 over 5 seeds was 2.46). ``tilt``: another roll-pitch sigma."""
        R = np.asarray(R_W_B, dtype=np.float64)
        rot = R.T @ np.diag([tilt**2, tilt**2, GAUGE_YAW_SIGMA_RAD**2]) @ R
        cov = np.zeros((6, 6))
        cov[:3, :3] = 0.5 * (rot + rot.T)
        cov[3:, 3:] = np.eye(3) * sigma_p_m**2
        return cov

    def _begin(self, frame: FrameFeatures, how: str) -> None:
        """Tracking from the window just started; the run's event (a re-start is counted)."""
        self.frontend.mark_keyframe(frame)
        self._initialized = True
        self._waiting_since_ns = self._waiting_reported_ns = None
        self._init_frames = []
        self._run_from(self.window.newest)
        if self._failures:
            self._reset_counter += 1
            detail = f"{how} (reset {self._reset_counter})"
            self._events.append(OdometryEvent(t_ns=frame.t_ns, kind="reinitialized", detail=detail))
        else:
            self._events.append(OdometryEvent(t_ns=frame.t_ns, kind="initialized", detail=how))

    def _new_window(self) -> SlidingWindow:
        spec = self.camera_spec
        right = None if self.stereo is None else self.stereo.right
        cams = [spec.camera] + ([] if right is None else [right.camera])
        T_B_R = None if right is None else right.T_B_C
        return SlidingWindow(self.config, spec.T_B_C, spec.camera.fx, T_B_R, cams)

    def _init_keyframes(self) -> int:
        """Keyframes a start in motion waits for: a window's (mono: the parallax that gives the
        structure and the acceleration that gives its scale), fewer with stereo (metric at once)."""
        cfg = self.config
        return cfg.window_keyframes if self.stereo is None else cfg.stereo_init_keyframes

    def _new_kf_index(self) -> int:
        k = self._next_kf
        self._next_kf += 1
        return k

    def _try_visual_init(self, frame: FrameFeatures) -> OdometryState | None:
        """The visual-inertial initialisation over the keyframes collected while moving."""
        init = self._visual_init
        dec = self.frontend.decide(frame)
        if not dec.keyframe:
            return None
        frame = self._with_stereo(frame)
        self.frontend.mark_keyframe(frame)
        need = self._init_keyframes()
        self._init_frames = (self._init_frames + [frame])[-need:]
        self._candidates[frame.t_ns] = self._info(frame)
        keep = {f.t_ns for f in self._init_frames}
        self._candidates = {t: c for t, c in self._candidates.items() if t in keep}
        if len(self._init_frames) < need:
            return None
        frames = tuple(self._init_frames)
        self._refresh_imu_noise(frame.t_ns)
        if self.noise_monitor is not None and self.imu_noise is None:
            # a start on the stated noise would keep its too-sure first spans (a datasheet's
            # noise is 15-30 times smaller than a vehicle's in flight): it waits the half second
            # the monitor needs
            self._still_waiting(frame.t_ns, "the IMU's noise is not measured yet")
            return None
        try:
            hold = self._hold_ns()  # a camera stamped early: its newest frame is past the IMU
            pims = tuple(
                self.imu.span(a.t_ns, b.t_ns, zero_bias(), hold_ns=hold)
                for a, b in itertools.pairwise(frames)
            )
        except VioError:
            return None
        window = InitWindow(
            frames=frames,
            preintegrations=pims,
            T_B_C=self.camera_spec.T_B_C,
            g_norm=self.config.g_norm,
            T_L_R=None if self.stereo is None else self.stereo.geometry.T_L_R,
        )
        result = init(window)
        if isinstance(result, InitFailure):
            self._still_waiting(frame.t_ns, result.reason)
            return None
        return self._start_visual(frames, pims, result)

    def _still_waiting(self, t_ns: int, reason: str) -> None:
        """A window refused: every ``WAITING_REPORT_S`` without a start (or a re-start after a
        failure), an event saying for how long and why the last window was refused (a
        monocular VIO needs acceleration to see its scale: it cannot start again on a steady
        cruise)."""
        since = self._waiting_since_ns
        if since is None:
            self._waiting_since_ns = since = t_ns
        last = self._waiting_reported_ns if self._waiting_reported_ns is not None else since
        if t_ns - last < s_to_ns(WAITING_REPORT_S):
            return
        self._waiting_reported_ns = t_ns
        what = "re-started after the failure" if self._failures else "started"
        detail = f"not {what} for {(t_ns - since) / NS_PER_S:.1f} s: the last window: {reason}"
        self._events.append(OdometryEvent(t_ns=int(t_ns), kind="waiting", detail=detail))

    def _start_visual(
        self,
        frames: tuple[FrameFeatures, ...],
        pims: tuple[gtsam.PreintegratedCombinedMeasurements, ...],
        result: InitResult,
    ) -> OdometryState:
        cfg = self.config
        bias = gtsam.imuBias.ConstantBias(np.zeros(3), np.asarray(result.gyro_bias))
        self.features.clear()
        kfs = []
        for i, f in enumerate(frames):
            k = self._new_kf_index()
            kfs.append(
                Keyframe(
                    index=k,
                    t_ns=f.t_ns,
                    pose=pose3(result.T_W_B[i]),
                    velocity=np.asarray(result.v_W_B[i], np.float64),
                    bias=bias,
                    pim=None if i == 0 else pims[i - 1],
                )
            )
            self._add_features(kfs[-1], f)
        prior = StatePrior(
            cov_pose=self._first_pose_cov(
                result.T_W_B[0].R_A_B.as_matrix(), GAUGE_POSITION_SIGMA_M
            ),
            cov_v=np.eye(3) * 0.1**2,
            cov_bias=np.diag([cfg.init_accel_bias_sigma_m_s2**2] * 3 + [0.01**2] * 3),
        )
        self.window.start(kfs[0], prior)
        for kf in kfs[1:]:
            self.window.push(kf)
        self.window.seed_landmarks(dict(result.landmarks_W))
        res = self.window.solve(self.features)
        if res.ok:
            self._cov_pose, self._cov_v, self._cov_bias = res.cov_pose, res.cov_v, res.cov_bias
        self._commit()
        self._retire()
        self._begin(frames[-1], "visual" if self.stereo is None else "visual, stereo")
        return self._keyframe_state(frames[-1])

    # -- tracking ---------------------------------------------------------------------------
    def _span(self, kf: Keyframe, t1_ns: int) -> gtsam.PreintegratedCombinedMeasurements:
        """The IMU from keyframe ``kf`` to ``t1_ns`` with its bias (empty for no span)."""
        self._refresh_imu_noise(t1_ns)
        return self.imu.span(kf.t_ns, t1_ns, kf.bias, hold_ns=self._hold_ns())

    def _refresh_imu_noise(self, t_ns: int) -> None:
        """At most every half second: the IMU noise measured in flight, where it exceeds the
        stated one, in the preintegration from now on (a change of over 10 % on any axis)."""
        if self.noise_monitor is None or t_ns - self._noise_checked_ns < NS_PER_S // 2:
            return
        measured = self.noise_monitor.noise()
        if measured is None:
            return  # (asked again at the next span: the first measurement is not put off)
        self._noise_checked_ns = t_ns
        old = self.imu_noise
        if old is not None:
            was = np.maximum(np.concatenate([old.gyro, old.accel]), 1e-12)
            rel = np.concatenate([measured.gyro, measured.accel]) / was
            if np.all(np.abs(rel - 1.0) < 0.1):
                return
        self.imu_noise = measured
        self._params = imu_params(
            self._noise, g_norm=self.config.g_norm, measured=measured,
            accel_inflation=self.config.accel_noise_inflation,
        )  # fmt: skip
        self.imu.params = self._params
        if self._imu_log is not None:
            self._imu_log.use_params(t_ns, self._params)
        self._report_imu_noise(t_ns, measured)

    def _report_imu_noise(self, t_ns: int, measured: MeasuredNoise) -> None:
        """An event when the measured noise first exceeds the stated one, and again at each
        change by a factor of 1.5 (a take-off, a landing)."""
        n = self._noise
        rms = np.sqrt(
            np.mean(np.concatenate([measured.gyro, measured.accel]).reshape(2, 3) ** 2, 1)
        )
        ratio = rms / np.maximum([n.gyro_noise_density, n.accel_noise_density], 1e-12)
        last = self._noise_reported
        if last is None:
            news = bool(np.any(ratio > 1.0))
        else:
            change = np.maximum(rms, 1e-12) / np.maximum(last, 1e-12)
            news = bool(np.any(np.abs(np.log(change)) >= np.log(1.5)))
        if not news:
            return
        self._noise_reported = rms
        detail = (
            f"IMU noise in flight: gyro {rms[0]:.2g} rad/s/sqrt(Hz) ({ratio[0]:.1f}x the stated), "
            f"accelerometer {rms[1]:.2g} m/s^2/sqrt(Hz) ({ratio[1]:.1f}x)"
        )
        self._events.append(OdometryEvent(t_ns=int(t_ns), kind="imu_noise", detail=detail))

    def _hold_ns(self) -> int:
        """An image the time offset moves ahead of the newest IMU: its last sample holds."""
        return max(s_to_ns(self._td_s), 0) + (2_000_000 if self._td is not None else 0)

    def _run_from(self, kf: Keyframe) -> None:
        """The state between frames: the newest keyframe propagated at the IMU's rate."""
        self.imu.run_from(kf.t_ns, kf.bias, hold_ns=self._hold_ns())

    def _predicted_state(
        self,
        t_ns: int,
        pim: gtsam.PreintegratedCombinedMeasurements,
        status: str,
        *,
        tracked: int,
    ) -> OdometryState:
        """The newest keyframe carried to ``t_ns`` by ``pim``; its covariance grown by the
        preintegration's (rotation, position; velocity in the world)."""
        kf = self.window.newest
        pr = ImuPropagator.predict(kf.pose, kf.velocity, kf.bias, pim, self._cov_pose, self._cov_v)
        if status == "tracking":
            self._trail.frame(t_ns, kf.index, kf.pose, pr.pose)
        return self._state(
            t_ns, pr.pose, pr.velocity, kf.bias, pr.cov_pose, pr.cov_v, status, False, tracked
        )

    def _state(
        self,
        t_ns: int,
        pose: gtsam.Pose3,
        v: FloatArray,
        bias: gtsam.imuBias.ConstantBias,
        cov_pose: FloatArray,
        cov_v: FloatArray,
        status: str,
        keyframe: bool,
        tracked: int,
    ) -> OdometryState:
        return OdometryState(
            t_ns=int(t_ns),
            T_W_B=to_pose(pose),
            v_W_B=np.asarray(v, np.float64),
            gyro_bias=np.asarray(bias.gyroscope(), np.float64),
            accel_bias=np.asarray(bias.accelerometer(), np.float64),
            cov_pose=0.5 * (cov_pose + cov_pose.T),
            cov_v=0.5 * (cov_v + cov_v.T),
            status="propagated" if status == "propagated" else "tracking",
            keyframe=keyframe,
            reset_counter=self._reset_counter,
            quality=self._quality(tracked, status),
            td_s=self._td_s,
            tracked=tracked,
        )

    def _quality(self, tracked: int, status: str) -> int:
        """PX4's 0-100: the share of the front end's feature budget tracked at the last frame
        (between frames, the last frame's)."""
        if status == "propagated":
            tracked = len(self._last_features.ids) if self._last_features is not None else 0
        budget = self.config.tracker.max_features
        return round(100 * min(1.0, tracked / budget)) if budget > 0 else 0

    def _keyframe_state(self, frame: FrameFeatures) -> OdometryState:
        kf = self.window.newest
        info = self._kf_info.get(kf.index)
        if info is not None:
            info.cov_pose = np.array(self._cov_pose)
            info.step, self._step = self._step, None
        self._last_p = np.asarray(kf.pose.translation(), np.float64)
        self._trail.frame(kf.t_ns, kf.index, kf.pose, kf.pose)
        return self._state(
            kf.t_ns, kf.pose, kf.velocity, kf.bias, self._cov_pose, self._cov_v,
            "tracking", True, len(frame.ids),
        )  # fmt: skip

    def _still_since(self, kf: Keyframe, frame: FrameFeatures) -> bool:
        """At rest from keyframe ``kf`` to this frame: a quiet IMU and features that stood,
        still enough to tell a velocity of ``static_velocity_sigma_m_s`` (what the constraint
        at rest claims) from none. A hovering quadrotor's IMU reads as one at rest, and a slow
        drift moves far features by less than ``static_image_motion_px``: at 4.9 m, 5 cm/s
        over 0.5 s is 2.3 px, 1 cm/s 0.5 px. Held at zero velocity, the VIO then stood still
        while the vehicle drifted (0.5 m in 7 s in one simulated flight). So the features must
        have moved less than twice that sigma would move them over the span at the median
        depth of the landmarks the frame sees (:meth:`_still_px`)."""
        cfg = self.config
        st = imu_stillness(self.imu.samples, kf.t_ns, frame.t_ns, cfg.static_lowpass_s)
        span = (frame.t_ns - kf.t_ns) * 1e-9
        if not is_still(st, cfg, span):
            return False
        ref = self.frontend.last_keyframe
        return ref is not None and self._stood(ref, frame, self._still_px(kf, frame, span))

    def _still_px(self, kf: Keyframe, frame: FrameFeatures, span_s: float) -> float:
        """The most median feature motion (px) that still tells the vehicle stood over
        ``span_s``: ``static_image_motion_px``, or less where the landmarks are far (twice
        ``static_velocity_sigma_m_s`` over the span, at their median depth from ``kf``)."""
        cfg = self.config
        position = self.window.landmark_position
        points = [p for j in frame.ids.tolist() if (p := position(j)) is not None]
        if len(points) < 10:
            return cfg.static_image_motion_px
        T_W_C = kf.pose.compose(self.window.T_B_C)
        R, t = T_W_C.rotation().matrix(), np.asarray(T_W_C.translation(), np.float64)
        depth = (np.asarray(points, np.float64) - t) @ R[:, 2]
        depth = depth[depth > 0.0]
        if depth.size < 10:
            return cfg.static_image_motion_px
        seen = 2.0 * cfg.static_velocity_sigma_m_s * span_s * self.window.focal_px
        return min(cfg.static_image_motion_px, seen / float(np.median(depth)))

    def _track(self, frame: FrameFeatures) -> OdometryState | None:
        cfg = self.config
        reason = tracking_failure(len(frame.ids), cfg)
        if reason is not None:
            return self._fail(frame.t_ns, reason)
        kf = self.window.newest
        try:
            with self._stage("preintegrate"):
                pim = self._span(kf, frame.t_ns)
        except VioError:
            self.input.counts["imu_gap"] += 1
            return None
        with self._stage("keyframe"):
            R_B = pim.deltaRij().matrix()
            R_BC = self._R_BC
            dec = self.frontend.decide(frame, R_BC.T @ R_B @ R_BC)
        if not dec.keyframe:
            return self._predicted_state(frame.t_ns, pim, "tracking", tracked=len(frame.ids))
        return self._add_keyframe(
            frame, kf, pim, drop_previous=dec.by_time and cfg.drop_second_newest,
            drop_if_still=dec.by_time and cfg.drop_at_rest,
        )  # fmt: skip

    def _add_keyframe(
        self,
        frame: FrameFeatures,
        prev: Keyframe,
        pim: gtsam.PreintegratedCombinedMeasurements,
        *,
        drop_previous: bool = False,
        drop_if_still: bool = False,
    ) -> OdometryState | None:
        """``drop_if_still``: the previous newest keyframe leaves instead of the oldest when it
        and this one are both at rest and the window holds motion before them
        (``VioConfig.drop_at_rest``)."""
        cfg = self.config
        frame = self._with_stereo(frame)
        nav = pim.predict(gtsam.NavState(prev.pose, prev.velocity), prev.bias)
        bias0 = prev.bias
        still = self._still_since(prev, frame)
        # (only once the window holds motion: at a start at rest it keeps the rest's keyframes;
        # and for drop_at_rest_max_s at most: the IMU is kept back to the oldest keyframe)
        moved = any(not k.still for k in self.window.keyframes[1:])
        young = frame.t_ns - self.window.keyframes[0].t_ns <= s_to_ns(cfg.drop_at_rest_max_s)
        drop_previous = drop_previous or (
            drop_if_still and still and prev.still and moved and young
        )
        k = self._new_kf_index()
        kf = Keyframe(
            index=k, t_ns=frame.t_ns, pose=nav.pose(), velocity=np.asarray(nav.velocity()),
            bias=prev.bias, pim=pim, still=still,
        )  # fmt: skip
        self.window.push(kf, drop_previous=drop_previous)
        if self.window.dropping == prev.index:
            # not published: the loop closer takes keyframes in order, as they leave as the
            # oldest (VINS-Mono's pose graph likewise gets MARGIN_OLD's keyframes only)
            self._kf_info.pop(prev.index, None)
        self._add_features(kf, frame)
        self.frontend.mark_keyframe(frame)
        with self._stage("optimize"):
            res = self.window.solve(self.features)
        if not res.ok:
            res = self._restart_in_place(prev, kf, res.reason)
        if not res.ok:
            return self._fail(frame.t_ns, res.reason)
        if res.qr_fallback:
            detail = "Cholesky refused the window (ill-conditioned): solved with QR"
            self._events.append(OdometryEvent(t_ns=frame.t_ns, kind="recovered", detail=detail))
        new = self.window.newest
        solved = SolvedState(
            p_W=np.asarray(new.pose.translation()), v_W=new.velocity,
            p_pred_W=np.asarray(nav.pose().translation()), v_pred_W=np.asarray(nav.velocity()),
            accel_bias=np.asarray(new.bias.accelerometer()),
            gyro_bias=np.asarray(new.bias.gyroscope()),
            accel_bias_before=np.asarray(bias0.accelerometer()),
            gyro_bias_before=np.asarray(bias0.gyroscope()),
        )  # fmt: skip
        reason = state_failure(solved, cfg)
        if reason is not None:
            return self._fail(frame.t_ns, reason)
        self._cov_pose, self._cov_v, self._cov_bias = res.cov_pose, res.cov_v, res.cov_bias
        self._step = res.step
        self._commit()
        self._retire()
        self._run_from(new)
        self._feed_time_offset(prev, new)
        self._prune_imu()
        return self._keyframe_state(frame)

    def _restart_in_place(self, prev: Keyframe, kf: Keyframe, reason: str) -> SolveResult:
        """The window restarted in place after ``kf``'s solve failed: a new graph over the
        window's keyframes at their last good estimates (``kf`` at its IMU prediction from
        ``prev``, the newest solved), the IMU between them integrated again, their
        observations, the landmarks starting from their last estimates, and on the oldest a
        prior with ``prev``'s marginal covariances times ``restart_inflation`` (the newest's:
        the oldest is known no worse); only the marginalised past is lost. If that does not
        solve, the same from ``prev`` and ``kf`` alone. Not done (a failed result) when off,
        or a second time within a window's keyframes of the last restart."""
        cfg = self.config
        last = self._restarted_kf
        if not cfg.restart_in_place:
            return SolveResult(ok=False, reason=reason)
        if last is not None and kf.index - last < cfg.window_keyframes:
            return SolveResult(ok=False, reason=f"{reason} (again within a window of a restart)")
        window = self.window
        window.rollback()  # the failed keyframe's factors leave the run's history
        points = {j: p for j in window.landmarks if (p := window.landmark_position(j)) is not None}
        a = cfg.restart_inflation
        prior = StatePrior(
            cov_pose=a * self._cov_pose, cov_v=a * self._cov_v, cov_bias=a * self._cov_bias
        )
        tries = [list(window.keyframes), [prev, kf]]
        for kfs in tries if len(window.keyframes) > 2 else tries[1:]:
            res = self._restart_with(kfs, prior, points)
            if res.ok:
                break
        if not res.ok:
            return SolveResult(
                ok=False, reason=f"{reason}; the restart in place failed: {res.reason}"
            )
        self._restarted_kf = kf.index
        detail = f"window restarted from the last good state ({reason})"
        self._events.append(OdometryEvent(t_ns=kf.t_ns, kind="recovered", detail=detail))
        self._retire()  # the keyframes the restart left out
        return res

    def _restart_with(
        self, kfs: list[Keyframe], prior: StatePrior, points: dict[int, FloatArray]
    ) -> SolveResult:
        """A new graph over ``kfs`` (see :meth:`_restart_in_place`); the observations of the
        window's other keyframes dropped; the landmarks of tracks seen in two of ``kfs`` start
        from ``points``."""
        window, features = self.window, self.features
        keep = {k.index for k in kfs}
        for old in window.keyframes:
            if old.index not in keep:
                features.drop_keyframe(old.index)
        try:
            for k0, k1 in itertools.pairwise(kfs):
                k1.pim = self.imu.span(k0.t_ns, k1.t_ns, k0.bias, hold_ns=self._hold_ns())
        except VioError as exc:
            return SolveResult(ok=False, reason=str(exc))
        window.start(kfs[0], prior)
        window.seed_landmarks({
            j: p for j, p in points.items() if len(keep.intersection(features.observations(j))) >= 2
        })  # fmt: skip
        for k1 in kfs[1:]:
            window.push(k1)
        with self._stage("optimize"):
            res = window.solve(features)
        if not res.ok:
            window.discard()  # not a segment of the run's history
        return res

    def _feed_time_offset(self, a: Keyframe, b: Keyframe) -> None:
        """The rotation of consecutive optimised camera poses, at the images' own stamps (the
        offset each was given taken back off), goes to the online time-offset estimator; its
        estimate, once it has one, is the offset later images get (VINS' ``estimate_td``)."""
        if self._td is None:
            return
        cfg = self.config
        R_C0_C1 = self._vision_rotation(a.index, b.index)
        applied = self._td_applied_ns
        t0 = a.t_ns - applied.get(a.t_ns, s_to_ns(self._td_s))
        t1 = b.t_ns - applied.get(b.t_ns, s_to_ns(self._td_s))
        for t in [t for t in applied if t < a.t_ns]:
            del applied[t]
        if t1 <= t0 or R_C0_C1 is None:
            return
        self._td.push_rotation(t0, t1, R_C0_C1)
        est = self._td.estimate()
        if est is None or not np.isfinite(est.td_s) or abs(est.td_s) > 0.1:
            return
        # a motion whose rate hardly changes, or an answer less sure than the stated offset
        if not (est.excited and est.sigma_s <= cfg.td_prior_sigma_s):
            if self._td_observable is not False:  # said once each time it stops being usable
                self._td_observable = False
                measured = f"measured {1e3 * est.td_s:.2f} ms, sigma {1e3 * est.sigma_s:.2f} ms"
                why = (
                    f"not observable from this motion (its rate changes by "
                    f"{est.excitation_rad_s2:.2f} rad/s^2, under "
                    f"{cfg.td_min_rate_change_rad_s2:.2f}; {measured})"
                    if not est.excited
                    else f"the estimate ({measured}) is less sure than the stated offset "
                    f"({1e3 * cfg.td_prior_sigma_s:.2f} ms)"
                )
                detail = f"camera-IMU offset held at {1e3 * self._td_s:.2f} ms: {why}"
                self._events.append(OdometryEvent(t_ns=b.t_ns, kind="td", detail=detail))
            return
        back = self._td_observable is False
        self._td_observable = True
        first = self._td_reported_s is None
        # weighed against the stated offset (its prior): a wandering early estimate moves little
        w = cfg.td_prior_sigma_s**2 / (cfg.td_prior_sigma_s**2 + est.sigma_s**2)
        self._td_s = self._td_stated_s + w * (float(est.td_s) - self._td_stated_s)
        self._td_sigma_s = float(np.sqrt(w) * est.sigma_s)  # the two sigmas combined
        settled = est.converged and not self._td_settled
        moved = not first and abs(self._td_s - float(self._td_reported_s or 0.0)) > 1e-3
        if first or settled or moved or back:  # first, moved over 1 ms, settled, usable again
            self._td_settled = self._td_settled or est.converged
            self._td_reported_s = self._td_s
            detail = (
                f"camera-IMU offset {1e3 * self._td_s:.2f} ms (measured {1e3 * est.td_s:.2f}, "
                f"sigma {1e3 * est.sigma_s:.2f} ms)"
            )
            self._events.append(OdometryEvent(t_ns=b.t_ns, kind="td", detail=detail))

    def _vision_rotation(self, ka: int, kb: int) -> FloatArray | None:
        """The camera's rotation from keyframe ``ka`` to ``kb`` by vision alone (the essential
        matrix of their common tracks): the optimised poses follow the gyro, which would hide
        the offset."""
        tracks = self.features.tracks.values()
        pairs = [(obs[ka], obs[kb]) for obs in tracks if ka in obs and kb in obs]
        if len(pairs) < 15:
            return None
        x0 = np.array([p[0] for p in pairs], np.float64)
        x1 = np.array([p[1] for p in pairs], np.float64)
        two = essential_pose(x0, x1, threshold=1.0 / self.window.focal_px, min_inliers=12)
        return None if two is None else two.T_Ca_Cb.R_A_B.as_matrix()

    # -- keyframes for the interface ---------------------------------------------------------
    def _info(self, frame: FrameFeatures) -> _KeyframeInfo:
        """A keyframe's features with the frame being pushed and, if asked, ORB descriptors at
        its corners (computed while its pixels are at hand)."""
        desc = ok = None
        if self.config.describe_keyframes and self._image_px is not None:
            with self._stage("describe"):
                try:
                    desc, ok = orb_at(self._image_px, frame.uv_px)
                except VisionError:
                    desc = ok = None
        return _KeyframeInfo(features=frame, image=self._image, descriptors=desc, described=ok)

    def _add_features(self, kf: Keyframe, frame: FrameFeatures) -> None:
        """A keyframe enters the window: its observations, and what it will be published with."""
        self.features.add(kf.index, frame)
        info = self._candidates.pop(frame.t_ns, None) or self._info(frame)
        info.keyframe = kf
        self._kf_info[kf.index] = info

    def _retire(self, *, everything: bool = False) -> None:
        """Publish the keyframes that left the window (all of them at a failure or the end)."""
        inside = set() if everything else {kf.index for kf in self.window.keyframes}
        for k in sorted(set(self._kf_info) - inside):
            info = self._kf_info.pop(k)
            if info.keyframe is not None:
                self._done.append(self._record(k, info))
        excess = len(self._done) - self.config.max_unread_keyframes
        if excess > 0:  # nobody reads them: the oldest go (memory stays bounded), counted
            del self._done[:excess]
            self.input.counts["keyframes_unread"] += excess

    def _record(self, k: int, info: _KeyframeInfo) -> KeyframeRecord:
        kf, f = info.keyframe, info.features
        assert kf is not None
        position = self.window.landmark_position
        seen = [(j, p) for j in f.ids.tolist() if (p := position(j)) is not None]
        seen = self._fixed_landmarks(seen, kf, f)
        cov = info.cov_pose if info.cov_pose is not None else self._cov_pose
        return KeyframeRecord(
            index=k, t_ns=kf.t_ns, reset_counter=self._reset_counter, T_W_B=to_pose(kf.pose),
            cov_pose=cov, camera=self.camera, image=info.image, ids=f.ids, uv_px=f.uv_px,
            xy=self.window.corrected_xy(f.xy), descriptors=info.descriptors, described=info.described,
            landmark_ids=np.array([j for j, _ in seen], np.int64),
            landmarks_W=np.array([p for _, p in seen], np.float64).reshape(-1, 3),
            T_B_C=self.window.extrinsic, step=info.step,
        )  # fmt: skip

    def _fixed_landmarks(
        self, seen: list[tuple[int, FloatArray]], kf: Keyframe, f: FrameFeatures
    ) -> list[tuple[int, FloatArray]]:
        """Of a keyframe's landmarks, those whose depth the window's views fix: the cameras that
        see it (this keyframe's, its second camera's where the track is there, and the window's
        keyframes that see the track) span ``keyframe_landmark_min_parallax_deg`` at it. A
        track seen only while hovering has next to no parallax: its point is where the window
        happened to leave it (in a hover of thesis 003's flight, 1-4 m off at 4.7 m: a landmark
        that goes on after its first keyframe leaves the window starts from its old estimate,
        but nothing holds its depth there), harmless to the odometry, not to a loop's PnP
        against a map."""
        need = math.radians(self.config.keyframe_landmark_min_parallax_deg)
        if need <= 0.0 or not seen:
            return seen
        T_B_C = self.window.extrinsic
        T_W_B = to_pose(kf.pose)
        own = [(T_W_B @ T_B_C).p_A_B]
        right = set()
        if self.stereo is not None:
            own.append((T_W_B @ self.stereo.right.T_B_C).p_A_B)
            right = set(f.stereo_ids.tolist())
        centres = {w.index: (to_pose(w.pose) @ T_B_C).p_A_B for w in self.window.keyframes}
        out = []
        for j, p in seen:
            views = [centres[k] for k in self.features.observations(j) if k in centres]
            cs = [own[0], *([own[1]] if j in right else []), *views]
            if parallax_rad(p, np.array(cs)) >= need:
                out.append((j, p))
        return out

    def _prune_imu(self) -> None:
        """Keep the IMU the window and a static start may still need."""
        last = self.imu.last_t_ns
        if last is None:
            return
        keep_ns = last - s_to_ns(self.config.static_window_s + 0.5)
        if self.window.keyframes:
            keep_ns = min(keep_ns, self.window.keyframes[0].t_ns)
        self.imu.prune(keep_ns)

    def _fail(self, t_ns: int, reason: str) -> OdometryState | None:
        """A failure: reported, the window reset; the next frames re-initialise."""
        self._events.append(OdometryEvent(t_ns=int(t_ns), kind="failure", detail=reason))
        self._failures += 1
        self._waiting_since_ns, self._waiting_reported_ns = int(t_ns), None
        if self.window.keyframes:
            self._last_p = np.asarray(self.window.keyframes[-1].pose.translation(), np.float64)
        self._retire(everything=True)
        self._candidates.clear()
        old = self.window
        old.rollback()  # what the failure refused leaves the run's history
        old.close_segment()
        self.window = self._new_window()
        self.window.segments, self.window.kf_times = old.segments, old.kf_times
        self.features.clear()
        self.frontend.reset()
        self._recent.clear()
        self._init_frames = []
        self._initialized = False
        self.imu.stop()
        return None
