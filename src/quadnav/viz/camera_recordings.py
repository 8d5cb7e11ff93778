"""The recordings of a ``quadnav markers`` run and of a dataset ``quadnav dataset make`` wrote,
built from their files.

Markers: the targets (markers, boards, diamonds) where the configuration puts them, the vehicle's
pose from the markers in each frame with its body axes and the camera's frustum on it (the mount
and the calibration of ``config.yaml``), the drawn frames with the detections (``images/``, else
``overlay.mp4``; a run that wrote neither shows the rest), the markers seen, the reprojection
error and the timing as time series, and each change of the reason a frame has no pose.

A dataset: the ground truth whole and as it goes, the body's pose with every camera's frustum,
each camera's images, the IMU's angular rate and specific force as time series, on a timeline
from the dataset's first stamp. The world's mesh is not drawn (the dataset does not hold it).

Images: every n-th frame (at most ``MAX_IMAGES`` a camera), downsampled by a whole factor to at
most ``MAX_IMAGE_WIDTH`` pixels wide, JPEG; ``recording.json`` says every how many.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from quadnav.io.folder_files import MarkersRunFiles
from quadnav.units import s_to_ns
from quadnav.viz.nav_recording import MAX_POINTS, MAX_SCALARS
from quadnav.viz.recording import (
    MAX_IMAGE_WIDTH,
    MAX_IMAGES,
    RecordingInfo,
    RecordingLog,
    finish_info,
    flight_blueprint,
    jpeg_of,
    log_camera,
    log_events,
    log_images,
    log_scalars,
    log_trajectory,
    log_vehicle,
    open_recording,
    small_size,
)

if TYPE_CHECKING:
    from quadnav.io.datasets import VisualInertialDataset

__all__ = ["MARKER_SERIES", "target_outlines", "write_dataset_recording", "write_markers_recording"]

#: ``poses.csv``'s columns drawn as time series.
MARKER_SERIES = ("n_markers", "rms_px", "detect_ms", "pose_ms")
FloatArray = NDArray[np.float64]


def _rectangle(T_W: FloatArray, x0: float, y0: float, x1: float, y1: float) -> FloatArray:
    """A closed rectangle in a target's face (z = 0), in the world."""
    face = np.array(
        [[x0, y0, 0, 1], [x1, y0, 0, 1], [x1, y1, 0, 1], [x0, y1, 0, 1], [x0, y0, 0, 1]]
    )
    return (face @ T_W.T)[:, :3]


def target_outlines(files: MarkersRunFiles) -> list[tuple[str, FloatArray]]:
    """Each target of the run's configuration, named, as its outline in the world."""
    from quadnav.io.config import load_config
    from quadnav.vision.config import MarkersConfig

    cfg = load_config(MarkersConfig, files.config, [])
    seen = files.stats.get("world_marker_id")
    mmap = cfg.marker_map(seen if isinstance(seen, int) else None)
    out = []
    for m in mmap.markers.values():
        h = m.length_m / 2
        out.append((f"marker {m.id}", _rectangle(m.T_W_M.matrix(), -h, -h, h, h)))
    for b in mmap.boards:
        s = b.spec
        board = _rectangle(
            b.T_W_O.matrix(), 0, 0, s.squares_x * s.square_m, s.squares_y * s.square_m
        )
        out.append((f"board {s.squares_x}x{s.squares_y}", board))
    for d in mmap.diamonds:
        h = 1.5 * d.spec.square_m
        out.append(("diamond", _rectangle(d.T_W_D.matrix(), -h, -h, h, h)))
    return out


def _camera(files: MarkersRunFiles, width: int) -> tuple[FloatArray, FloatArray, tuple[int, int]]:
    """The camera's mount ``T_B_C``, its ``(fx, fy, cx, cy)`` and size, downsampled to
    ``width`` (a 60 degree view when the calibration file is gone)."""
    from quadnav.io.config import load_config
    from quadnav.io.opencv_yaml import read_camera_yaml
    from quadnav.vision.config import MarkersConfig

    cfg = load_config(MarkersConfig, files.config, [])
    T_B_C = cfg.T_B_C().matrix()
    if cfg.camera_file is not None and Path(cfg.camera_file).is_file():
        cam = read_camera_yaml(cfg.camera_file)
        K, size = np.array([cam.fx, cam.fy, cam.K[0, 2], cam.K[1, 2]]), (cam.width, cam.height)
    else:
        K, size = np.array([554.3, 554.3, 320.0, 240.0]), (640, 480)
    scale = size[0] / width
    return T_B_C, K / scale, (width, round(size[1] / scale))


def _frames(files: MarkersRunFiles) -> tuple[list[int], list[bytes], int, int]:
    """The drawn frames kept (their indices, JPEGs), every how many, and their width."""
    from quadnav.io.frames import open_frames

    if files.frames is None:
        return [], [], 1, MAX_IMAGE_WIDTH
    n = max(len(files.poses.t_ns), 1)
    every = max(1, math.ceil(n / MAX_IMAGES))
    kept: list[int] = []
    jpegs: list[bytes] = []
    width = MAX_IMAGE_WIDTH
    for frame in open_frames(files.frames):
        if frame.index % every or frame.image is None:
            continue
        h, w = frame.image.shape[:2]
        _, size = small_size(w, h, MAX_IMAGE_WIDTH)
        kept.append(frame.index)
        jpegs.append(jpeg_of(frame.image, size))
        width = size[0]
    return kept, jpegs, every, width


