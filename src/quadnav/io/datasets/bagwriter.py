"""Datasets as ROS 2 bags (rosbags' ``Writer``, sqlite3 storage): ``/camK/image_raw``
(``sensor_msgs/msg/Image``: mono8 for grey pictures, bgr8 for colour) with ``/camK/camera_info``
once per camera (its lens; ``P[0, 3] = -fx * x`` of the camera in the first one's frame),
``/imu0`` (``sensor_msgs/msg/Imu``, orientation unknown per REP 145) and ``/groundtruth``
(``geometry_msgs/msg/PoseStamped``); a message's bag time is its stamp.

:class:`Ros2BagWriter` writes sample by sample (for a sequence being made) into
``<path>.partial/`` and renames it at ``close()``, as :class:`~quadnav.io.datasets.EurocWriter`
does; :func:`write_ros2_bag` converts a dataset, reading its images one at a time."""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav.errors import IoError, SampleError
from quadnav.geometry.rotations import Pose
from quadnav.io.datasets.bags import IMAGE_TYPES, IMU_TYPE, INFO_TYPE
from quadnav.io.datasets.files import PartialWriter
from quadnav.io.datasets.types import VisualInertialDataset
from quadnav.messages import ImageFrame, ImuSample
from quadnav.rig import CameraSpec, Rig
from quadnav.units import NS_PER_S

__all__ = ["Ros2BagWriter", "write_ros2_bag"]

POSE_TYPE = "geometry_msgs/msg/PoseStamped"


