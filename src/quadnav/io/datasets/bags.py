"""ROS 1 and ROS 2 bags as datasets, through rosbags' ``AnyReader`` (the writer of ROS 2 bags
is :mod:`quadnav.io.datasets.bagwriter`).

Read: ``sensor_msgs/Image`` (mono8, mono16, bgr8, rgb8, bgra8, rgba8), ``sensor_msgs/
CompressedImage`` (JPEG/PNG through ``cv2.imdecode``) and ``sensor_msgs/Imu``; the stamps are
the header stamps. Every image topic is a camera (``cam0``, ``cam1``... in the order of
``image_topics``, or of the topic names); several IMU topics, or a raw and a compressed topic of
one camera, need ``imu_topic`` / ``image_topics`` (a one-line error lists the candidates).
Calibration: a file the user gives (an EuRoC folder or a Kalibr camchain, cameras in order) or
else each camera's ``camera_info`` topic (``plumb_bob`` / ``equidistant``; extrinsics are then
the identity, and a right camera's baseline from ``P[0, 3] = -fx * b``; the IMU's noise unknown,
written as zeros).

Lazy frames: opening a bag reads every message once to learn the stamps (an image is decoded
only as far as its header) and keeps, per frame, its connection and bag time; a frame's
:meth:`~quadnav.messages.ImageFrame.image` reads that one message again (a time-window query on
a reader that stays open) and decodes it. No pixels are held.
"""

from __future__ import annotations

import functools
import weakref
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import GeometryError, IoError, SampleError
from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.io.datasets.files import rate_of_stamps, to_uint8
from quadnav.io.datasets.kalibr import DISTORTION_NAMES
from quadnav.io.datasets.types import (
    IN_ORDER,
    REPEATED,
    GroundTruth,
    ImuTable,
    IssueLog,
    VisualInertialDataset,
    order_faults,
    sort_frames,
)
from quadnav.messages import ImageFrame
from quadnav.rig import CameraSpec, ImuNoiseModel, ImuSpec, Rig
from quadnav.units import NS_PER_S

__all__ = ["IMAGE_TYPES", "IMU_TYPE", "INFO_TYPE", "decode_image", "read_bag_dataset"]

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
IMU_TYPE = "sensor_msgs/msg/Imu"
INFO_TYPE = "sensor_msgs/msg/CameraInfo"


def _stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * NS_PER_S + int(msg.header.stamp.nanosec)


def decode_image(msg: Any, msgtype: str) -> NDArray[np.uint8]:
    """The pixels of an Image or CompressedImage message (grey (h, w) or BGR (h, w, 3))."""
    if msgtype.endswith("CompressedImage"):
        img = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise SampleError(f"compressed image ({msg.format}) cannot be decoded")
        return to_uint8(img)
    h, w, step, enc = int(msg.height), int(msg.width), int(msg.step), str(msg.encoding).lower()
    raw = np.asarray(msg.data, dtype=np.uint8)
    if raw.size < h * step:
        raise SampleError(f"image of {h}x{w} has {raw.size} bytes, needs {h * step}")
    rows = raw[: h * step].reshape(h, step)
    if enc in ("mono8", "8uc1"):
        return np.ascontiguousarray(rows[:, :w])
    if enc in ("mono16", "16uc1"):
        dt = np.dtype(">u2" if msg.is_bigendian else "<u2")
        return to_uint8(rows[:, : 2 * w].copy().view(dt).astype(np.uint16))
    channels = {"bgr8": 3, "rgb8": 3, "bgra8": 4, "rgba8": 4, "8uc3": 3}.get(enc)
    if channels is None:
        raise SampleError(f"image encoding {msg.encoding!r} is not one quadnav reads")
    px = rows[:, : channels * w].reshape(h, w, channels)
    if enc.startswith("rgb"):
        px = px[:, :, [2, 1, 0]]
    return np.ascontiguousarray(px[:, :, :3])


