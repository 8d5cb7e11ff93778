"""Trajectories from ROS 1 and ROS 2 bags, through the ``rosbags`` library.

Reads ``nav_msgs/Odometry``, ``geometry_msgs/PoseStamped`` and
``geometry_msgs/PoseWithCovarianceStamped`` messages (ROS frames are ENU/FLU, as ours). The
time of each pose is its header stamp; the position covariance comes along where the message
has one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from quadnav.errors import GeometryError, IoError
from quadnav.geometry.trajectory import Trajectory
from quadnav.units import NS_PER_S

__all__ = ["POSE_TYPES", "read_bag_trajectory"]

POSE_TYPES = (
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
)


def _pose_of(msg: Any, msgtype: str) -> tuple[Any, Any]:
    """(geometry_msgs/Pose, 36-element covariance or None) of a supported message."""
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return msg.pose, None
    return msg.pose.pose, msg.pose.covariance


def read_bag_trajectory(path: Path, *, topic: str | None = None) -> Trajectory:
    """The poses on ``topic`` (or on the only pose topic in the bag)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if not path.exists():
        raise IoError(f"bag not found: {path}")
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            candidates = [c for c in reader.connections if c.msgtype in POSE_TYPES]
            if topic is not None:
                candidates = [c for c in candidates if c.topic == topic]
            topics = sorted({c.topic for c in candidates})
            if not topics:
                what = f"topic {topic!r} with" if topic else "any topic of"
                raise IoError(f"{path}: no {what} types {', '.join(POSE_TYPES)}")
            if len(topics) > 1:
                raise IoError(
                    f"{path}: several pose topics ({', '.join(topics)}); choose one with --topic"
                )
            t, p, q, cov = [], [], [], []
            for conn, _, raw in reader.messages(connections=candidates):
                msg: Any = reader.deserialize(raw, conn.msgtype)
                pose, c = _pose_of(msg, conn.msgtype)
                t.append(int(msg.header.stamp.sec) * NS_PER_S + int(msg.header.stamp.nanosec))
                p.append([pose.position.x, pose.position.y, pose.position.z])
                q.append(
                    [pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w]
                )
                if c is not None:
                    cov.append(np.asarray(c, dtype=np.float64).reshape(6, 6)[:3, :3])
    except IoError:
        raise
    except Exception as exc:  # rosbags raises its own error types for corrupt bags
        raise IoError(f"{path}: cannot read the bag: {exc}") from None
    order = np.argsort(np.asarray(t, dtype=np.int64), kind="stable")
    cov_p = np.asarray(cov)[order] if len(cov) == len(t) and cov else None
    if cov_p is not None and not np.any(cov_p):
        cov_p = None  # an all-zero covariance means "not filled in"
    try:
        return Trajectory(
            t_ns=np.asarray(t, dtype=np.int64)[order],
            p_W_B=np.asarray(p, dtype=np.float64).reshape(-1, 3)[order],
            q_W_B_xyzw=np.asarray(q, dtype=np.float64).reshape(-1, 4)[order],
            cov_p=cov_p,
            name=f"{path.stem}{topics[0].replace('/', '_')}",
        )
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None
