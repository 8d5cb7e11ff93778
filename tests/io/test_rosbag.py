from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from quadnav.errors import IoError
from quadnav.io import read_trajectory


def _msgs(ts, kind: str, n: int = 5):
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    Point = ts.types["geometry_msgs/msg/Point"]
    Quat = ts.types["geometry_msgs/msg/Quaternion"]
    Pose = ts.types["geometry_msgs/msg/Pose"]
    out = []
    for k in range(n):
        stamp = Time(sec=100 + k, nanosec=250_000_000)
        extra = {"seq": k} if "seq" in Header.__dataclass_fields__ else {}  # ROS 1 headers count
        header = Header(stamp=stamp, frame_id="map", **extra)
        pose = Pose(
            position=Point(x=float(k), y=2.0 * k, z=1.0),
            orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0),
        )
        if kind == "geometry_msgs/msg/PoseStamped":
            msg = ts.types[kind](header=header, pose=pose)
        else:
            cov = np.zeros(36)
            cov[0] = cov[7] = cov[14] = 0.01 * (k + 1)
            pwc = ts.types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov)
            if kind == "nav_msgs/msg/Odometry":
                twist = ts.types["geometry_msgs/msg/TwistWithCovariance"](
                    twist=ts.types["geometry_msgs/msg/Twist"](
                        linear=ts.types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                        angular=ts.types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                    ),
                    covariance=np.zeros(36),
                )
                msg = ts.types[kind](
                    header=header, child_frame_id="base_link", pose=pwc, twist=twist
                )
            else:
                msg = ts.types[kind](header=header, pose=pwc)
        out.append(((100 + k) * 10**9, msg))
    return out


def write_ros2(path: Path, topics: dict[str, str]) -> None:
    from rosbags.rosbag2 import Writer

    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Writer(path, version=9) as w:
        for topic, kind in topics.items():
            conn = w.add_connection(topic, kind, typestore=ts)
            for stamp, msg in _msgs(ts, kind):
                w.write(conn, stamp, ts.serialize_cdr(msg, kind))


def write_ros1(path: Path, topic: str, kind: str) -> None:
    from rosbags.rosbag1 import Writer

    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer(path) as w:
        conn = w.add_connection(topic, kind, typestore=ts)
        for stamp, msg in _msgs(ts, kind):
            w.write(conn, stamp, ts.serialize_ros1(msg, kind))


@pytest.mark.parametrize(
    "kind",
    [
        "nav_msgs/msg/Odometry",
        "geometry_msgs/msg/PoseStamped",
        "geometry_msgs/msg/PoseWithCovarianceStamped",
    ],
)
def test_ros2_bag_poses(tmp_path: Path, kind: str) -> None:
    bag = tmp_path / "bag2"
    write_ros2(bag, {"/est": kind})
    tr = read_trajectory(bag)
    assert list(tr.t_ns) == [(100 + k) * 10**9 + 250_000_000 for k in range(5)]
    np.testing.assert_allclose(tr.p_W_B[:, 1], 2.0 * np.arange(5))
    if kind == "geometry_msgs/msg/PoseStamped":
        assert tr.cov_p is None
    else:
        np.testing.assert_allclose(tr.cov_p[:, 0, 0], 0.01 * np.arange(1, 6))


def test_ros1_bag_odometry(tmp_path: Path) -> None:
    bag = tmp_path / "b.bag"
    write_ros1(bag, "/odom", "nav_msgs/msg/Odometry")
    tr = read_trajectory(bag)
    assert len(tr) == 5 and tr.t_ns[0] == 100_250_000_000


def test_bag_with_several_pose_topics_needs_a_topic(tmp_path: Path) -> None:
    bag = tmp_path / "bag2"
    write_ros2(bag, {"/a": "nav_msgs/msg/Odometry", "/b": "geometry_msgs/msg/PoseStamped"})
    with pytest.raises(IoError, match="--topic"):
        read_trajectory(bag)
    assert len(read_trajectory(bag, topic="/b")) == 5
    with pytest.raises(IoError, match="no topic '/c'"):
        read_trajectory(bag, topic="/c")


def test_corrupt_bag_is_an_io_error(tmp_path: Path) -> None:
    bag = tmp_path / "broken.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n" + bytes(100))
    with pytest.raises(IoError, match=r"broken\.bag"):
        read_trajectory(bag)
