"""The SLAM behind the odometry interface (:class:`quadnav.odometry.VisualOdometry`), so that the
runner that drives the VIO (``experiments/odometry_run.py``: run folder, trajectory, metrics,
report) drives it too.

A stereo rig's two cameras are rectified once (:class:`~quadnav.vision.stereo.StereoRectifier`);
a frame of the first camera waits for its partner of the same time, and the pair is rectified,
made into a :class:`~quadnav.slam.frame.Frame` and tracked. The odometry's world is the
vehicle's frame (the rig's ``T_V_B``) at the first tracked frame: a SLAM without an IMU knows no
gravity, so its world is level only if the vehicle started level (on the ground, as usual);
otherwise evaluate it after an SE(3) alignment. The body's pose is the rectified left camera's
through the rig's extrinsic. IMU samples are not used. Frames of
another camera, a partner that never comes (the next left frame comes first), an image that
cannot be read: rejected and counted. A loss is an event (``failure``) and the states stop.
Until the SLAM publishes its keyframes for a loop closer, ``keyframes()`` hands out none.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.errors import QuadnavError, SlamError
from quadnav.geometry.rotations import Pose
from quadnav.messages import ImageFrame, ImuSample
from quadnav.odometry import (
    FrameFeatures,
    KeyframeRecord,
    OdometryEvent,
    OdometryState,
    StageTiming,
)
from quadnav.rig import Rig
from quadnav.slam.config import SlamConfig
from quadnav.slam.frame import StereoCamera, stereo_frame
from quadnav.slam.tracking import StereoTracker
from quadnav.vision.orb import OrbExtractor

__all__ = ["SlamOdometry"]

#: the pose covariance a state is given (no marginals yet): 1 cm and 0.5 degree, body frame
_COV_POSE = np.diag([np.radians(0.5) ** 2] * 3 + [0.01**2] * 3)


class SlamOdometry:
    """Stereo SLAM as an odometry (see the module) on a stereo ``rig``."""

    def __init__(self, rig: Rig, config: SlamConfig | None = None) -> None:
        from quadnav.vision.stereo import StereoRectifier

        if not rig.stereo:
            raise SlamError(f"rig {rig.name!r} has one camera: the stereo SLAM needs two")
        self.config = config or SlamConfig()
        self.rectifier = StereoRectifier(rig)
        K = self.rectifier.K
        self.camera = StereoCamera(fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]),
                                   cy=float(K[1, 2]), baseline_m=self.rectifier.baseline_m)  # fmt: skip
        left = rig.cameras[0]
        # the rectified left camera in the body: the original one turned by R0 (x_rect = R0 x)
        self.T_B_C = left.T_B_C @ Pose(Rotation.from_matrix(self.rectifier.R0.T), np.zeros(3))
        self._names = (left.name, rig.cameras[1].name)
        self.T_V_B = rig.T_V_B
        self.extractor = OrbExtractor(self.config.orb)
        self.tracker = StereoTracker(self.config)
        self._pending: ImageFrame | None = None
        self._T_W_C0: Pose | None = None  # (the first tracked camera pose: the world's origin)
        self._last: OdometryState | None = None
        self._events: list[OdometryEvent] = []
        self._rejected: Counter[str] = Counter()
        self._seconds: dict[str, float] = {}
        self._calls: Counter[str] = Counter()

    # -- the odometry interface -------------------------------------------------------------
    @property
    def cameras(self) -> tuple[str, ...]:
        return self._names

    def push(self, sample: ImuSample | ImageFrame) -> OdometryState | None:
        if isinstance(sample, ImuSample):
            return None
        if sample.camera == self._names[0]:
            if self._pending is not None:
                self._rejected["unpaired_frames"] += 1
            self._pending = sample
            return None
        if sample.camera != self._names[1]:
            self._rejected["other_camera"] += 1
            return None
        left, self._pending = self._pending, None
        if left is None or left.t_ns != sample.t_ns:
            self._rejected["unpaired_frames"] += 1
            return None
        return self._pair(left, sample)

    def keyframes(self, *, final: bool = False) -> Sequence[KeyframeRecord]:
        del final
        return []

    def newest_keyframe(self) -> KeyframeRecord | None:
        return None

    @property
    def events(self) -> tuple[OdometryEvent, ...]:
        return tuple(self._events)

    @property
    def last_features(self) -> FrameFeatures | None:
        return None

    @property
    def rejected(self) -> Mapping[str, int]:
        return dict(self._rejected)

    def timing(self) -> StageTiming:
        return StageTiming(stages=tuple((k, self._seconds[k], self._calls[k]) for k in self._calls))

    # -- a pair -------------------------------------------------------------------------------
    def _pair(self, left: ImageFrame, right: ImageFrame) -> OdometryState | None:
        t0 = time.perf_counter()
        try:
            L, R = self.rectifier.rectify(left.image(), right.image())
            frame = stereo_frame(left.t_ns, L, R, self.camera, self.extractor, self.config)
        except QuadnavError:
            self._rejected["unreadable_images"] += 1
            return None
        t1 = time.perf_counter()
        before = self.tracker.state
        result = self.tracker.track(frame)
        self._time("frame", t1 - t0)
        self._time("track", time.perf_counter() - t1)
        if result.state == "lost" and before != "lost":
            self._events.append(
                OdometryEvent(t_ns=left.t_ns, kind="failure", detail="tracking lost")
            )
        if result.T_W_C is None:
            return None
        if self._T_W_C0 is None:
            self._T_W_C0 = result.T_W_C
            self._events.append(OdometryEvent(t_ns=left.t_ns, kind="initialized", detail="stereo"))
        # the body in the world of the vehicle's first pose: T_V_B T_B0_Bk
        T_B0_Bk = self.T_B_C @ self._T_W_C0.inverse() @ result.T_W_C @ self.T_B_C.inverse()
        T_W_B = self.T_V_B @ T_B0_Bk
        v = np.zeros(3)
        if self._last is not None and left.t_ns > self._last.t_ns:
            v = (T_W_B.p_A_B - self._last.T_W_B.p_A_B) / ((left.t_ns - self._last.t_ns) * 1e-9)
        self._last = OdometryState(
            t_ns=left.t_ns, T_W_B=T_W_B, v_W_B=v, gyro_bias=np.zeros(3), accel_bias=np.zeros(3),
            cov_pose=_COV_POSE, cov_v=np.eye(3) * 0.05**2, keyframe=result.keyframe,
            tracked=result.inliers,
            quality=int(min(100, 100 * result.inliers / max(self.config.orb.n_features / 4, 1))),
        )  # fmt: skip
        return self._last

    def _time(self, stage: str, seconds: float) -> None:
        self._seconds[stage] = self._seconds.get(stage, 0.0) + seconds
        self._calls[stage] += 1
