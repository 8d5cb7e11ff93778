"""KITTI odometry sequences: ``image_0/`` and ``image_1/`` (rectified grey PNGs ``000000.png``...),
``image_2/``/``image_3/`` (colour) when present, ``times.txt`` (seconds) and ``calib.txt``
(``P0:``..``P3:`` 3x4 projection matrices, ``Tr:``).

The images are rectified: no distortion. The body frame is camera 0's; camera k sits at
``x = -P_k[0, 3] / fx`` (its baseline from P0). No IMU (``Rig.imu = None``). Ground truth from
a KITTI poses file (camera 0's poses) when one is given, stamped with ``times.txt``."""

from __future__ import annotations

import functools
import os
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.errors import GeometryError, IoError
from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.datasets.files import load_image
from quadnav.io.datasets.types import (
    GroundTruth,
    ImuTable,
    IssueLog,
    VisualInertialDataset,
    sort_frames,
)
from quadnav.messages import ImageFrame
from quadnav.rig import CameraSpec, Rig
from quadnav.units import NS_PER_S

__all__ = ["read_kitti_calib", "read_kitti_sequence", "read_kitti_times"]


def read_kitti_calib(path: Path) -> dict[str, np.ndarray]:
    """``P0``..``P3`` (3x4) and ``Tr`` (3x4) of a ``calib.txt``."""
    if not path.is_file():
        raise IoError(f"{path}: no such file")
    out = {}
    for k, raw in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        if not raw.strip():
            continue
        key, _, rest = raw.partition(":")
        try:
            vals = np.array([float(x) for x in rest.split()])
        except ValueError:
            raise IoError(f"{path}:{k}: {key.strip()} must be numbers") from None
        if vals.size != 12 or not np.isfinite(vals).all():
            raise IoError(f"{path}:{k}: {key.strip()} must be 12 finite numbers, got {vals.size}")
        out[key.strip()] = vals.reshape(3, 4)
    for key in ("P0", "P1"):
        if key not in out:
            raise IoError(f"{path}: missing {key}:")
    return out


def read_kitti_times(path: Path) -> list[int]:
    """``times.txt``: seconds, one a line, as integer ns; they must increase."""
    if not path.is_file():
        raise IoError(f"{path}: no such file")
    stamps: list[int] = []
    for k, raw in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        if not raw.strip():
            continue
        try:
            t = float(raw)
        except ValueError:
            raise IoError(f"{path}:{k}: not a time in seconds: {raw.strip()!r}") from None
        if not np.isfinite(t) or t < 0:
            raise IoError(f"{path}:{k}: not a time in seconds: {raw.strip()!r}")
        t_ns = round(t * NS_PER_S)
        if stamps and t_ns <= stamps[-1]:
            raise IoError(f"{path}:{k}: time {raw.strip()} is not after the previous one")
        stamps.append(t_ns)
    if not stamps:
        raise IoError(f"{path}: no times in the file")
    return stamps


def _camera(
    name: str, P: np.ndarray, size: tuple[int, int], rate_hz: float, path: Path
) -> CameraSpec:
    K = P[:, :3]
    if K[0, 0] <= 0 or abs(K[2, 2] - 1.0) > 1e-9:
        raise IoError(f"{path}: {name}'s P has no camera matrix in its first three columns")
    x = -P[0, 3] / K[0, 0]
    try:
        lens = PinholeCamera(K.copy(), np.zeros(0), size[0], size[1])
        return CameraSpec(
            name=name,
            camera=lens,
            T_B_C=Pose(Rotation.identity(), np.array([x, 0.0, 0.0])),
            rate_hz=rate_hz,
        )
    except GeometryError as exc:
        raise IoError(f"{path}: {name}: {exc}") from None


def read_kitti_sequence(root: Path, *, poses: Path | None = None) -> VisualInertialDataset:
    """A KITTI odometry sequence folder (see the module docstring)."""
    calib = read_kitti_calib(root / "calib.txt")
    stamps = read_kitti_times(root / "times.txt")
    rate = float(NS_PER_S / np.median(np.diff(stamps))) if len(stamps) > 1 else 10.0
    issues = IssueLog()
    specs, frames = [], []
    for k in range(4):
        folder = root / f"image_{k}"
        if not folder.is_dir() or f"P{k}" not in calib:
            continue
        names = sorted(n for n in os.listdir(folder) if n.endswith(".png"))
        if len(names) != len(stamps):
            raise IoError(f"{folder}: {len(names)} images for {len(stamps)} times in times.txt")
        first = cv2.imread(str(folder / names[0]), cv2.IMREAD_UNCHANGED)
        if first is None:
            raise IoError(f"{folder / names[0]}: missing or corrupt image")
        size = (int(first.shape[1]), int(first.shape[0]))
        specs.append(_camera(f"cam{k}", calib[f"P{k}"], size, rate, root / "calib.txt"))
        for n, t in zip(names, stamps, strict=True):
            f = str(folder / n)
            frames.append(
                ImageFrame(
                    t_ns=t, camera=f"cam{k}", load=functools.partial(load_image, f), origin=f
                )
            )
    if not specs:
        raise IoError(f"{root}: no image_0/ folder")
    rig = Rig(name=root.name, cameras=tuple(specs), imu=None)
    gt = None
    if poses is not None:
        gt = _kitti_groundtruth(poses, stamps)
    return VisualInertialDataset(
        name=root.name,
        root=root,
        kind="kitti",
        rig=rig,
        frames=sort_frames(frames, rig.camera_names),
        imu=ImuTable.empty(),
        groundtruth=gt,
        issues=issues.freeze(),
    )


def _kitti_groundtruth(poses: Path, stamps: list[int]) -> GroundTruth:
    from quadnav.io.trajectory_io import read_kitti

    traj = read_kitti(poses)
    if len(traj.t_ns) != len(stamps):
        raise IoError(f"{poses}: {len(traj.t_ns)} poses for {len(stamps)} times in times.txt")
    stamped = Trajectory(
        t_ns=np.asarray(stamps, dtype=np.int64),
        p_W_B=traj.p_W_B,
        q_W_B_xyzw=traj.q_W_B_xyzw,
        name=traj.name,
    )
    return GroundTruth(stamped, source=str(poses))
