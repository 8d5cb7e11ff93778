"""What the visual-inertial odometry gives out, and what its parts hand one another.

The VIO's world frame ``W`` is gravity-aligned (z up) with the yaw and origin of its
initialisation; its body ``B`` is the rig's body (the IMU's frame for EuRoC's rig). Poses are
``geometry.Pose`` (``T_W_B``). Covariances of a pose follow GTSAM's ``Pose3`` convention:
6x6 over (rx, ry, rz, x, y, z), a perturbation on the right, ``T = T_hat Exp(xi)``, i.e. in the
body frame. :meth:`VioState.odometry` turns that into PX4's world-frame order for the EKF.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal, Protocol

import gtsam
import numpy as np
from numpy.typing import NDArray

from quadnav.geometry import Pose
from quadnav.messages import ImuSample, OdometrySample

__all__ = [
    "FrameFeatures",
    "InitResult",
    "InitWindow",
    "StageTiming",
    "VioEvent",
    "VioState",
    "VisualOdometry",
]

FloatArray = NDArray[np.float64]

Status = Literal["tracking", "propagated"]
EventKind = Literal["initialized", "failure", "reinitialized", "td"]


@dataclass(frozen=True, slots=True, kw_only=True)
class FrameFeatures:
    """One camera frame's tracked features: ``ids`` (stable per track), ``uv_px`` (distorted
    pixels, as tracked), ``xy`` (undistorted normalised image coordinates, z = 1) and
    ``velocity_xy_s`` (their image velocity in normalised coordinates per second, for the time
    offset), with ``keyframe`` the front end's decision and ``parallax_px`` its reason."""

    t_ns: int
    ids: NDArray[np.int64]
    uv_px: FloatArray
    xy: FloatArray
    velocity_xy_s: FloatArray
    keyframe: bool = False
    parallax_px: float = 0.0


@dataclass(frozen=True, slots=True, kw_only=True)
class VioState:
    """The estimate at ``t_ns``: the pose and velocity of the body in the VIO's world, the IMU
    biases, the covariances (``cov_pose`` GTSAM's 6x6 (rot, trans) in the body frame;
    ``cov_v`` 3x3 world), ``status`` (``tracking`` after an optimisation at a camera frame,
    ``propagated`` by the IMU between frames), ``reset_counter`` (bumped at each
    re-initialisation), the camera-IMU time offset in use and the features tracked."""

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
    td_s: float = 0.0
    tracked: int = 0

    def odometry(self, *, source: str = "vio", quality: int = 100) -> OdometrySample:
        """This state as an external-odometry sample (PX4's ``ODOMETRY``): the pose covariance
        carried to the world frame and PX4's (x, y, z, rx, ry, rz) order."""
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
            quality=quality,
            source=source,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class VioEvent:
    """Something the run must report: the initialisation (``detail`` says static or visual),
    a failure (too few tracks, a jump in bias or velocity, an implausible motion) and the
    re-initialisation after it, a time-offset estimate settling."""

    t_ns: int
    kind: EventKind
    detail: str


@dataclass(frozen=True, slots=True, kw_only=True)
class StageTiming:
    """Wall time per stage of the pipeline (``track``, ``keyframe``, ``preintegrate``,
    ``initialize``, ``optimize``, ``marginalize``...): total seconds and calls, in order."""

    stages: tuple[tuple[str, float, int], ...] = field(default=())

    def per_call_ms(self) -> dict[str, float]:
        return {name: 1e3 * s / max(n, 1) for name, s, n in self.stages}


@dataclass(frozen=True, slots=True, kw_only=True)
class InitWindow:
    """What a visual-inertial initialisation works on (thesis 003 §3.2): the window's frames in
    time order with their features, the IMU preintegrated between consecutive frames (with zero
    bias; ``len(frames) - 1`` of them), the camera's mount ``T_B_C`` and gravity's magnitude."""

    frames: tuple[FrameFeatures, ...]
    preintegrations: tuple[gtsam.PreintegratedCombinedMeasurements, ...]
    T_B_C: Pose
    g_norm: float


@dataclass(frozen=True, slots=True, kw_only=True)
class InitResult:
    """A metric, gravity-aligned start: per window frame ``T_W_B`` and ``v_W_B`` (W: z up, the
    yaw of the first frame's body), the gyro bias, the metric scale of the vision-only
    structure, gravity as the alignment found it (in the first camera's frame, before it was
    rotated onto -z), the landmarks triangulated (id -> point in W) and ``detail`` (how it went,
    for the run's events)."""

    T_W_B: tuple[Pose, ...]
    v_W_B: FloatArray
    gyro_bias: FloatArray
    scale: float
    gravity_C0: FloatArray
    landmarks_W: Mapping[int, FloatArray]
    detail: str


class VisualOdometry(Protocol):
    """What a run feeds and reads: IMU samples and camera images in time order; a state back
    once initialised (IMU-rate propagation from ``push_imu``, an optimised state from
    ``push_image``)."""

    def push_imu(self, sample: ImuSample) -> VioState | None: ...

    def push_image(self, t_ns: int, image: NDArray[np.uint8]) -> VioState | None: ...

    @property
    def events(self) -> tuple[VioEvent, ...]: ...

    @property
    def last_features(self) -> FrameFeatures | None: ...

    def timing(self) -> StageTiming: ...
