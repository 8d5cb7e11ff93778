"""Segments of an odometry's run and their relocalization into the map.

A *segment* is a stretch of the odometry that loop closure can trust end to end: it begins at
the start, at each reset of the odometry (a new odometry frame), and after each gap in the
images longer than ``LoopConfig.image_gap_s`` (the odometry went on on the IMU alone: its pose
across the gap is a dead reckoning). Each segment is its own frame in the pose graph, without
odometry edges to the one before. The first segment (or a loaded map) is the root; a segment
is *joined* once a verified loop ties it to a joined one.

Until then it is *relocalizing* (VINS-Mono's relocalization, ORB-SLAM's after a loss): every
new keyframe of the odometry, still in its window, is looked up in the place database without
waiting for temporal consistency (the best entries of the three best islands) and verified
against the map. After a gap (the odometry's frame went on) one verified match joins the
segment if its map-to-odometry transform lies within ``relocalize_max_jump_m`` / ``_rad`` of the
one before the gap: a place that only looks like the old one, metres away, is refused there as
the drift check refuses it for loops. After a reset or on a loaded map (the frame is unrelated:
no such check) it takes two verified matches within ``relocalize_window_s`` whose transforms
agree (``relocalize_agree_m`` and ``_rad``). The loops enter the graph when the keyframe leaves
the odometry's window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from quadnav.geometry.rotations import Pose, rot_z, yaw_of

__all__ = ["RelocCandidate", "Segment", "Segments", "continuing_frame", "four_dof", "transform_gap"]


def four_dof(T: Pose) -> Pose:
    """``T`` with its rotation reduced to the yaw (a map-to-odometry transform of a
    gravity-aligned odometry has no roll or pitch)."""
    from scipy.spatial.transform import Rotation

    yaw = yaw_of(T.R_A_B.as_matrix())
    return Pose(R_A_B=Rotation.from_matrix(rot_z(yaw)), p_A_B=np.asarray(T.p_A_B, np.float64))


def continuing_frame(T_M_last: Pose, T_O_first: Pose) -> Pose:
    """The map-to-odometry transform (a yaw and a translation) that puts a new odometry frame's
    first pose ``T_O_first`` where the output last was, ``T_M_last``: in position, and in
    heading."""
    from scipy.spatial.transform import Rotation

    yaw = yaw_of(T_M_last.R_A_B.as_matrix()) - yaw_of(T_O_first.R_A_B.as_matrix())
    R = rot_z(yaw)
    return Pose(R_A_B=Rotation.from_matrix(R), p_A_B=T_M_last.p_A_B - R @ T_O_first.p_A_B)


def transform_gap(a: Pose, b: Pose) -> tuple[float, float]:
    """How far apart two transforms are: metres, and radians of yaw."""
    dyaw = yaw_of(b.R_A_B.as_matrix()) - yaw_of(a.R_A_B.as_matrix())
    dyaw = (dyaw + math.pi) % (2 * math.pi) - math.pi
    return float(np.linalg.norm(b.p_A_B - a.p_A_B)), abs(dyaw)


@dataclass(slots=True, kw_only=True)
class Segment:
    """A segment: its id (its pose graph frame), the odometry frame (``reset_counter``) it is
    in, the time it starts, whether it is ``joined`` to the map, and ``prior``: the transform
    it is taken at until then when the odometry's frame went on across a gap (None after a
    reset or in a new run on a loaded map: unknown)."""

    id: int
    reset_counter: int
    t_start_ns: int
    joined: bool
    prior: Pose | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class RelocCandidate:
    """A verified match of a segment's newest keyframe (odometry index ``new``) to keyframe
    ``old`` of the map: the pose of new in old's body ``T_old_new``, its 4-DoF covariance, and
    the map-to-odometry transform it implies ``T_M_O``."""

    segment: int
    t_ns: int
    old: int
    new: int
    T_old_new: Pose
    cov_4dof: np.ndarray
    T_M_O: Pose
    inliers: int


@dataclass(slots=True)
class Segments:
    """The run's segments in time order, and each keyframe's."""

    items: list[Segment] = field(default_factory=list)

    @property
    def current(self) -> Segment:
        return self.items[-1]

    def start(self, reset_counter: int, t_ns: int, *, joined: bool, prior: Pose | None) -> Segment:
        seg = Segment(
            id=len(self.items), reset_counter=reset_counter, t_start_ns=t_ns, joined=joined,
            prior=prior,
        )  # fmt: skip
        self.items.append(seg)
        return seg

    def of(self, reset_counter: int, t_ns: int) -> Segment:
        """The segment a keyframe of odometry frame ``reset_counter`` at ``t_ns`` belongs to:
        the last of its frame begun at or before it (the first of its frame if none)."""
        mine = [s for s in self.items if s.reset_counter == reset_counter]
        if not mine:
            return self.current
        before = [s for s in mine if s.t_start_ns <= t_ns]
        return before[-1] if before else mine[0]