class _Ros2Messages:
    """Builders of the ROS 2 messages write_ros2_bag writes."""

    def __init__(self) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.ts = get_typestore(Stores.ROS2_HUMBLE)
        self.T = self.ts.types

    def header(self, t_ns: int, frame: str) -> Any:
        stamp = self.T["builtin_interfaces/msg/Time"](sec=t_ns // NS_PER_S, nanosec=t_ns % NS_PER_S)
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def image(self, t_ns: int, frame: str, img: NDArray[np.uint8]) -> Any:
        grey = img.ndim == 2 or img.shape[2] == 1
        px = np.ascontiguousarray(img if img.ndim == 3 and not grey else img.reshape(img.shape[:2]))
        if px.ndim == 3 and px.shape[2] == 4:
            px = np.ascontiguousarray(px[:, :, :3])
        h, w = px.shape[:2]
        return self.T["sensor_msgs/msg/Image"](
            header=self.header(t_ns, frame),
            height=h,
            width=w,
            encoding="mono8" if px.ndim == 2 else "bgr8",
            is_bigendian=0,
            step=w * (1 if px.ndim == 2 else 3),
            data=px.ravel(),
        )

    def info(self, t_ns: int, frame: str, spec: CameraSpec, x0: Pose) -> Any:
        cam = spec.camera
        x = (x0.inverse() @ spec.T_B_C).p_A_B[0]
        P = np.hstack([cam.K, np.array([[-cam.fx * x], [0.0], [0.0]])])
        roi = self.T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        return self.T["sensor_msgs/msg/CameraInfo"](
            header=self.header(t_ns, frame),
            height=cam.height,
            width=cam.width,
            distortion_model="equidistant" if cam.model == "equidistant" else "plumb_bob",
            d=np.asarray(cam.dist, dtype=np.float64),
            k=cam.K.ravel().copy(),
            r=np.eye(3).ravel(),
            p=P.ravel(),
            binning_x=0,
            binning_y=0,
            roi=roi,
        )

    def imu(self, t_ns: int, g: NDArray[np.float64], a: NDArray[np.float64]) -> Any:
        V, Q = self.T["geometry_msgs/msg/Vector3"], self.T["geometry_msgs/msg/Quaternion"]
        unknown = np.zeros(9)
        unknown[0] = -1.0  # REP 145: no orientation estimate
        return self.T["sensor_msgs/msg/Imu"](
            header=self.header(t_ns, "imu0"),
            orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=unknown,
            angular_velocity=V(x=g[0], y=g[1], z=g[2]),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=V(x=a[0], y=a[1], z=a[2]),
            linear_acceleration_covariance=np.zeros(9),
        )

    def pose(self, t_ns: int, p: NDArray[np.float64], q: NDArray[np.float64]) -> Any:
        G = self.T
        pose = G["geometry_msgs/msg/Pose"](
            position=G["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
            orientation=G["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        return G["geometry_msgs/msg/PoseStamped"](header=self.header(t_ns, "world"), pose=pose)


class Ros2BagWriter(PartialWriter):
    """A ROS 2 bag of ``rig``'s cameras and IMU, written sample by sample (module docstring)."""

    def __init__(self, path: Path | str, rig: Rig, *, camera_info: bool = True) -> None:
        from rosbags.rosbag2 import Writer

        self.path = Path(path)
        if self.path.exists():
            raise IoError(f"{self.path}: already exists")
        self.partial = self.path.with_name(self.path.name + ".partial")
        if self.partial.exists():
            shutil.rmtree(self.partial)
        self.rig = rig
        self.m = _Ros2Messages()
        self.camera_info = camera_info
        # the bag is made inside the partial folder under its own name, so its storage file is
        # <name>.db3 (rosbags names it after the folder), then moved out whole
        self.partial.mkdir(parents=True)
        self.writer: Any = Writer(self.partial / self.path.name, version=9)
        self.writer.open()
        self.conns: dict[str, Any] = {}
        self.closed = False

    def _write(self, topic: str, msgtype: str, t_ns: int, msg: Any) -> None:
        if self.closed:
            raise IoError(f"{self.path}: the writer is closed")
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.m.ts)
        self.writer.write(self.conns[topic], int(t_ns), self.m.ts.serialize_cdr(msg, msgtype))

    def add_frame(self, camera: str, t_ns: int, image: NDArray[np.uint8]) -> None:
        spec = self.rig.camera(camera)
        info = f"/{camera}/camera_info"
        if self.camera_info and info not in self.conns:
            msg = self.m.info(t_ns, camera, spec, self.rig.cameras[0].T_B_C)
            self._write(info, INFO_TYPE, t_ns, msg)
        self._write(f"/{camera}/image_raw", IMAGE_TYPES[0], t_ns, self.m.image(t_ns, camera, image))

    def add_imu(self, sample: ImuSample) -> None:
        msg = self.m.imu(sample.t_ns, sample.gyro_rad_s, sample.accel_m_s2)
        self._write("/imu0", IMU_TYPE, sample.t_ns, msg)

    def add_groundtruth(self, t_ns: int, p: ArrayLike, q: ArrayLike) -> None:
        msg = self.m.pose(t_ns, np.asarray(p, float), np.asarray(q, float))
        self._write("/groundtruth", POSE_TYPE, t_ns, msg)

    def close(self) -> Path:
        if not self.closed:
            self.writer.close()
            (self.partial / self.path.name).rename(self.path)
            self.partial.rmdir()
            self.closed = True
        return self.path

    def abort(self) -> None:
        with contextlib.suppress(Exception):  # rosbags' own errors: the folder goes anyway
            self.writer.close()
        shutil.rmtree(self.partial, ignore_errors=True)
        self.closed = True


def write_ros2_bag(
    dataset: VisualInertialDataset, path: Path | str, *, camera_info: bool = True
) -> Path:
    """``dataset`` as a ROS 2 bag at ``path`` (see the module docstring)."""
    try:
        with Ros2BagWriter(path, dataset.rig, camera_info=camera_info) as w:
            for item in dataset.stream():
                if isinstance(item, ImageFrame):
                    w.add_frame(item.camera, item.t_ns, item.image())
                else:
                    w.add_imu(item)
            gt = dataset.groundtruth
            if gt is not None:
                tr = gt.trajectory
                for t, p, q in zip(tr.t_ns, tr.p_W_B, tr.q_W_B_xyzw, strict=True):
                    w.add_groundtruth(int(t), p, q)
    except (IoError, SampleError):
        raise
    except Exception as exc:  # rosbags' own error types
        raise IoError(f"{path}: cannot write the bag: {exc}") from None
    return Path(path)
