"""A synthetic visual-inertial scene for the VIO's tests: a smooth motion (position and yaw
sweeping, a gentle roll and pitch) in a room whose walls carry known landmarks, the IMU it
makes (``sim.motion.synthesize_imu``, EuRoC's noise) and the normalised observations of the
landmarks in a forward camera (thesis 003's), with pixel noise."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.messages import ImuSample
from quadnav.odometry import FrameFeatures
from quadnav.rig import ImuNoiseModel, Rig, rig_named
from quadnav.sim.motion import SplineMotion, synthesize_imu

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Scene:
    rig: Rig
    motion: SplineMotion
    imu: list[ImuSample]
    landmarks_W: FloatArray
    frames: list[FrameFeatures]
    true_gyro_bias: FloatArray
    true_accel_bias: FloatArray


def _motion(duration_s: float) -> SplineMotion:
    t = np.arange(0.0, duration_s + 2.0, 0.01) - 1.0
    s = np.clip(t, 0.0, None)
    p = np.column_stack(
        [0.8 * np.sin(0.9 * s), 0.6 * (1 - np.cos(0.7 * s)), 1.2 + 0.15 * np.sin(1.3 * s)]
    )
    eul = np.column_stack([0.05 * np.sin(1.1 * s), 0.04 * np.sin(0.8 * s), 0.5 * np.sin(0.5 * s)])
    q = Rotation.from_euler("xyz", eul).as_quat()
    t_ns = np.rint((t + 1.0) * 1e9).astype(np.int64)
    return SplineMotion.from_arrays(t_ns, p, q, knot_spacing_s=0.1, trim_s=0.5)


def _landmarks(rng: np.random.Generator, n: int = 600) -> FloatArray:
    """Points on the walls, floor and ceiling of a 10 x 10 x 3 m room."""
    pts = rng.uniform([-5.0, -5.0, 0.0], [5.0, 5.0, 3.0], size=(n, 3))
    face = rng.integers(0, 4, size=n)
    pts[face == 0, 0] = 5.0
    pts[face == 1, 0] = -5.0
    pts[face == 2, 1] = 5.0
    pts[face == 3, 1] = -5.0
    return pts


def observe(
    rig: Rig,
    T_W_B: FloatArray,
    landmarks_W: FloatArray,
    t_ns: int,
    sigma_px: float,
    rng: np.random.Generator,
) -> FrameFeatures:
    """The landmarks a camera at body pose ``T_W_B`` (4x4) sees, as a front end gives them."""
    cam = rig.cameras[0]
    T_W_C = T_W_B @ cam.T_B_C.matrix()
    T_C_W = np.linalg.inv(T_W_C)
    p_C = landmarks_W @ T_C_W[:3, :3].T + T_C_W[:3, 3]
    K = cam.camera.K
    front = p_C[:, 2] > 0.2
    xy = p_C[:, :2] / np.where(front, p_C[:, 2], 1.0)[:, None]
    uv = xy * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    inside = front & (uv[:, 0] > 0) & (uv[:, 0] < cam.camera.width) & (uv[:, 1] > 0)
    inside &= uv[:, 1] < cam.camera.height
    ids = np.flatnonzero(inside).astype(np.int64)
    noisy = xy[ids] + rng.normal(0.0, sigma_px / K[0, 0], size=(len(ids), 2))
    return FrameFeatures(
        t_ns=int(t_ns),
        ids=ids,
        uv_px=noisy * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]],
        xy=noisy,
        velocity_xy_s=np.zeros_like(noisy),
    )


def make_scene(
    seed: int, *, duration_s: float = 6.0, rate_hz: float = 10.0, sigma_px: float = 0.7
) -> Scene:
    rng = np.random.default_rng(seed)
    rig = rig_named("thesis003_sim")
    motion = _motion(duration_s)
    noise = ImuNoiseModel.euroc_adis16448()
    series = synthesize_imu(motion, rate_hz=200.0, noise=noise, rng=rng)
    landmarks = _landmarks(rng)
    t_frames = motion.t_start_ns + np.arange(0, int(duration_s * rate_hz)) * int(1e9 / rate_hz)
    p, q = motion.pose(t_frames)
    frames = []
    for k, t in enumerate(t_frames):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(q[k]).as_matrix()
        T[:3, 3] = p[k]
        frames.append(observe(rig, T, landmarks, int(t), sigma_px, rng))
    return Scene(
        rig=rig,
        motion=motion,
        imu=list(series.samples()),
        landmarks_W=landmarks,
        frames=frames,
        true_gyro_bias=series.gyro_bias_rad_s[0],
        true_accel_bias=series.accel_bias_m_s2[0],
    )
