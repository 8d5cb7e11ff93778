"""A simulated odometry that drifts, in a room whose walls carry points with descriptors: what
the loop closure tests drive."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.messages import ImageFrame, ImuSample
from quadnav.odometry import (
    FrameFeatures,
    KeyframeRecord,
    KeyframeStep,
    OdometryEvent,
    OdometryState,
    StageTiming,
)
from quadnav.rig import CameraSpec

FOCAL_PX = 460.0
T_B_C = Pose(Rotation.from_matrix([[0, 0, 1], [-1, 0, 0], [0, -1, 0]]), np.array([0.1, 0, 0]))
PER_LAP = 40
CAMERA = CameraSpec(
    name="cam0",
    camera=PinholeCamera(K=np.array([[FOCAL_PX, 0, 376], [0, FOCAL_PX, 240], [0, 0, 1.0]]),
                         dist=np.zeros(4), width=752, height=480),
    T_B_C=T_B_C, rate_hz=5.0,
)  # fmt: skip


def _flip(desc: np.ndarray, n_bits: int, rng: np.random.Generator) -> np.ndarray:
    bits = np.unpackbits(desc, axis=1)
    for row in bits:
        row[rng.choice(256, n_bits, replace=False)] ^= 1
    return np.packbits(bits, axis=1)


class DriftingOdometry:
    """Two laps of a circle in a room whose walls carry points with descriptors; the odometry's
    poses and its landmarks drift by a random walk in position and yaw. One keyframe a frame."""

    def __init__(
        self, seed: int, laps: int = 2, *, another_room: bool = False, shift_m: float = 0.0,
        drift_seed: int | None = None, frame: Pose | None = None, jump_at: int = -1,
        jump: Pose | None = None, reset_at: int = -1, swing_m2: float = 0.0,
        steps: bool = False, steps_told: float = 1.0,
    ) -> None:  # fmt: skip
        """``drift_seed``: another drift in the same room (a second flight); ``frame``: the
        odometry's frame in the world; ``jump`` added to the drift at keyframe ``jump_at`` (a
        dead reckoning through a camera blackout); from keyframe ``reset_at`` on, the odometry
        has re-initialised (``reset_counter`` 1) in a new frame of its own, whose origin is the
        body there, its yaw the body's. ``swing_m2``: the covariance also holds an error the
        poses share (a heading's at the start, as a VIO's marginal does), of that variance per
        square metre from the start: it rises and falls over a lap. ``steps``: the records
        carry each step's own covariance (:class:`KeyframeStep`), which that shared error does
        not touch, ``steps_told`` times the true one."""
        rng = np.random.default_rng(seed)
        drift_rng = rng if drift_seed is None else np.random.default_rng(drift_seed)
        self.rng = rng
        n = 1500
        ang, z = rng.uniform(0, 2 * np.pi, n), rng.uniform(-1.0, 2.5, n)
        r = rng.uniform(4.5, 6.0, n)
        self.X = np.column_stack([r * np.cos(ang), r * np.sin(ang), z])
        self.desc = rng.integers(0, 256, (n, 32), dtype=np.uint8)
        #: the later laps in a room of the same shape whose walls look otherwise
        self.desc_later = (
            rng.integers(0, 256, (n, 32), dtype=np.uint8) if another_room else self.desc
        )
        #: the later laps in a copy of the room ``shift_m`` along x that looks the same
        self.shift = np.array([shift_m, 0.0, 0.0])
        self.truth: list[Pose] = []
        self.odo: list[Pose] = []
        D = frame or Pose.identity()
        for k in range(laps * PER_LAP):
            a = 2 * np.pi * k / PER_LAP
            T = Pose(
                Rotation.from_euler("z", a + np.pi / 2),
                np.array([np.cos(a), np.sin(a), 0.2 * (k >= PER_LAP)]),
            )
            if k >= PER_LAP:
                T = Pose(T.R_A_B, T.p_A_B + self.shift)
            step = Pose(
                Rotation.from_euler("z", drift_rng.normal(0, 0.006)), drift_rng.normal(0, 0.015, 3)
            )
            D = step @ D if k else D
            if k == jump_at and jump is not None:
                D = jump @ D
            if k == reset_at:  # the new frame: the body's pose there, its yaw only
                yaw = float(T.R_A_B.as_euler("zyx")[0])
                D = Pose(Rotation.from_euler("z", yaw), T.p_A_B).inverse()
            self.truth.append(T)
            self.odo.append(D @ T)
        self.reset_at = reset_at
        #: an honest covariance, as the VIO's: the random walk's variance since the odometry's
        #: frame began (its yaw's at a metre from the origin included), the jump's besides
        walk = 0.015**2 + 0.006**2
        self.var_m2 = [
            (k - max(reset_at, 0) if 0 <= reset_at <= k else k) * walk
            + (0.3**2 if 0 <= jump_at <= k and jump is not None and not 0 <= reset_at <= k else 0.0)
            for k in range(laps * PER_LAP)
        ]  # fmt: skip
        self.walk_m2 = walk
        self.swing_m2 = swing_m2
        self.steps = steps
        self.steps_told = steps_told
        self._pending: list[KeyframeRecord] = []
        self._newest: KeyframeRecord | None = None

    def cov_pose(self, k: int) -> np.ndarray:
        """The pose covariance at keyframe ``k`` (rotation, then position)."""
        far = float(np.sum((self.truth[k].p_A_B - self.truth[0].p_A_B) ** 2))
        return np.diag([1e-4] * 3 + [1e-4 + self.var_m2[k] + self.swing_m2 * far] * 3)

    def record(self, k: int) -> KeyframeRecord:
        T, T_odo = self.truth[k], self.odo[k]
        D = T_odo @ T.inverse()
        X_seen = self.X + (self.shift if k >= PER_LAP else 0.0)
        Xc = (T @ T_B_C).inverse() @ X_seen
        vis = np.flatnonzero(Xc[:, 2] > 0.5)
        xy = Xc[vis, :2] / Xc[vis, 2:]
        inside = np.abs(xy).max(axis=1) < 0.7
        vis, xy = (
            vis[inside],
            xy[inside] + self.rng.normal(0, 0.7 / FOCAL_PX, (int(inside.sum()), 2)),
        )
        return KeyframeRecord(
            index=k, t_ns=k * 200_000_000, reset_counter=self.reset_counter(k), T_W_B=T_odo, cov_pose=self.cov_pose(k),
            camera="cam0", image=None, ids=vis.astype(np.int64), uv_px=xy * FOCAL_PX + 376, xy=xy,
            descriptors=_flip((self.desc if k < PER_LAP else self.desc_later)[vis], 4, self.rng), described=np.ones(len(vis), bool),
            landmark_ids=vis.astype(np.int64), landmarks_W=D @ X_seen[vis],
            step=KeyframeStep(after=k - 1, cov_W=np.eye(3) * self.walk_m2 * self.steps_told) if self.steps and k else None,
        )  # fmt: skip

    def reset_counter(self, k: int) -> int:
        return int(0 <= self.reset_at <= k)

    # -- the odometry interface ------------------------------------------------------------
    cameras = ("cam0",)
    events: tuple[OdometryEvent, ...] = ()
    last_features: FrameFeatures | None = None
    rejected: Mapping[str, int] = {}

    def push(self, sample: ImuSample | ImageFrame) -> OdometryState | None:
        k = sample.t_ns // 200_000_000  # a frame (and keyframe) each 0.2 s
        if k >= len(self.truth):
            return None
        self._newest = self.record(k)
        self._pending.append(self._newest)
        return OdometryState(
            t_ns=k * 200_000_000, T_W_B=self.odo[k], v_W_B=np.zeros(3), gyro_bias=np.zeros(3),
            accel_bias=np.zeros(3), cov_pose=self.cov_pose(k), cov_v=np.eye(3) * 1e-4,
            reset_counter=self.reset_counter(k),
        )  # fmt: skip

    def keyframes(self, *, final: bool = False) -> Sequence[KeyframeRecord]:
        out, self._pending = self._pending, []
        return out

    def newest_keyframe(self) -> KeyframeRecord | None:
        return self._newest

    def timing(self) -> StageTiming:
        return StageTiming()
