"""EuRoC ASL folders (``mav0/cam*/``, ``imu0/``, ground truth) and TUM-VI's export of them.

EuRoC: each sensor's ``sensor.yaml`` gives its calibration (``T_BS``, ``rate_hz``,
``resolution``, ``intrinsics``, ``distortion_model``, ``distortion_coefficients``, IMU noise
densities). TUM-VI: the same ``mav0/`` layout with ``mocap0/data.csv`` as ground truth and the
calibration in ``dso/camchain.yaml`` (Kalibr) and ``dso/imu_config.yaml``. Ground truth, in
order of preference: ``state_groundtruth_estimate0`` (pose, velocity, biases), ``vicon0`` /
``mocap0`` (pose), ``leica0`` (position only).

Images are not opened here: each frame holds its file name; a listed file that does not exist
is rejected and counted (the folder is listed once); a corrupt one fails when its pixels are
asked for, naming the file.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from pathlib import Path

import numpy as np

from quadnav.errors import GeometryError, IoError
from quadnav.geometry.rotations import Pose
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.datasets.depth import read_depth
from quadnav.io.datasets.files import (
    load_image,
    pose_of_4x4,
    rate_of_stamps,
    read_image_list,
    read_table,
    read_yaml,
    yaml_numbers,
)
from quadnav.io.datasets.kalibr import camera_of, noise_from, read_camchain, read_kalibr_imu
from quadnav.io.datasets.types import (
    GroundTruth,
    ImuTable,
    IssueLog,
    VisualInertialDataset,
    sort_frames,
)
from quadnav.messages import ImageFrame
from quadnav.rig import CameraSpec, ImuSpec, Rig

__all__ = ["find_mav0", "read_asl", "read_euroc_camera", "read_euroc_imu"]

_GT_FOLDERS = ("state_groundtruth_estimate0", "vicon0", "mocap0", "leica0")


def find_mav0(root: Path) -> Path | None:
    """``root/mav0`` or ``root`` itself when it is a ``mav0`` folder (None otherwise)."""
    if (root / "mav0").is_dir():
        return root / "mav0"
    if root.name == "mav0" and root.is_dir():
        return root
    return None


def camera_folders(mav0: Path) -> list[Path]:
    found = [
        p for p in mav0.iterdir() if p.is_dir() and p.name[:3] == "cam" and p.name[3:].isdigit()
    ]
    return sorted(found, key=lambda p: int(p.name[3:]))


def read_euroc_camera(folder: Path) -> CameraSpec:
    """A camera from its EuRoC ``sensor.yaml``."""
    path = folder / "sensor.yaml"
    doc = read_yaml(path)
    if doc.get("camera_model", "pinhole") != "pinhole":
        raise IoError(f"{path}: camera_model {doc.get('camera_model')!r} is not pinhole")
    for key in ("distortion_model", "rate_hz"):
        if key not in doc:
            raise IoError(f"{path}: missing key {key!r}")
    lens = camera_of(
        yaml_numbers(doc, "intrinsics", path, 4),
        yaml_numbers(doc, "distortion_coefficients", path),
        doc["distortion_model"],
        yaml_numbers(doc, "resolution", path, 2),
        path,
    )
    offset = yaml_numbers(doc, "time_offset_ns", path, 1)[0] if "time_offset_ns" in doc else 0.0
    exposure = yaml_numbers(doc, "exposure_s", path, 1)[0] if "exposure_s" in doc else 0.0
    try:
        return CameraSpec(
            name=folder.name,
            camera=lens,
            T_B_C=pose_of_4x4(yaml_numbers(doc, "T_BS", path, 16), path, "T_BS"),
            rate_hz=yaml_numbers(doc, "rate_hz", path, 1)[0],
            time_offset_ns=int(offset),
            exposure_s=exposure,
        )
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None


def read_euroc_imu(folder: Path) -> ImuSpec:
    """The IMU from its EuRoC ``sensor.yaml``."""
    path = folder / "sensor.yaml"
    doc = read_yaml(path)
    noise = noise_from(doc, path)
    T = pose_of_4x4(yaml_numbers(doc, "T_BS", path, 16), path, "T_BS") if "T_BS" in doc else None
    try:
        return ImuSpec(
            rate_hz=yaml_numbers(doc, "rate_hz", path, 1)[0],
            noise=noise,
            T_B_I=T or Pose.identity(),
            name=folder.name,
        )
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None


def camera_frames(folder: Path, issues: IssueLog) -> list[ImageFrame]:
    """The frames listed in ``folder/data.csv``, each loading ``folder/data/<file>`` on demand."""
    csv = folder / "data.csv"
    lines, stamps, names = read_image_list(csv, issues)
    data = folder / "data"
    present = set(os.listdir(data)) if data.is_dir() else set()
    if not present and names:
        raise IoError(f"{data}: no such folder (or no image in it), listed by {csv}")
    frames = []
    for line, t, name in zip(lines, stamps, names, strict=True):
        if name not in present:
            where = f"{folder.name}/data.csv:{line} ({name})"
            issues.reject("missing images", where, camera=folder.name)
            continue
        file = str(data / name)
        frames.append(
            ImageFrame(
                t_ns=t,
                camera=folder.name,
                load=functools.partial(load_image, file),
                origin=f"{file} ({folder.name}/data.csv:{line})",
            )
        )
    return frames


def read_imu_rows(folder: Path, issues: IssueLog) -> ImuTable:
    """``imu0/data.csv``: ``t_ns, w_x, w_y, w_z, a_x, a_y, a_z``; unreadable, NaN, repeated and
    out-of-order rows rejected and counted (:func:`read_table`)."""
    table = read_table(folder / "data.csv", 6, issues, "IMU rows")
    return ImuTable(table.t_ns, table.values[:, 0:3], table.values[:, 3:6])


def _gt_body(folder: Path, T_R_S: Trajectory) -> Trajectory:
    """The body's poses from the tracked sensor's (``T_R_B = T_R_S T_BS^-1``)."""
    yaml_path = folder / "sensor.yaml"
    if not yaml_path.is_file():
        return T_R_S
    doc = read_yaml(yaml_path)
    if "T_BS" not in doc:
        return T_R_S
    T_S_B = pose_of_4x4(yaml_numbers(doc, "T_BS", yaml_path, 16), yaml_path, "T_BS").inverse()
    if np.allclose(T_S_B.matrix(), np.eye(4)):
        return T_R_S
    from scipy.spatial.transform import Rotation

    R = Rotation.from_quat(T_R_S.q_W_B_xyzw)
    p = T_R_S.p_W_B + R.apply(T_S_B.p_A_B)
    q = (R * T_S_B.R_A_B).as_quat()
    return Trajectory(t_ns=T_R_S.t_ns, p_W_B=p, q_W_B_xyzw=q, name=T_R_S.name)


def read_groundtruth(mav0: Path, issues: IssueLog) -> GroundTruth | None:
    """The first ground truth folder present (see the module docstring)."""
    for name in _GT_FOLDERS:
        folder = mav0 / name
        if (folder / "data.csv").is_file():
            break
    else:
        return None
    n = {"state_groundtruth_estimate0": 16, "leica0": 3}.get(name, 7)
    tab = read_table(folder / "data.csv", n, issues, "ground-truth rows")
    v = tab.values
    q = v[:, [4, 5, 6, 3]] if n >= 7 else np.tile([0.0, 0.0, 0.0, 1.0], (len(v), 1))
    try:
        traj = Trajectory(t_ns=tab.t_ns, p_W_B=v[:, 0:3], q_W_B_xyzw=q, name=name)
        traj = _gt_body(folder, traj) if n >= 7 else traj
        if n == 16:
            return GroundTruth(traj, v[:, 7:10], v[:, 10:13], v[:, 13:16], source=name)
        return GroundTruth(traj, orientation_known=n >= 7, source=name)
    except GeometryError as exc:
        raise IoError(f"{folder / 'data.csv'}: {exc}") from None


def _calibration_source(mav0: Path, calib: Path | None) -> Path:
    """Where the calibration is: a camchain file, or a ``mav0`` folder of sensor.yaml files
    (``calib``'s when it is an EuRoC folder; TUM-VI's ``dso/camchain.yaml`` before the
    folder's own sensor.yaml files)."""
    if calib is not None and calib.is_dir():
        found = find_mav0(calib)
        if found is None:
            raise IoError(f"{calib}: no mav0/ folder (not an EuRoC calibration)")
        return found
    if calib is not None:
        return calib
    tumvi = mav0.parent / "dso" / "camchain.yaml"
    return tumvi if tumvi.is_file() else mav0


def _rig(
    mav0: Path, cams: list[Path], frames: dict[str, list[ImageFrame]], calib: Path | None
) -> Rig:
    """The rig from sensor.yaml files or from a Kalibr camchain (see _calibration_source)."""
    source = _calibration_source(mav0, calib)
    if source.is_file():
        rates = {c.name: rate_of_stamps([f.t_ns for f in frames[c.name]]) for c in cams}
        specs = read_camchain(source, rates)
        imu = _tumvi_imu(source.parent, mav0 / "imu0")
    elif (source / cams[0].name / "sensor.yaml").is_file():
        specs = tuple(read_euroc_camera(c) for c in camera_folders(source))
        imu = read_euroc_imu(source / "imu0") if (source / "imu0").is_dir() else None
    else:
        raise IoError(
            f"{mav0}: no calibration: neither {source / cams[0].name / 'sensor.yaml'} nor "
            f"{mav0.parent / 'dso' / 'camchain.yaml'} exists"
        )
    if [s.name for s in specs] != [c.name for c in cams]:
        raise IoError(
            f"{mav0}: the calibration has cameras {[s.name for s in specs]}, "
            f"the folder {[c.name for c in cams]}"
        )
    try:
        return Rig(name=mav0.parent.name, cameras=specs, imu=imu, depth=read_depth(mav0)[0])
    except GeometryError as exc:
        raise IoError(f"{mav0}: {exc}") from None


def _tumvi_imu(calib_dir: Path, imu_folder: Path) -> ImuSpec | None:
    for name in ("imu_config.yaml", "imu.yaml"):
        if (calib_dir / name).is_file():
            return read_kalibr_imu(calib_dir / name)
    if (imu_folder / "sensor.yaml").is_file():
        return read_euroc_imu(imu_folder)
    if (imu_folder / "data.csv").is_file():
        raise IoError(f"{calib_dir}: no imu_config.yaml or imu.yaml for {imu_folder / 'data.csv'}")
    return None


def read_asl(
    root: Path, *, calibration: Path | None = None, kind: str = "euroc"
) -> VisualInertialDataset:
    """An EuRoC ASL folder (``root`` holds ``mav0/``); ``calibration`` (a Kalibr camchain or an
    EuRoC folder) takes the place of the files' own."""
    mav0 = find_mav0(root)
    if mav0 is None:
        raise IoError(f"{root}: no mav0/ folder (not an EuRoC ASL dataset)")
    cams = camera_folders(mav0)
    if not cams:
        raise IoError(f"{mav0}: no cam0/ folder")
    issues = IssueLog()
    frames = {c.name: camera_frames(c, issues) for c in cams}
    rig = _rig(mav0, cams, frames, calibration)
    imu = read_imu_rows(mav0 / "imu0", issues) if rig.imu is not None else ImuTable.empty()
    gt = read_groundtruth(mav0, issues)
    exposure = {c.name: c.exposure_s for c in rig.cameras}
    all_frames = [
        dataclasses.replace(f, exposure_s=exposure[f.camera]) if exposure[f.camera] else f
        for c in cams
        for f in frames[c.name]
    ]
    return VisualInertialDataset(
        name=mav0.parent.name,
        root=mav0.parent,
        kind=kind,
        rig=rig,
        frames=sort_frames(all_frames, rig.camera_names),
        imu=imu,
        groundtruth=gt,
        issues=issues.freeze(),
        depth=read_depth(mav0)[1],  # the sensor.yaml read again: two small files
    )
