"""A drifting odometry around a loop, for the pose graph's tests, benchmark and examples.

Keyframes go ``laps`` times round a circle (rising and falling, heading along it, rolling and
pitching a little). The odometry starts at the truth and integrates the true relative motion
with a random walk in x, y, z (in the body frame) and yaw; its roll and pitch are the truth's
(gravity makes them observable), so its drift is the 4-DoF one VINS-Mono's graph corrects. Loop
edges join a keyframe of a later lap to the one at the same place of the first, measured from the
truth with a little noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.random import Generator
from scipy.spatial.transform import Rotation

from quadnav.geometry.rotations import Pose, rot_z
from quadnav.posegraph.types import FloatArray, LoopEdge

__all__ = ["DriftingLoop", "drifting_loop", "position_rmse"]


@dataclass(frozen=True, slots=True, kw_only=True)
class DriftingLoop:
    """Keyframes ``0..N-1``: their true poses, the drifting odometry's and loop edges between
    laps (``per_lap`` keyframes a lap)."""

    truth: tuple[Pose, ...]
    odometry: tuple[Pose, ...]
    loops: tuple[LoopEdge, ...]
    per_lap: int


def _truth(n: int, per_lap: int, radius_m: float) -> list[Pose]:
    a = 2 * math.pi * np.arange(n) / per_lap
    p = np.stack([radius_m * np.cos(a), radius_m * np.sin(a), 1.5 + 0.5 * np.sin(3 * a)], axis=1)
    yaw = a + math.pi / 2
    rp = 0.1 * np.stack([np.sin(5 * a), np.cos(4 * a)], axis=1)
    R = Rotation.from_euler("ZYX", np.column_stack([yaw, rp[:, 0], rp[:, 1]]))
    return [Pose(R[k], p[k]) for k in range(n)]


def drifting_loop(
    rng: Generator,
    *,
    keyframes: int = 200,
    per_lap: int = 100,
    loops: int = 5,
    radius_m: float = 5.0,
    sigma_step_m: float = 0.02,
    sigma_step_yaw_rad: float = 0.004,
    sigma_loop_m: float = 0.01,
    sigma_loop_rad: float = 0.002,
) -> DriftingLoop:
    """A drifting odometry over ``keyframes`` keyframes, ``per_lap`` a lap, with ``loops`` loop
    edges spread over the laps after the first (per step noise ``sigma_step_*``)."""
    truth = _truth(keyframes, per_lap, radius_m)
    odo = [truth[0]]
    yaw_drift = 0.0
    for k in range(1, keyframes):
        step = (truth[k - 1].inverse() @ truth[k]).p_A_B + rng.normal(0.0, sigma_step_m, 3)
        p = odo[-1].p_A_B + odo[-1].R_A_B.apply(step)  # the step in the body frame, noisy
        yaw_drift += float(rng.normal(0.0, sigma_step_yaw_rad))  # roll and pitch: the truth's
        R = Rotation.from_matrix(rot_z(yaw_drift) @ truth[k].R_A_B.as_matrix())
        odo.append(Pose(R, p))
    later = np.arange(per_lap, keyframes)
    picks = later[np.linspace(0, len(later) - 1, loops).round().astype(int)] if loops else []
    edges = []
    for new in picks:
        old = int(new) % per_lap
        rel = truth[old].inverse() @ truth[int(new)]
        noise = Pose(
            Rotation.from_rotvec(rng.normal(0.0, sigma_loop_rad, 3)),
            rng.normal(0.0, sigma_loop_m, 3),
        )
        edges.append(LoopEdge(old=old, new=int(new), T_old_new=rel @ noise))
    return DriftingLoop(
        truth=tuple(truth), odometry=tuple(odo), loops=tuple(edges), per_lap=per_lap
    )


def position_rmse(
    poses: tuple[Pose, ...] | list[Pose], truth: tuple[Pose, ...] | list[Pose]
) -> float:
    """The root mean square of the position errors (m), no alignment (both start together)."""
    d = np.array([p.p_A_B - t.p_A_B for p, t in zip(poses, truth, strict=True)], dtype=np.float64)
    err: FloatArray = np.sqrt((d**2).sum(axis=1))
    return float(np.sqrt(np.mean(err**2)))