def _reasons(poses_t: NDArray[np.int64], reasons: Iterable[str]) -> list[tuple[int, str]]:
    """Each change of the reason a frame has no pose (``-``: it has one again)."""
    out, last = [], "-"
    for t, why in zip(poses_t.tolist(), reasons, strict=True):
        if why != last:
            out.append((int(t), f"no pose: {why}" if why != "-" else "pose again"))
        last = why
    return out


def write_markers_recording(files: MarkersRunFiles, path: Path) -> RecordingInfo:
    """Write the recording of a ``quadnav markers`` run to ``path`` (an ``.rrd``)."""
    import rerun as rr
    import rerun.blueprint as rrb

    poses = files.poses
    p, q = poses.columns(("x_m", "y_m", "z_m")), poses.columns(("qx", "qy", "qz", "qw"))
    ok = np.isfinite(p).all(axis=1) & np.isfinite(q).all(axis=1)
    camera = rrb.Spatial2DView(name="camera", origin="/camera/image")
    series = [(name, f"/series/{name}") for name in MARKER_SERIES]
    blueprint = flight_blueprint("markers", p[ok], series, side=[camera])
    indices, jpegs, every, width = _frames(files)
    with open_recording(path, files.run_dir.name, blueprint) as log:
        outlines = target_outlines(files)
        strips = rr.LineStrips3D(
            [o for _, o in outlines], labels=[n for n, _ in outlines], colors=[(255, 200, 0)],
            radii=[0.004],
        )  # fmt: skip
        log.rec.log("world/targets", strips, static=True)
        log_trajectory(log, "markers", poses.t_ns[ok], p[ok], MAX_POINTS, (30, 100, 230))
        log_vehicle(log, poses.t_ns[ok], p[ok], q[ok], MAX_POINTS)
        T_B_C, K, size = _camera(files, width)
        log_camera(log, "world/vehicle/camera", T_B_C, K, size, depth_m=0.1)
        by_frame = dict(
            zip(poses.column("frame").astype(int).tolist(), poses.t_ns.tolist(), strict=False)
        )
        fps = float(files.stats.get("fps", 30.0) or 30.0)  # type: ignore[arg-type]
        t = [by_frame.get(k, s_to_ns(k / fps)) for k in indices]
        log_images(log, "camera/image", np.array(t, np.int64), jpegs, every)
        for name in MARKER_SERIES:
            log_scalars(log, f"series/{name}", poses.t_ns, poses.column(name), MAX_SCALARS)
        log_events(log, _reasons(poses.t_ns, poses.text["reason"]), level="INFO")
    return finish_info(log, path)


def _dataset_cameras(log: RecordingLog, dataset: VisualInertialDataset) -> list[str]:
    """Each camera's frustum on the body and its images; the cameras' entities."""
    entities = []
    for name in dataset.rig.camera_names:
        spec = dataset.rig.camera(name)
        m = spec.camera
        scale, size = small_size(m.width, m.height, MAX_IMAGE_WIDTH)
        K = np.array([m.fx, m.fy, m.K[0, 2], m.K[1, 2]]) / scale
        log_camera(log, f"world/vehicle/{name}", spec.T_B_C.matrix(), K, size, depth_m=0.15)
        frames = dataset.frames_of(name)
        every = max(1, math.ceil(len(frames) / MAX_IMAGES))
        kept = frames[::every]
        jpegs = [jpeg_of(f.image(), size) for f in kept]
        t = np.array([f.t_ns for f in kept], np.int64)
        log_images(log, f"cameras/{name}", t, jpegs, every)
        entities.append(f"/cameras/{name}")
    return entities


def write_dataset_recording(root: Path, path: Path) -> RecordingInfo:
    """Write the recording of the dataset at ``root`` (as ``quadnav dataset make`` wrote it)
    to ``path`` (an ``.rrd``)."""
    import rerun.blueprint as rrb

    from quadnav.io.datasets import open_dataset

    dataset = open_dataset(root)
    gt = dataset.groundtruth
    truth = gt.trajectory if gt is not None else None
    p = truth.p_W_B if truth is not None else np.zeros((0, 3))
    views = [rrb.Spatial2DView(name=n, origin=f"/cameras/{n}") for n in dataset.rig.camera_names]
    series = [("gyro (rad/s)", "/imu/gyro"), ("accel (m/s²)", "/imu/accel")]
    blueprint = flight_blueprint(f"dataset {dataset.name}", p, series, side=views)
    starts = [int(x.t_ns[0]) for x in (truth, dataset.imu) if x is not None and len(x.t_ns)]
    t0 = min([*starts, *([dataset.frames[0].t_ns] if dataset.frames else [])], default=0)
    with open_recording(path, Path(root).name, blueprint, t0_ns=t0) as log:
        if truth is not None:
            log_trajectory(log, "truth", truth.t_ns, p, MAX_POINTS, (40, 160, 40))
            log_vehicle(log, truth.t_ns, p, truth.q_W_B_xyzw, MAX_POINTS)
        _dataset_cameras(log, dataset)
        imu = dataset.imu
        for k, axis in enumerate("xyz"):
            log_scalars(log, f"imu/gyro/{axis}", imu.t_ns, imu.gyro_rad_s[:, k], MAX_SCALARS)
            log_scalars(log, f"imu/accel/{axis}", imu.t_ns, imu.accel_m_s2[:, k], MAX_SCALARS)
        log_events(log, [(0, str(dataset.issues.summary()))], level="INFO")
    return finish_info(log, path)
