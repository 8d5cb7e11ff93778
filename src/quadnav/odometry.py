"""The odometry interface: what a visual odometry (the VIO now, the SLAM next) takes, gives out and
publishes, with no GTSAM and no OpenCV in it, so that a run, a loop closer, a map or a fusion
depends on it and not on an estimator.

An odometry takes :class:`~quadnav.messages.ImuSample` and :class:`~quadnav.messages.ImageFrame`
(of any camera of its rig) in time order through ``push`` and answers with an
:class:`OdometryState` once it has one. Its world frame ``W`` is gravity-aligned (z up) with the
yaw and origin of its initialisation; ``reset_counter`` goes up each time it starts again (its
frame then jumps, as PX4's external odometry expects). ``keyframes()`` hands out, once each, the
keyframes it has finished with (they left its window): their final pose, covariance, keypoints
with their descriptors, the landmarks they see and a reference to their image, for a loop closer
or a map to keep. The odometry keeps none of them, so its memory stays bounded.

Covariances of a pose follow GTSAM's ``Pose3`` convention: 6x6 over (rx, ry, rz, x, y, z), a
perturbation on the right, ``T = T_hat Exp(xi)``, i.e. in the body frame.
:meth:`OdometryState.odometry` turns that into PX4's world-frame order for the EKF.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import SampleError
from quadnav.geometry.rotations import Pose
from quadnav.messages import ImageFrame, ImuSample, OdometrySample

if TYPE_CHECKING:
    from quadnav.geometry.trajectory import Trajectory

__all__ = [
    "TRACKING_EVENTS",
    "CameraCalibration",
    "EventKind",
    "FrameFeatures",
    "KeyframeRecord",
    "KeyframeStep",
    "LoopConstraint",
    "LoopRefinedTrajectory",
    "OdometryEvent",
    "OdometryState",
    "OnlineCalibration",
    "RefinedTrajectory",
    "StageTiming",
    "Status",
    "VisualOdometry",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

Status = Literal["tracking", "propagated"]
EventKind = Literal[
    "initialized",
    "failure",
    "reinitialized",
    "recovered",
    "td",
    "stereo",
    "imu_noise",
    "loop",
    "loop_rejected",
    "relocalized",
    "image_gap",
    "waiting",
]
#: The events that start or break the estimate's continuity; "recovered" (a solve redone another
#: way, or the window restarted from the last good state: the output goes on) does not;
#: the others ("td", "stereo", "imu_noise") report what the odometry measured about its sensors,
#: and "loop" / "loop_rejected" a place recognised and closed or refused (the output may jump at
#: a loop closed: its reset counter says so), "relocalized" / "image_gap" a loop closer's
#: segment joined to its map and a gap in the images it saw, "waiting" an odometry that has
#: not (re-)started for a while and why.
TRACKING_EVENTS: tuple[EventKind, ...] = ("initialized", "failure", "reinitialized")


@dataclass(frozen=True, slots=True, kw_only=True)
class FrameFeatures:
    """One camera frame's tracked features: ``ids`` (stable per track), ``uv_px`` (distorted
    pixels, as tracked), ``xy`` (undistorted normalised image coordinates, z = 1) and
    ``velocity_xy_s`` (their image velocity in normalised coordinates per second, for the time
    offset), with ``keyframe`` the front end's decision and ``parallax_px`` its reason; with a
    stereo rig, the same features in the second camera."""

    t_ns: int
    ids: IntArray
    uv_px: FloatArray
    xy: FloatArray
    velocity_xy_s: FloatArray
    keyframe: bool = False
    parallax_px: float = 0.0
    #: with a stereo rig: the features also found in the second camera (ids, a subset of
    #: ``ids``) and where (undistorted normalised coordinates of that camera)
    stereo_ids: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    stereo_xy: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometryState:
    """The estimate at ``t_ns``: the pose and velocity of the body in the odometry's world, the
    IMU biases, the covariances (``cov_pose`` GTSAM's 6x6 (rot, trans) in the body frame;
    ``cov_v`` 3x3 world), ``status`` (``tracking`` after an optimisation at a camera frame,
    ``propagated`` by the IMU between frames), whether it is a keyframe's, ``reset_counter``
    (up at each re-initialisation), ``quality`` (0-100 as PX4's ODOMETRY: the share of the
    features the front end aims for that it tracks), the camera-IMU time offset in use and the
    features tracked."""

    t_ns: int
    T_W_B: Pose
    v_W_B: FloatArray
    gyro_bias: FloatArray
    accel_bias: FloatArray
    cov_pose: FloatArray
    cov_v: FloatArray
    status: Status = "tracking"
    keyframe: bool = False
    reset_counter: int = 0
    quality: int = 100
    td_s: float = 0.0
    tracked: int = 0

    def odometry(self, *, source: str = "vio", quality: int | None = None) -> OdometrySample:
        """This state as an external-odometry sample (PX4's ``ODOMETRY``): the pose covariance
        carried to the world frame and PX4's (x, y, z, rx, ry, rz) order; ``quality`` replaces
        the state's own when given."""
        R = self.T_W_B.R_A_B.as_matrix()
        J = np.zeros((6, 6))
        J[0:3, 3:6] = R  # position error in W = R * body translation error
        J[3:6, 0:3] = R  # world-frame attitude error = R * body-frame one
        cov = J @ self.cov_pose @ J.T
        return OdometrySample(
            t_ns=self.t_ns,
            p_W_B=self.T_W_B.p_A_B,
            q_W_B_xyzw=self.T_W_B.R_A_B.as_quat(),
            v_W_B=self.v_W_B,
            cov_pose=0.5 * (cov + cov.T),
            cov_v=0.5 * (self.cov_v + self.cov_v.T),
            reset_counter=self.reset_counter,
            quality=self.quality if quality is None else quality,
            source=source,
        )


def _rows(a: object, cols: int | None, dtype: type, name: str) -> NDArray[np.generic]:
    arr: NDArray[np.generic] = np.asarray(a, dtype=dtype)
    want = (arr.shape[0], cols) if cols is not None else (arr.shape[0],) if arr.ndim else ()
    if arr.ndim == 0 or arr.shape != want:
        raise SampleError(
            f"KeyframeRecord.{name} must have shape (N{', ' + str(cols) if cols else ''}), got {arr.shape}"
        )
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise SampleError(f"KeyframeRecord.{name} must be finite")
    return arr


@dataclass(frozen=True, slots=True, kw_only=True)
class KeyframeStep:
    """A keyframe's position step from an earlier keyframe of the same odometry frame: the
    earlier one's ``index`` (``after``) and the step's covariance ``cov_W`` (3x3, m^2, in the
    odometry's world), from the two poses' joint marginal when the later one was solved. The
    difference of the two marginals is not it: a marginal also holds what the two poses share
    (the heading's error times their distance from the start, the scale's), which rises and
    falls as the vehicle flies away and back."""

    after: int
    cov_W: FloatArray

    def __post_init__(self) -> None:
        cov = np.asarray(self.cov_W, np.float64)
        if cov.shape != (3, 3) or not np.isfinite(cov).all():
            raise SampleError(f"KeyframeStep.cov_W must be a finite 3x3, got {cov.shape}")
        object.__setattr__(self, "cov_W", cov)


@dataclass(frozen=True, slots=True, kw_only=True)
class KeyframeRecord:
    """A keyframe an odometry has finished with: its number ``index`` (unique in the run), time,
    ``reset_counter`` (the odometry frame it is in), pose ``T_W_B`` and its ``cov_pose`` (body
    frame, GTSAM's order), the camera it was taken with and its ``image`` (the frame, whose
    pixels load on demand; None if the odometry was given bare pixels without a source).

    Its keypoints: ``ids`` (track ids, one per keypoint), ``uv_px`` (distorted pixels), ``xy``
    (undistorted normalised coordinates) and ``descriptors`` (``(N, 32)`` uint8 ORB/BRIEF, or
    None when the odometry describes none; a keypoint it could not describe has a row of
    zeros and ``described`` False). The landmarks it sees: ``landmark_ids`` (track ids, a subset
    of ``ids``) and their positions ``landmarks_W`` in the odometry's world. ``T_B_C``: the
    camera's extrinsic as the odometry had it (refined online, it differs from the rig's
    stated one; None: the rig's). ``step``: its position step's covariance from the keyframe
    before (:class:`KeyframeStep`; None when the odometry gives none)."""

    index: int
    t_ns: int
    reset_counter: int
    T_W_B: Pose
    cov_pose: FloatArray
    camera: str
    image: ImageFrame | None
    ids: IntArray
    uv_px: FloatArray
    xy: FloatArray
    descriptors: NDArray[np.uint8] | None = None
    described: NDArray[np.bool_] | None = None
    landmark_ids: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    landmarks_W: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    T_B_C: Pose | None = None
    step: KeyframeStep | None = None

    def __post_init__(self) -> None:
        ids = _rows(self.ids, None, np.int64, "ids")
        object.__setattr__(self, "ids", ids)
        for name in ("uv_px", "xy"):
            arr = _rows(getattr(self, name), 2, np.float64, name)
            if len(arr) != len(ids):
                raise SampleError(f"KeyframeRecord.{name} needs one row per id ({len(ids)})")
            object.__setattr__(self, name, arr)
        if self.descriptors is not None:
            d = np.asarray(self.descriptors)
            if d.dtype != np.uint8 or d.ndim != 2 or len(d) != len(ids):
                raise SampleError(
                    "KeyframeRecord.descriptors must be (N, bytes) uint8, a row per id"
                )
        lid = _rows(self.landmark_ids, None, np.int64, "landmark_ids")
        lw = _rows(self.landmarks_W, 3, np.float64, "landmarks_W")
        if len(lid) != len(lw):
            raise SampleError("KeyframeRecord.landmarks_W needs one row per landmark id")
        object.__setattr__(self, "landmark_ids", lid)
        object.__setattr__(self, "landmarks_W", lw)
        cov = np.asarray(self.cov_pose, np.float64)
        if cov.shape != (6, 6) or not np.isfinite(cov).all():
            raise SampleError(f"KeyframeRecord.cov_pose must be a finite 6x6, got {cov.shape}")


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometryEvent:
    """Something a run must report: the initialisation (``detail`` says how), a failure (too
    few tracks, a jump in bias or velocity, an implausible motion) and the re-initialisation
    after it, a time-offset estimate settling, stereo frames used as mono."""

    t_ns: int
    kind: EventKind
    detail: str


@dataclass(frozen=True, slots=True, kw_only=True)
class StageTiming:
    """Wall time per stage of the pipeline (``track``, ``keyframe``, ``preintegrate``,
    ``initialize``, ``optimize``...): total seconds and calls, in order."""

    stages: tuple[tuple[str, float, int], ...] = field(default=())

    def per_call_ms(self) -> dict[str, float]:
        return {name: 1e3 * s / max(n, 1) for name, s, n in self.stages}


class VisualOdometry(Protocol):
    """What a run, a closed loop or a loop closer drives: IMU samples and camera frames of any
    camera of the rig, in time order; a state back once initialised (IMU-rate propagation from
    an IMU sample, an optimised state from an image). Bad input is rejected and counted in
    ``rejected``, never raised."""

    @property
    def cameras(self) -> tuple[str, ...]: ...  # the rig's cameras it uses

    def push(self, sample: ImuSample | ImageFrame) -> OdometryState | None: ...

    # the keyframes finished since the last call, each once; ``final``: the window's too
    def keyframes(self, *, final: bool = False) -> Sequence[KeyframeRecord]: ...

    # the newest keyframe as it stands, provisional (``keyframes`` hands it out once final)
    def newest_keyframe(self) -> KeyframeRecord | None: ...

    @property
    def events(self) -> tuple[OdometryEvent, ...]: ...

    @property
    def last_features(self) -> FrameFeatures | None: ...

    @property
    def rejected(self) -> Mapping[str, int]: ...

    def timing(self) -> StageTiming: ...


@runtime_checkable
class RefinedTrajectory(Protocol):
    """An odometry that can give its past frames again through the map it refined since (a
    SLAM: each frame's pose relative to its reference keyframe, on that keyframe's final pose,
    as ORB-SLAM2's ``SaveTrajectoryTUM`` writes it). Not causal: what the field's papers
    evaluate for a SLAM; the causal estimate is each frame's state when it was pushed."""

    def final_trajectory(self) -> Trajectory: ...


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopConstraint:
    """A verified loop between two keyframes of one odometry (its keyframe numbers): the
    ``new`` one's body pose in the ``old`` one's, ``T_old_new``, and its 6x6 covariance
    ``cov`` in the module's convention (rx, ry, rz, x, y, z at ``new``, in its body frame).
    What it was measured from, where known: the old side's landmarks (``landmark_ids``, track ids
    as in :class:`KeyframeRecord`) and where the ``new`` keyframe's first camera saw each
    (``xy``, undistorted normalised coordinates): an odometry that keeps those landmarks can
    take the loop as their observations rather than as a relative pose."""

    old: int
    new: int
    T_old_new: Pose
    cov: FloatArray
    landmark_ids: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    xy: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))

    def __post_init__(self) -> None:
        c = np.asarray(self.cov, dtype=np.float64)
        if c.shape != (6, 6) or not np.all(np.isfinite(c)):
            raise SampleError(f"LoopConstraint: cov must be a finite 6x6 matrix, got {c.shape}")
        if np.any(np.linalg.eigvalsh(0.5 * (c + c.T)) <= 0.0):
            raise SampleError("LoopConstraint: cov must be positive definite")
        ids = np.asarray(self.landmark_ids, np.int64).reshape(-1)
        xy = np.asarray(self.xy, np.float64)
        if xy.shape != (len(ids), 2) or not np.all(np.isfinite(xy)):
            raise SampleError(
                f"LoopConstraint: xy must be finite, one row of 2 per landmark id ({len(ids)}), "
                f"got {xy.shape}"
            )
        object.__setattr__(self, "landmark_ids", ids)
        object.__setattr__(self, "xy", xy)


