"""What the parts of the visual-inertial initialisation hand one another (GTSAM's
preintegration inside). What the VIO gives out is the odometry interface's
(:mod:`quadnav.odometry`): ``OdometryState``, ``KeyframeRecord``, ``FrameFeatures``..."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from quadnav.geometry import Pose
from quadnav.odometry import FrameFeatures

__all__ = ["InitResult", "InitWindow"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class InitWindow:
    """What a visual-inertial initialisation works on (thesis 003 §3.2): the window's frames in
    time order with their features, the IMU preintegrated between consecutive frames (with zero
    bias; ``len(frames) - 1`` of them), the camera's mount ``T_B_C`` and gravity's magnitude
    (and, stereo, the second camera's pose in the first)."""

    frames: tuple[FrameFeatures, ...]
    preintegrations: tuple[gtsam.PreintegratedCombinedMeasurements, ...]
    T_B_C: Pose
    g_norm: float
    #: with a stereo rig, the second camera in the first (its frames then carry stereo corners)
    T_L_R: Pose | None = None


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
