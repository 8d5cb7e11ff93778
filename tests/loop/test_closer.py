"""Loop closure over an odometry that drifts: a revisited place is recognised, verified and
closed, and the corrected keyframes are far nearer the truth than the odometry's."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.loop import LoopClosure, LoopConfig
from quadnav.messages import ImageFrame, ImuSample
from quadnav.odometry import (
    FrameFeatures,
    KeyframeRecord,
    OdometryEvent,
    OdometryState,
    StageTiming,
)
from quadnav.posegraph import PoseGraphConfig
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


class _DriftingOdometry:
    """Two laps of a circle in a room whose walls carry points with descriptors; the odometry's
    poses and its landmarks drift by a random walk in position and yaw. One keyframe a frame."""

    def __init__(
        self, seed: int, laps: int = 2, *, another_room: bool = False, shift_m: float = 0.0
    ) -> None:
        rng = np.random.default_rng(seed)
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
        D = Pose.identity()
        for k in range(laps * PER_LAP):
            a = 2 * np.pi * k / PER_LAP
            T = Pose(
                Rotation.from_euler("z", a + np.pi / 2),
                np.array([np.cos(a), np.sin(a), 0.2 * (k >= PER_LAP)]),
            )
            if k >= PER_LAP:
                T = Pose(T.R_A_B, T.p_A_B + self.shift)
            step = Pose(Rotation.from_euler("z", rng.normal(0, 0.006)), rng.normal(0, 0.015, 3))
            D = step @ D if k else D
            self.truth.append(T)
            self.odo.append(D @ T)
        self._k = 0
        self._pending: list[KeyframeRecord] = []

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
            index=k, t_ns=k * 200_000_000, reset_counter=0, T_W_B=T_odo, cov_pose=np.eye(6) * 1e-4,
            camera="cam0", image=None, ids=vis.astype(np.int64), uv_px=xy * FOCAL_PX + 376, xy=xy,
            descriptors=_flip((self.desc if k < PER_LAP else self.desc_later)[vis], 4, self.rng), described=np.ones(len(vis), bool),
            landmark_ids=vis.astype(np.int64), landmarks_W=D @ X_seen[vis],
        )  # fmt: skip

    # -- the odometry interface ------------------------------------------------------------
    cameras = ("cam0",)
    events: tuple[OdometryEvent, ...] = ()
    last_features: FrameFeatures | None = None
    rejected: Mapping[str, int] = {}

    def push(self, sample: ImuSample | ImageFrame) -> OdometryState | None:
        k = self._k
        self._k += 1
        if k >= len(self.truth):
            return None
        self._pending.append(self.record(k))
        return OdometryState(
            t_ns=k * 200_000_000, T_W_B=self.odo[k], v_W_B=np.zeros(3), gyro_bias=np.zeros(3),
            accel_bias=np.zeros(3), cov_pose=np.eye(6) * 1e-4, cov_v=np.eye(3) * 1e-4,
        )  # fmt: skip

    def keyframes(self, *, final: bool = False) -> Sequence[KeyframeRecord]:
        out, self._pending = self._pending, []
        return out

    def timing(self) -> StageTiming:
        return StageTiming()


#: the graph told the simulated odometry's own drift per keyframe
LOOP = LoopConfig(
    executor="thread",
    graph=PoseGraphConfig(sequential_sigma_m=0.015, sequential_sigma_yaw_rad=0.006,
                          loop_sigma_m=0.02, loop_sigma_yaw_rad=0.01),
)  # fmt: skip


def _frame(k: int) -> ImageFrame:
    return ImageFrame(t_ns=k * 200_000_000, camera="cam0", load=lambda: np.zeros((8, 8), np.uint8))


def _rmse(poses: Sequence[Pose], truth: Sequence[Pose]) -> float:
    d = np.array([p.p_A_B - t.p_A_B for p, t in zip(poses, truth, strict=True)])
    return float(np.sqrt((d**2).sum(axis=1).mean()))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_revisit_is_closed_and_the_keyframes_corrected(seed: int) -> None:
    odo = _DriftingOdometry(seed)
    loop = LoopClosure(odo, CAMERA, config=LOOP)
    try:
        outputs = []
        for k in range(len(odo.truth)):
            st = loop.push(_frame(k))
            assert st is not None
            outputs.append(st)
        records = loop.keyframes(final=True)
        assert len(records) == len(odo.truth)
        assert loop.stats.accepted >= 1, loop.stats
        assert not loop.stats.rejected, loop.stats  # every place recognised here is real
        kinds = [e.kind for e in loop.events]
        assert kinds.count("loop") == loop.stats.accepted
        poses = loop.graph.keyframe_poses()
        corrected = [poses[k] for k in range(len(odo.truth))]
        second = slice(PER_LAP, None)
        drifted = _rmse(odo.odo[second], odo.truth[second])
        fixed = _rmse(corrected[second], odo.truth[second])
        assert drifted > 0.1  # the odometry did drift
        # the first lap's own drift stays (no loop sees it); the second lap is drawn to it
        assert fixed < 0.7 * drifted, (fixed, drifted)
        # the output after the loop is corrected online too, with the reset counter raised
        # when the correction jumped
        late = outputs[-1]
        assert np.linalg.norm(late.T_W_B.p_A_B - odo.truth[-1].p_A_B) < np.linalg.norm(
            odo.odo[-1].p_A_B - odo.truth[-1].p_A_B
        )
    finally:
        loop.close()


@pytest.mark.parametrize("seed", [3, 4])
def test_a_lap_in_another_room_of_the_same_shape_closes_no_loop_to_the_first(seed: int) -> None:
    odo = _DriftingOdometry(seed, another_room=True)
    loop = LoopClosure(odo, CAMERA, config=LOOP)
    try:
        for k in range(len(odo.truth)):
            loop.push(_frame(k))
        loop.keyframes(final=True)
        assert loop.stats.keyframes == 2 * PER_LAP
        # the first lap meets its own start, the second its own: never one the other
        assert all((old < PER_LAP) == (new < PER_LAP) for old, new in loop.stats.loops), loop.stats
    finally:
        loop.close()


def test_the_local_map_joins_the_neighbours_landmarks_once_seen_from_the_old_camera() -> None:
    from quadnav.loop import local_map

    odo = _DriftingOdometry(5)
    recs = [odo.record(k) for k in range(8, 13)]
    old = recs[2]
    merged = local_map(old, recs, T_B_C)
    own = set(old.landmark_ids.tolist())
    union = set().union(*(r.landmark_ids.tolist() for r in recs))
    assert own < set(merged.landmark_ids.tolist()) <= union  # more than its own, each once
    assert len(set(merged.landmark_ids.tolist())) == len(merged.landmark_ids)
    assert merged.index == old.index and merged.T_W_B is old.T_W_B
    # each landmark at its projection into the old keyframe's camera
    c = (old.T_W_B @ T_B_C).inverse() @ merged.landmarks_W
    assert np.all(c[:, 2] > 0)
    assert np.allclose(merged.xy, c[:, :2] / c[:, 2:], atol=1e-12)
    # its own landmarks keep the old keyframe's own descriptors
    row = {i: k for k, i in enumerate(old.ids.tolist())}
    for k, j in enumerate(merged.landmark_ids.tolist()):
        if j in row:
            assert np.array_equal(merged.descriptors[k], old.descriptors[row[j]])
    # a keyframe of another odometry frame (after a reset) lends nothing
    other = dataclasses.replace(recs[0], reset_counter=1)
    alone = local_map(old, [other, old], T_B_C)
    assert set(alone.landmark_ids.tolist()) == own


def test_a_look_alike_room_metres_away_passes_the_geometry_but_not_the_drift_check() -> None:
    """Perceptual aliasing: the second lap flies an identical room 3 m along; the pictures and
    their geometry agree with the first lap's, but the loop would move the odometry by metres
    after a few of flight."""
    odo = _DriftingOdometry(6, shift_m=3.0)
    loop = LoopClosure(odo, CAMERA, config=LOOP)
    try:
        for k in range(len(odo.truth)):
            loop.push(_frame(k))
        loop.keyframes(final=True)
        across = [(o, n) for o, n in loop.stats.loops if (o < PER_LAP) != (n < PER_LAP)]
        assert not across, loop.stats
        assert loop.stats.rejected["drift"] >= 1, loop.stats
        assert any("drift" in e.detail for e in loop.events if e.kind == "loop_rejected")
    finally:
        loop.close()