class _Cursor:
    """Where one topic's reading stands: a message generator and the (bag time, rank among
    messages of that bag time) of the last message it gave."""

    def __init__(self, messages: Iterator[tuple[Any, int, bytes]]) -> None:
        self.messages = messages
        self.at: tuple[int, int] = (-1, -1)


class _BagSource:
    """One bag kept open for the frames' loaders. Per topic a cursor goes forward through the
    messages, so frames asked for in order (a stream) cost one read each; asking for an
    earlier frame starts a new cursor at its bag time."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.reader: Any = None
        self.cursors: dict[str, _Cursor] = {}

    def _open(self) -> Any:
        if self.reader is None:
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore

            store = get_typestore(Stores.ROS2_HUMBLE)
            self.reader = AnyReader([self.path], default_typestore=store)
            self.reader.open()
            weakref.finalize(self, self.reader.close)
        return self.reader

    def load(self, topic: str, bag_t: int, nth: int) -> NDArray[np.uint8]:
        reader = self._open()
        cur = self.cursors.get(topic)
        if cur is None or cur.at >= (bag_t, nth):
            conns = [c for c in reader.connections if c.topic == topic]
            cur = self.cursors[topic] = _Cursor(reader.messages(connections=conns, start=bag_t))
        for conn, t, raw in cur.messages:
            cur.at = (t, cur.at[1] + 1 if t == cur.at[0] else 0)
            if cur.at == (bag_t, nth):
                return decode_image(reader.deserialize(raw, conn.msgtype), conn.msgtype)
            if t > bag_t:
                break
        del self.cursors[topic]
        raise SampleError(f"{self.path}: no message on {topic} at bag time {bag_t}")


def _choose_images(topics: dict[str, str], chosen: Sequence[str] | None, path: Path) -> list[str]:
    images = sorted(t for t, k in topics.items() if k in IMAGE_TYPES)
    if chosen:
        missing = [t for t in chosen if topics.get(t) not in IMAGE_TYPES]
        if missing:
            raise IoError(
                f"{path}: image topic {missing[0]!r} is not in the bag; its image topics: "
                f"{', '.join(images) or 'none'}"
            )
        return list(chosen)
    if not images:
        raise IoError(f"{path}: no sensor_msgs/Image or CompressedImage topic")
    for a in images:
        if any(b != a and b.startswith(a + "/") for b in images):
            raise IoError(
                f"{path}: several image topics of one camera ({', '.join(images)}); "
                "choose them with image_topics"
            )
    return images


def _choose_imu(topics: dict[str, str], chosen: str | None, path: Path) -> str | None:
    imus = sorted(t for t, k in topics.items() if k == IMU_TYPE)
    if chosen is not None:
        if chosen not in imus:
            raise IoError(
                f"{path}: IMU topic {chosen!r} is not in the bag; its IMU topics: {', '.join(imus) or 'none'}"
            )
        return chosen
    if len(imus) > 1:
        raise IoError(f"{path}: several IMU topics ({', '.join(imus)}); choose one with imu_topic")
    return imus[0] if imus else None


def _info_topic(image_topic: str) -> str:
    base = image_topic.removesuffix("/compressed")
    return base.rsplit("/", 1)[0] + "/camera_info"


def _field(msg: Any, *names: str) -> Any:
    for n in names:
        if hasattr(msg, n):
            return getattr(msg, n)
    raise IoError(f"CameraInfo has none of the fields {names}")


def _lens_of_info(msg: Any, topic: str, path: Path) -> tuple[PinholeCamera, float]:
    """(lens, x of the camera in the first one's frame from P) of a CameraInfo message."""
    model = DISTORTION_NAMES.get(str(msg.distortion_model).lower() or "none")
    if model is None:
        raise IoError(
            f"{path}: {topic}: distortion model {msg.distortion_model!r} is not plumb_bob or equidistant"
        )
    K = np.asarray(_field(msg, "k", "K"), dtype=np.float64).reshape(3, 3)
    P = np.asarray(_field(msg, "p", "P"), dtype=np.float64).reshape(3, 4)
    d = np.asarray(_field(msg, "d", "D"), dtype=np.float64)
    try:
        lens = PinholeCamera(K, d, int(msg.width), int(msg.height), model=model)  # type: ignore[arg-type]
    except GeometryError as exc:
        raise IoError(f"{path}: {topic}: {exc}") from None
    x = -P[0, 3] / P[0, 0] if P[0, 0] > 0 else 0.0
    return lens, float(x)


class _Scan:
    """What one pass over a bag learns: frames (stamps, where), IMU rows, the first CameraInfo
    of each topic."""

    def __init__(self) -> None:
        self.frames: dict[str, list[tuple[int, int, int]]] = {}
        self.imu: list[tuple[int, list[float]]] = []
        self.info: dict[str, Any] = {}


def _scan(reader: Any, images: list[str], imu: str | None, issues: IssueLog) -> _Scan:
    scan = _Scan()
    seen: dict[tuple[str, int], int] = {}
    infos = {_info_topic(t) for t in images}
    wanted = set(images) | infos | ({imu} if imu else set())
    conns = [c for c in reader.connections if c.topic in wanted]
    for conn, bag_t, raw in reader.messages(connections=conns):
        if conn.topic in infos:
            if conn.topic not in scan.info:
                scan.info[conn.topic] = reader.deserialize(raw, conn.msgtype)
            continue
        msg = reader.deserialize(raw, conn.msgtype)
        if conn.topic == imu:
            w, a = msg.angular_velocity, msg.linear_acceleration
            vals = [w.x, w.y, w.z, a.x, a.y, a.z]
            if not np.isfinite(vals).all():
                issues.reject("IMU messages with a NaN", f"{imu} at {_stamp_ns(msg)}")
                continue
            scan.imu.append((_stamp_ns(msg), vals))
            continue
        nth = seen.get((conn.topic, bag_t), 0)
        seen[(conn.topic, bag_t)] = nth + 1
        scan.frames.setdefault(conn.topic, []).append((_stamp_ns(msg), bag_t, nth))
    return scan


def _rig_from_infos(path: Path, images: list[str], scan: _Scan, imu: ImuSpec | None) -> Rig:
    specs = []
    for k, topic in enumerate(images):
        info = scan.info.get(_info_topic(topic))
        if info is None:
            raise IoError(
                f"{path}: no calibration for {topic}: record {_info_topic(topic)} or give "
                "calibration (an EuRoC folder or a Kalibr camchain)"
            )
        lens, x = _lens_of_info(info, topic, path)
        T = Pose(Pose.identity().R_A_B, np.array([x, 0.0, 0.0]))
        specs.append(
            CameraSpec(
                name=f"cam{k}", camera=lens, T_B_C=T, rate_hz=_rate(scan.frames.get(topic, []))
            )
        )
    return Rig(name=path.stem, cameras=tuple(specs), imu=imu)


def _rate(stamps: Sequence[tuple[int, ...]] | Sequence[int]) -> float:
    return rate_of_stamps([s[0] if isinstance(s, tuple) else s for s in stamps])


def _unknown_imu(scan: _Scan) -> ImuSpec | None:
    """The bag's IMU when no file calibrates it: its rate from the stamps, its noise unknown
    (zeros)."""
    if not scan.imu:
        return None
    zero = ImuNoiseModel(
        gyro_noise_density=0, gyro_random_walk=0, accel_noise_density=0, accel_random_walk=0
    )
    return ImuSpec(rate_hz=_rate([t for t, _ in scan.imu]), noise=zero)


def _rig_from_file(calib: Path, images: list[str], scan: _Scan) -> Rig:
    from quadnav.io.datasets.euroc import (
        camera_folders,
        find_mav0,
        read_euroc_camera,
        read_euroc_imu,
    )
    from quadnav.io.datasets.kalibr import read_camchain, read_kalibr_imu

    rates = {f"cam{k}": _rate(scan.frames.get(t, [])) for k, t in enumerate(images)}
    imu: ImuSpec | None = None
    if calib.is_dir():
        mav0 = find_mav0(calib)
        if mav0 is None:
            raise IoError(f"{calib}: no mav0/ folder (not an EuRoC calibration)")
        cams = tuple(read_euroc_camera(c) for c in camera_folders(mav0))
        if (mav0 / "imu0" / "sensor.yaml").is_file():
            imu = read_euroc_imu(mav0 / "imu0")
    else:
        cams = read_camchain(calib, rates)
        beside = calib.parent / "imu.yaml"
        imu = read_kalibr_imu(beside) if beside.is_file() else None
    if len(cams) != len(images):
        raise IoError(
            f"{calib}: {len(cams)} cameras for {len(images)} image topics ({', '.join(images)})"
        )
    if imu is None:
        imu = _unknown_imu(scan)
    return Rig(name=calib.stem, cameras=cams, imu=imu)


def read_bag_dataset(
    path: Path,
    *,
    calibration: Path | None = None,
    image_topics: Sequence[str] | None = None,
    imu_topic: str | None = None,
) -> VisualInertialDataset:
    """A ROS 1 or ROS 2 bag as a dataset (see the module docstring)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    issues = IssueLog()
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            topics = {c.topic: c.msgtype for c in reader.connections}
            images = _choose_images(topics, image_topics, path)
            imu = _choose_imu(topics, imu_topic, path)
            scan = _scan(reader, images, imu, issues)
            gt_topic = _groundtruth_topic(topics)
    except IoError:
        raise
    except Exception as exc:  # rosbags raises its own error types for corrupt bags
        raise IoError(f"{path}: cannot read the bag: {exc}") from None
    try:
        if calibration is not None:
            rig = _rig_from_file(calibration, images, scan)
        else:
            rig = _rig_from_infos(path, images, scan, _unknown_imu(scan))
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None
    source = _BagSource(path)
    frames = [
        ImageFrame(
            t_ns=t,
            camera=f"cam{k}",
            load=functools.partial(source.load, topic, bag_t, nth),
            origin=f"{path} {topic} at {t}",
        )
        for k, topic in enumerate(images)
        for t, bag_t, nth in scan.frames.get(topic, [])
    ]
    return VisualInertialDataset(
        name=path.stem,
        root=path,
        kind="bag",
        rig=rig,
        frames=sort_frames(frames, rig.camera_names),
        imu=_imu_table(scan.imu, issues, imu or ""),
        groundtruth=_groundtruth(path, gt_topic),
        issues=issues.freeze(),
    )


def _groundtruth_topic(topics: dict[str, str]) -> str | None:
    """``/groundtruth`` (what write_ros2_bag writes) or else the bag's only pose topic."""
    from quadnav.io.rosbag import POSE_TYPES

    poses = sorted(t for t, k in topics.items() if k in POSE_TYPES)
    if "/groundtruth" in poses:
        return "/groundtruth"
    return poses[0] if len(poses) == 1 else None


def _groundtruth(path: Path, topic: str | None) -> GroundTruth | None:
    from quadnav.io.rosbag import read_bag_trajectory

    if topic is None:
        return None
    return GroundTruth(read_bag_trajectory(path, topic=topic), source=topic)


def _imu_table(rows: list[tuple[int, list[float]]], issues: IssueLog, topic: str) -> ImuTable:
    """The IMU messages in the bag's order; those whose stamp repeats or goes out of order
    rejected and counted, as the rows of a csv are."""
    if not rows:
        return ImuTable.empty()
    t = np.array([r[0] for r in rows], dtype=np.int64)
    v = np.array([r[1] for r in rows], dtype=np.float64)
    faults = order_faults(t)
    for i in np.flatnonzero(faults):
        fault = "repeated" if faults[i] == REPEATED else "out of order"
        issues.reject(f"IMU messages {fault}", f"{topic} at {int(t[i])}")
    keep = faults == IN_ORDER
    return ImuTable(t[keep], v[keep, 0:3], v[keep, 3:6])
