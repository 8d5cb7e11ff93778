"""A synthetic initialisation window for the initialisation's tests: a smooth analytic body path
(fitted by ``sim.motion.SplineMotion``, its IMU from ``synthesize_imu`` with the ADIS16448's
noise plus a chosen constant gyro bias), EuRoC's left camera mount, random 3-D points in the
room ahead, their projections with pixel noise as normalised coordinates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.geometry import Pose
from quadnav.messages import ImuSample
from quadnav.odometry import FrameFeatures
from quadnav.rig import ImuNoiseModel, euroc_mono
from quadnav.sim.motion import SplineMotion, synthesize_imu
from quadnav.units import GRAVITY_M_S2, NS_PER_S
from quadnav.vio.preintegration import imu_params, preintegrate
from quadnav.vio.types import InitWindow

FOCAL_PX = 458.0


@dataclass(frozen=True)
class Scene:
    window: InitWindow
    T_W_B: list[Pose]  # truth at the frames (the motion's world)
    v_W_B: np.ndarray
    gyro_bias: np.ndarray
    points_W: np.ndarray  # the true points, by feature id


def _path(t_s: np.ndarray, speed: float, spin: bool, cruise: bool) -> tuple[np.ndarray, np.ndarray]:
    """Positions and body attitudes: a lateral figure with height changes, accelerating, and a
    yaw/pitch/roll wobble (or, ``spin``, a pure rotation at a fixed point; ``cruise``, a
    constant velocity)."""
    if spin:
        p = np.zeros((len(t_s), 3))
    elif cruise:
        p = speed * np.outer(t_s, [0.5, 0.6, 0.1])
    else:
        p = speed * np.column_stack(
            [0.6 * np.sin(1.3 * t_s), 0.5 * t_s + 0.2 * np.sin(2.1 * t_s), 0.3 * np.sin(1.7 * t_s)]
        )
    eul = np.column_stack(
        [0.4 * np.sin(0.9 * t_s), 0.15 * np.sin(1.9 * t_s), 0.1 * np.cos(1.4 * t_s)]
    )
    return p, Rotation.from_euler("ZYX", eul).as_quat()


def make_scene(
    seed: int,
    *,
    n_frames: int = 10,
    frame_dt_s: float = 0.1,
    pixel_sigma: float = 0.7,
    gyro_bias: tuple[float, float, float] = (0.01, -0.01, 0.01),
    speed: float = 1.0,
    spin: bool = False,
    cruise: bool = False,
    n_points: int = 300,
    imu_rate_hz: float = 200.0,
    depth_m: tuple[float, float] = (2.0, 10.0),
    stereo_baseline_m: float | None = None,
) -> Scene:
    """``stereo_baseline_m``: a second camera that far to the right of the first (EuRoC's is
    0.11 m), seeing every point the first sees."""
    rng = np.random.default_rng(seed)
    cam = euroc_mono().cameras[0]
    T_B_C = cam.T_B_C
    t_s = np.arange(0.0, 3.0, 0.005)
    p, q = _path(t_s, speed, spin, cruise)
    motion = SplineMotion.from_arrays((t_s * NS_PER_S).astype(np.int64), p, q, knot_spacing_s=0.1)
    noise = ImuNoiseModel.euroc_adis16448()
    imu = synthesize_imu(motion, rate_hz=imu_rate_hz, noise=noise, rng=rng)
    bg = np.asarray(gyro_bias, dtype=np.float64)
    samples = [
        ImuSample(t_ns=s.t_ns, gyro_rad_s=s.gyro_rad_s + bg, accel_m_s2=s.accel_m_s2)
        for s in imu.samples()
    ]
    t0 = motion.t_start_ns + int(0.2 * NS_PER_S)
    stamps = [t0 + int(k * frame_dt_s * NS_PER_S) for k in range(n_frames)]
    pos, quat = motion.pose(np.asarray(stamps, dtype=np.int64))
    T_W_B = [Pose(Rotation.from_quat(quat[k]), pos[k]) for k in range(n_frames)]
    # points ahead of the first camera, 3-8 m away, spread across the view
    T_W_C0 = T_W_B[0] @ T_B_C
    depth = rng.uniform(*depth_m, n_points)
    xy0 = rng.uniform(-0.7, 0.7, (n_points, 2))
    P_W = T_W_C0 @ np.column_stack([xy0 * depth[:, None], depth])
    frames = []
    for k, T in enumerate(T_W_B):
        Pc = (T @ T_B_C).inverse() @ P_W
        xy = Pc[:, :2] / Pc[:, 2:3]
        vis = (Pc[:, 2] > 0.3) & (np.abs(xy[:, 0]) < 0.8) & (np.abs(xy[:, 1]) < 0.55)
        ids = np.flatnonzero(vis).astype(np.int64)
        obs = xy[vis] + rng.normal(0.0, pixel_sigma / FOCAL_PX, (len(ids), 2))
        stereo: dict[str, np.ndarray] = {}
        if stereo_baseline_m is not None:
            Pr = Pc[vis] - [stereo_baseline_m, 0.0, 0.0]
            xr = Pr[:, :2] / Pr[:, 2:3] + rng.normal(0.0, pixel_sigma / FOCAL_PX, (len(ids), 2))
            stereo = {"stereo_ids": ids.copy(), "stereo_xy": xr}
        frames.append(
            FrameFeatures(
                t_ns=stamps[k],
                ids=ids,
                uv_px=obs * FOCAL_PX,
                xy=obs,
                velocity_xy_s=np.zeros_like(obs),
                keyframe=True,
                **stereo,
            )
        )
    params = imu_params(noise)
    pims = tuple(
        preintegrate(params, samples, stamps[k], stamps[k + 1]) for k in range(n_frames - 1)
    )
    T_L_R = (
        None if stereo_baseline_m is None else Pose(Rotation.identity(), [stereo_baseline_m, 0, 0])
    )
    window = InitWindow(
        frames=tuple(frames), preintegrations=pims, T_B_C=T_B_C, g_norm=GRAVITY_M_S2, T_L_R=T_L_R
    )
    v = motion.velocity(np.asarray(stamps, dtype=np.int64))
    b_true = bg + imu.gyro_bias_rad_s[np.searchsorted(imu.t_ns, stamps[0])]
    return Scene(window=window, T_W_B=T_W_B, v_W_B=v, gyro_bias=b_true, points_W=P_W)