@runtime_checkable
class LoopRefinedTrajectory(Protocol):
    """An odometry whose final trajectory a loop closer can refine: through the keyframe
    poses its pose graph found (by the odometry's keyframe number), or, when the odometry
    smooths its whole run at the end, with the loops as factors of that smoothing."""

    def final_trajectory_with(
        self, loops: Sequence[LoopConstraint], keyframe_poses: Mapping[int, Pose]
    ) -> Trajectory: ...

    def final_keyframe_poses(self) -> Mapping[int, Pose]:
        """The keyframes' poses the last :meth:`final_trajectory_with` smoothed (by keyframe
        number; none when it smooths nothing), for a map to keep."""
        ...


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraCalibration:
    """A camera of the rig as an odometry has it: the extrinsic ``T_B_C`` (the camera in the
    body frame), the pinhole intrinsics in pixels (the lens's distortion as stated) and the
    camera-IMU time offset (s; a frame's stamp plus it is its time on the IMU's clock), with
    their standard deviations where it estimates them."""

    camera: str
    T_B_C: Pose
    fx: float
    fy: float
    cx: float
    cy: float
    time_offset_s: float
    #: the estimate's standard deviations where the odometry has them (None: not estimated):
    #: the extrinsic's rotation (deg) and translation (m) about and along the camera's axes
    #: (a perturbation on the right of ``T_B_C``), ``fx, fy, cx, cy`` (px), the offset (s)
    sigma_rotation_deg: tuple[float, float, float] | None = None
    sigma_translation_m: tuple[float, float, float] | None = None
    sigma_intrinsics_px: tuple[float, float, float, float] | None = None
    sigma_time_offset_s: float | None = None


@runtime_checkable
class OnlineCalibration(Protocol):
    """An odometry that refines its rig's calibration while it runs (VINS-Mono's
    ``estimate_extrinsic``, OpenVINS's online intrinsics and time offset): each camera it uses
    as it has it now (the stated calibration until refined)."""

    def calibration(self) -> tuple[CameraCalibration, ...]: ...
