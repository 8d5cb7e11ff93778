"""A stand-in for the VIO estimator that satisfies :class:`quadnav.odometry.VisualOdometry`: the
ground truth moved into a VIO world (yawed and shifted), with Gaussian pose errors drawn from
the covariance it reports, initialised after a delay, failing and re-initialising on a
schedule, and features moving across the image. What a run makes of it is known in advance,
which tests the run's plumbing, not an estimator."""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.geometry import Pose
from quadnav.geometry.trajectory import Trajectory
from quadnav.messages import ImageFrame, ImuSample
from quadnav.odometry import (
    FrameFeatures,
    KeyframeRecord,
    OdometryEvent,
    OdometryState,
    StageTiming,
)

#: The double's pose noise: 2 mrad, 3 cm per axis (body frame (rot, trans), GTSAM's order).
SIGMAS = np.array([0.002] * 3 + [0.03] * 3)


class TruthPlusNoise:
    def __init__(
        self,
        truth: Trajectory,
        *,
        seed: int = 0,
        init_after_s: float = 0.5,
        fail_at_s: float | None = None,
        reinit_after_s: float = 0.3,
        interrupt_at_frame: int | None = None,
        recover_at_s: float | None = None,
    ) -> None:
        self.truth = truth
        self.rng = np.random.default_rng(seed)
        self.t0: int | None = None
        self.init_after_s = init_after_s
        self.fail_at_s = fail_at_s
        self.reinit_after_s = reinit_after_s
        self.interrupt_at_frame = interrupt_at_frame
        self.recover_at_s = recover_at_s  # a "recovered" event then (the output goes on)
        self._events: list[OdometryEvent] = []
        self._features: FrameFeatures | None = None
        self.frames = 0
        self.imu = 0
        self.reset = 0
        self.track_s = 0.0
        self.world = (Rotation.from_euler("z", 50.0, degrees=True), np.array([1.0, -2.0, 0.3]))

    cameras = ("cam0",)

    @property
    def rejected(self) -> dict[str, int]:
        return {}

    def push(self, sample: ImuSample | ImageFrame) -> OdometryState | None:
        if isinstance(sample, ImageFrame):
            return self._image(sample.t_ns, sample.image())
        self.imu += 1
        return None

    def keyframes(self, *, final: bool = False) -> list[KeyframeRecord]:
        return []

    def _phase(self, t_s: float) -> str:
        if t_s < self.init_after_s:
            return "waiting"
        if (
            self.fail_at_s is not None
            and self.fail_at_s <= t_s < self.fail_at_s + self.reinit_after_s
        ):
            return "failed"
        return "tracking"

    def _event(self, t_ns: int, kind: str, detail: str) -> None:
        self._events.append(OdometryEvent(t_ns=t_ns, kind=kind, detail=detail))  # type: ignore[arg-type]

    def _image(self, t_ns: int, image: NDArray[np.uint8]) -> OdometryState | None:
        if self.interrupt_at_frame is not None and self.frames == self.interrupt_at_frame:
            raise KeyboardInterrupt
        tic = time.perf_counter()
        self.frames += 1
        self.t0 = t_ns if self.t0 is None else self.t0
        t_s = (t_ns - self.t0) * 1e-9
        ids = np.arange(self.frames, self.frames + 40, dtype=np.int64) // 4  # tracks of 4 frames
        uv = np.column_stack([(ids * 37) % image.shape[1], (ids * 53) % image.shape[0]]).astype(
            float
        )
        self._features = FrameFeatures(
            t_ns=t_ns, ids=ids, uv_px=uv, xy=uv / 400.0, velocity_xy_s=np.zeros_like(uv)
        )
        self.track_s += time.perf_counter() - tic
        phase = self._phase(t_s)
        kinds = [e.kind for e in self._events]
        if phase == "waiting":
            return None
        if phase == "failed":
            if kinds[-1:] != ["failure"]:
                self._event(t_ns, "failure", "too few tracks (scheduled)")
            return None
        if not kinds:
            self._event(t_ns, "initialized", "static (scheduled)")
        elif kinds[-1] == "failure":
            self.reset += 1
            self._event(t_ns, "reinitialized", "static (scheduled)")
        if self.recover_at_s is not None and t_s >= self.recover_at_s and "recovered" not in kinds:
            self._event(t_ns, "recovered", "QR fallback (scheduled)")
        return self._state(t_ns)

    def _state(self, t_ns: int) -> OdometryState:
        truth = self.truth.interpolate(np.array([t_ns]))
        xi = self.rng.normal(size=6) * SIGMAS
        R_true = truth.R_W_B[0]
        R_est = R_true * Rotation.from_rotvec(-xi[:3])  # T_true = T_est Exp(xi), to first order
        p_est = truth.p_W_B[0] - R_est.apply(xi[3:])
        Rw, tw = self.world
        pose = Pose.from_quat_xyzw((Rw * R_est).as_quat(), Rw.apply(p_est) + tw)
        return OdometryState(
            t_ns=t_ns,
            T_W_B=pose,
            v_W_B=np.zeros(3),
            gyro_bias=np.zeros(3),
            accel_bias=np.zeros(3),
            cov_pose=np.diag(SIGMAS**2),
            cov_v=np.eye(3) * 1e-4,
            reset_counter=self.reset,
            tracked=40,
        )

    @property
    def events(self) -> tuple[OdometryEvent, ...]:
        return tuple(self._events)

    @property
    def last_features(self) -> FrameFeatures | None:
        return self._features

    def timing(self) -> StageTiming:
        return StageTiming(
            stages=(
                ("track", self.track_s, self.frames),
                ("optimize", 0.001 * self.frames, self.frames),
            )
        )
