"""The SLAM's map: map points (position, descriptor, the level first seen at, the keyframe that
made them, how many keyframes observe them, whether culled) and keyframes (their pose, frame
and, per keypoint, the map point it observes or -1)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.rotations import Pose
from quadnav.slam.frame import Frame

__all__ = ["SlamKeyframe", "SlamMap"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(slots=True)
class SlamKeyframe:
    """A keyframe: its ``index``, the camera's pose ``T_C_W``, its ``frame`` and ``points``
    (per keypoint: the map point it observes, -1 for none)."""

    index: int
    T_C_W: Pose
    frame: Frame
    points: IntArray

    @property
    def observed(self) -> tuple[IntArray, IntArray]:
        """(keypoints, map points) of its observations."""
        kp = np.flatnonzero(self.points >= 0)
        return kp, self.points[kp]


class SlamMap:
    """Map points in growing arrays (ids are indices, never reused) and the keyframes."""

    def __init__(self) -> None:
        self.X_W = np.zeros((0, 3))
        self.descriptors = np.zeros((0, 32), np.uint8)
        self.octave = np.zeros(0, np.int64)
        self.first_keyframe = np.zeros(0, np.int64)
        self.n_obs = np.zeros(0, np.int64)
        self.bad = np.zeros(0, bool)
        self.keyframes: list[SlamKeyframe] = []

    def __len__(self) -> int:
        return int((~self.bad).sum())

    def add_keyframe(self, T_C_W: Pose, frame: Frame) -> SlamKeyframe:
        kf = SlamKeyframe(index=len(self.keyframes), T_C_W=T_C_W, frame=frame,
                          points=np.full(len(frame), -1, np.int64))  # fmt: skip
        self.keyframes.append(kf)
        return kf

    def add_points(self, kf: SlamKeyframe, kps: IntArray) -> IntArray:
        """New map points from keyframe ``kf``'s keypoints ``kps`` (with a depth), observed there."""
        kps = np.asarray(kps, np.int64)
        ids = np.arange(len(self.X_W), len(self.X_W) + len(kps), dtype=np.int64)
        X = kf.T_C_W.inverse() @ kf.frame.points_C(kps) if len(kps) else np.zeros((0, 3))
        f = kf.frame.features
        self.X_W = np.vstack([self.X_W, X])
        self.descriptors = np.vstack([self.descriptors, f.descriptors[kps]])
        self.octave = np.r_[self.octave, f.octave[kps]]
        self.first_keyframe = np.r_[self.first_keyframe, np.full(len(kps), kf.index, np.int64)]
        self.n_obs = np.r_[self.n_obs, np.zeros(len(kps), np.int64)]
        self.bad = np.r_[self.bad, np.zeros(len(kps), bool)]
        self.observe(kf, kps, ids)
        return ids

    def observe(self, kf: SlamKeyframe, kps: IntArray, ids: IntArray) -> None:
        """Keyframe ``kf`` sees map points ``ids`` at its keypoints ``kps``."""
        kf.points[kps] = ids
        np.add.at(self.n_obs, ids, 1)

    def forget(self, kf: SlamKeyframe, kps: IntArray) -> None:
        """Keyframe ``kf`` no longer sees the points at its keypoints ``kps`` (outliers)."""
        ids = kf.points[kps]
        ids = ids[ids >= 0]
        np.subtract.at(self.n_obs, ids, 1)
        kf.points[kps] = -1

    def cull(self, ids: IntArray) -> None:
        """Points ``ids`` are bad: no keyframe keeps them."""
        self.bad[ids] = True
        for kf in self.keyframes:
            kf.points[np.isin(kf.points, ids)] = -1

    def local_points(self, keyframes: list[SlamKeyframe]) -> IntArray:
        """The good map points these keyframes observe."""
        ids = np.unique(
            np.concatenate(
                [kf.points[kf.points >= 0] for kf in keyframes] or [np.zeros(0, np.int64)]
            )
        )
        return np.asarray(ids[~self.bad[ids]], np.int64)
