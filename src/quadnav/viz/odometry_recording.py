"""The recording of a visual odometry run (``quadnav vio`` / ``quadnav slam``'s folder) for
rerun's viewer, built from the folder's files (:mod:`quadnav.io.odometry_run_files`).

In the world (the odometry's, ENU-like, z up), on the timeline ``t``: the estimate and the
ground truth (aligned onto the estimate by the rigid motion that best fits their positions, for
the eye only: the metrics have their own alignments) whole and as they go, with ``--loop`` the
keyframes as the last pose graph has them, a SLAM's frames through its final map; the body's
pose with its axes and the camera's frustum; each keyframe as a small frustum from its time
on; the landmarks from the time each was first seen (the map growing); the accepted loops as
edges between their keyframes; the position's 3-sigma ellipsoid. Beside it the camera's image
with the features tracked in it (coloured by track length: red new, blue long), the features
tracked and the position's sigma as time series, and the events. ``viz.npz`` (written with
``--rerun``) brings the image, the features, the landmarks and the covariances; a folder without
it shows the rest. A blueprint per kind (VIO, VIO with loop closure, SLAM). Each stream is
bounded as in a navigation run's recording.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.geometry.multiview import kabsch
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.odometry_run_files import OdometryRunFiles, VizCapture
from quadnav.viz.nav_recording import ELLIPSOID_SIGMAS, MAX_POINTS, MAX_SCALARS
from quadnav.viz.recording import (
    RecordingInfo,
    RecordingLog,
    decimation,
    every_of,
    eye_on,
    finish_info,
    log_camera,
    log_images,
    log_trajectory,
    log_vehicle,
    open_recording,
)

if TYPE_CHECKING:
    import rerun.blueprint as rrb

__all__ = [
    "MAX_MAP_POINTS",
    "MAX_ODOMETRY_ELLIPSOIDS",
    "odometry_blueprint",
    "recording_kind",
    "write_odometry_recording",
]

#: Landmarks drawn (every n-th, at most this many).
MAX_MAP_POINTS = 50_000
#: Position ellipsoids drawn along the estimate.
MAX_ODOMETRY_ELLIPSOIDS = 30
#: A keyframe's frustum: its depth (m).
KEYFRAME_FRUSTUM_M = 0.12
#: Keyframes drawn (every n-th, at most this many).
MAX_KEYFRAMES = 1000

_COLOURS = {
    "truth": (40, 160, 40), "estimate": (30, 100, 230), "keyframes_loop": (230, 120, 20),
    "estimate_final": (230, 120, 20), "keyframes": (120, 120, 255), "map": (150, 150, 150),
    "loop": (255, 40, 200),
}  # fmt: skip
FloatArray = NDArray[np.float64]


def aligned_truth(truth: Trajectory, est: Trajectory, *, max_dt_ns: int = 20_000_000) -> FloatArray:
    """The truth's positions moved onto the estimate's world by the rotation and translation
    that best fit the positions at matching stamps (within ``max_dt_ns``); unmoved when fewer
    than three match."""
    if len(est) < 3 or len(truth) == 0:
        return truth.p_W_B
    k = np.clip(np.searchsorted(truth.t_ns, est.t_ns), 1, len(truth) - 1)
    k = np.where(np.abs(truth.t_ns[k - 1] - est.t_ns) < np.abs(truth.t_ns[k] - est.t_ns), k - 1, k)
    ok = np.abs(truth.t_ns[k] - est.t_ns) <= max_dt_ns
    if ok.sum() < 3:
        return truth.p_W_B
    a, b = truth.p_W_B[k[ok]], est.p_W_B[ok]
    mu_a, mu_b = a.mean(axis=0), b.mean(axis=0)
    R, _ = kabsch(a - mu_a, b - mu_b)
    return np.asarray((truth.p_W_B - mu_a) @ R.T + mu_b, dtype=np.float64)


def _trajectories(log: RecordingLog, files: OdometryRunFiles) -> None:
    est = files.estimate
    log_trajectory(log, "estimate", est.t_ns, est.p_W_B, MAX_POINTS, _COLOURS["estimate"])
    if files.truth is not None:
        p = aligned_truth(files.truth, est)
        log_trajectory(log, "truth", files.truth.t_ns, p, MAX_POINTS, _COLOURS["truth"])
    for name in ("keyframes_loop", "estimate_final"):
        traj = getattr(files, name)
        if traj is not None and len(traj):
            log_trajectory(log, name, traj.t_ns, traj.p_W_B, MAX_POINTS, _COLOURS[name])


def _vehicle(log: RecordingLog, files: OdometryRunFiles) -> None:
    """The body's pose with its axes; the camera's frustum on it (with ``viz.npz``)."""
    est = files.estimate
    log_vehicle(log, est.t_ns, est.p_W_B, est.q_W_B_xyzw, MAX_POINTS)
    cap = files.capture
    if cap is not None:
        log_camera(log, "world/vehicle/camera", cap.T_B_C, cap.K, (cap.width, cap.height))


def _frustum_lines(T_W_C: FloatArray, K: FloatArray, size: tuple[int, int]) -> list[FloatArray]:
    """A camera's frustum ``KEYFRAME_FRUSTUM_M`` deep: four edges from its centre and the far
    rectangle, as line strips in the world."""
    fx, fy, cx, cy = K
    w, h = size
    uv = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
    corners = np.column_stack([(uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy, np.ones(4)])
    far_C = corners * KEYFRAME_FRUSTUM_M
    far_W = far_C @ T_W_C[:3, :3].T + T_W_C[:3, 3]
    o = T_W_C[:3, 3]
    return [np.array([o, c]) for c in far_W] + [np.vstack([far_W, far_W[:1]])]


def _keyframes(log: RecordingLog, files: OdometryRunFiles) -> None:
    """Each keyframe as a small frustum (the rig's camera on it; with no ``viz.npz``, a 90
    degree one looking along the body's x) from its time on."""
    import rerun as rr

    kf = files.keyframes
    keep = decimation(len(kf), MAX_KEYFRAMES)
    if len(keep) == 0:
        return
    cap = files.capture
    if cap is not None:
        T_B_C, K, size = cap.T_B_C, cap.K, (cap.width, cap.height)
    else:
        T_B_C, K, size = np.eye(4), np.array([1.0, 1.0, 1.0, 1.0]), (2, 2)
        T_B_C[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    T_W_B = np.tile(np.eye(4), (len(keep), 1, 1))
    T_W_B[:, :3, :3] = Rotation.from_quat(kf.q_W_B_xyzw[keep]).as_matrix()
    T_W_B[:, :3, 3] = kf.p_W_B[keep]
    strips = [s for T in T_W_B for s in _frustum_lines(T @ T_B_C, K, size)]
    per = len(strips) // len(keep)
    lines = rr.LineStrips3D.columns(
        strips=strips, colors=[_COLOURS["keyframes"]] * len(strips), radii=[0.003] * len(strips)
    ).partition([per] * len(keep))
    log.columns("world/keyframes", kf.t_ns[keep], lines, every_of(keep))


def _map(log: RecordingLog, cap: VizCapture) -> None:
    """The landmarks, each from the time it was first seen, at its last position."""
    import rerun as rr

    keep = decimation(len(cap.landmark_ids), MAX_MAP_POINTS)
    if len(keep) == 0:
        return
    t = cap.landmark_t_ns[keep]
    stamps, starts = np.unique(t, return_index=True)
    lengths = np.diff(np.append(starts, len(t)))
    points = rr.Points3D.columns(
        positions=cap.landmark_W[keep], colors=[_COLOURS["map"]] * len(keep),
        radii=[0.01] * len(keep),
    ).partition(lengths.tolist())  # fmt: skip
    log.columns("world/map", stamps, points, every_of(keep))


def _nearest(t_ns: NDArray[np.int64], t: int) -> int:
    k = int(np.clip(np.searchsorted(t_ns, t), 1, max(len(t_ns) - 1, 1)))
    return k - 1 if len(t_ns) < 2 or abs(int(t_ns[k - 1]) - t) <= abs(int(t_ns[k]) - t) else k


def _loops(log: RecordingLog, files: OdometryRunFiles) -> None:
    """Each accepted loop as an edge between its keyframes (as the last pose graph has them,
    or as published), from the time it was found."""
    import rerun as rr

    kf = files.keyframes_loop if files.keyframes_loop is not None else files.keyframes
    if not files.loops or len(kf) == 0:
        return
    loops = sorted(files.loops, key=lambda x: x[1])
    edges = [np.array([kf.p_W_B[_nearest(kf.t_ns, a)], kf.p_W_B[_nearest(kf.t_ns, b)]])
             for a, b in loops]  # fmt: skip
    strips = rr.LineStrips3D.columns(
        strips=edges, colors=[_COLOURS["loop"]] * len(edges), radii=[0.01] * len(edges)
    )
    log.columns("world/loops", np.array([b for _, b in loops], np.int64), strips)


def _ellipsoids(log: RecordingLog, files: OdometryRunFiles, cap: VizCapture) -> None:
    """The position's ``ELLIPSOID_SIGMAS``-sigma ellipsoid at frames with an estimate."""
    import rerun as rr

    est = files.estimate
    ok = np.isfinite(cap.state_cov_p_W).all(axis=(1, 2)) & np.isin(cap.state_t_ns, est.t_ns)
    rows = np.flatnonzero(ok)[decimation(int(ok.sum()), MAX_ODOMETRY_ELLIPSOIDS)]
    if len(rows) == 0:
        return
    t = cap.state_t_ns[rows]
    centres = est.p_W_B[np.searchsorted(est.t_ns, t)]
    values, vectors = np.linalg.eigh(cap.state_cov_p_W[rows])
    vectors[np.linalg.det(vectors) < 0, :, 2] *= -1.0
    shapes = rr.Ellipsoids3D.columns(
        centers=centres, half_sizes=ELLIPSOID_SIGMAS * np.sqrt(np.clip(values, 0.0, None)),
        quaternions=Rotation.from_matrix(vectors).as_quat(),
        colors=[_COLOURS["estimate"]] * len(rows), line_radii=[0.002] * len(rows),
    )  # fmt: skip
    log.columns("world/estimate/sigma", t, shapes, max(1, len(cap.state_t_ns) // len(rows)))


def _track_colours(lengths: NDArray[np.int64]) -> NDArray[np.uint8]:
    """Red for a new feature to blue for one tracked 20 frames or more (VINS-Mono's colours)."""
    a = np.clip(lengths / 20.0, 0.0, 1.0)
    return np.column_stack([255 * (1 - a), np.zeros_like(a), 255 * a]).astype(np.uint8)


def _camera(log: RecordingLog, cap: VizCapture) -> None:
    """The images (JPEG, as captured) with the features tracked in them."""
    import rerun as rr

    n = len(cap.image_t_ns)
    if n == 0:
        return
    blobs = [cap.image_bytes(k) for k in range(n)]
    log_images(log, "camera/image", cap.image_t_ns, blobs, cap.image_every)
    if len(cap.feature_image) == 0:
        return
    counts = np.bincount(cap.feature_image, minlength=n)
    has = np.flatnonzero(counts)
    features = rr.Points2D.columns(
        positions=cap.feature_uv, colors=_track_colours(cap.feature_length),
        radii=[2.0] * len(cap.feature_uv),
    ).partition(counts[has].tolist())  # fmt: skip
    log.columns("camera/image/features", cap.image_t_ns[has], features, cap.image_every)


def _series(log: RecordingLog, cap: VizCapture) -> None:
    """Features tracked, and the position's sigma (m, the root of the covariance's trace)."""
    import rerun as rr

    keep = decimation(len(cap.state_t_ns), MAX_SCALARS)
    t = cap.state_t_ns[keep]
    tracked = rr.Scalars.columns(scalars=cap.state_tracked[keep].astype(np.float64))
    log.columns("series/tracked", t, tracked, every_of(keep))
    trace = np.trace(cap.state_cov_p_W[keep], axis1=1, axis2=2)
    ok = np.isfinite(trace)
    sigma = rr.Scalars.columns(scalars=np.sqrt(np.clip(trace[ok], 0.0, None)))
    log.columns("series/sigma_m", t[ok], sigma, every_of(keep))


_LEVELS = {"failure": "ERROR", "rejected_image": "WARN", "reinitialized": "WARN"}


def _events(log: RecordingLog, files: OdometryRunFiles) -> None:
    import rerun as rr

    for t_ns, kind, detail in files.events:
        log.at(t_ns)
        log.rec.log("events", rr.TextLog(f"{kind}: {detail}", level=_LEVELS.get(kind, "INFO")))
    log.rows["/events"] = len(files.events)


def odometry_blueprint(kind: str, positions: FloatArray | None = None) -> rrb.Blueprint:
    """The layout of a ``kind`` run (``vio``, ``vio_loop``, ``slam``): the 3-D view (what was
    logged up to the time shown: the map growing; looking at ``positions``) beside the camera,
    the time series and the events; opened at the run's end."""
    import rerun.blueprint as rrb

    title = {"vio": "VIO", "vio_loop": "VIO with loop closure", "slam": "SLAM"}[kind]
    up_to_now = rrb.VisibleTimeRange(
        "t", start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.cursor_relative()
    )
    eye = eye_on(positions if positions is not None else np.zeros((0, 3)))
    world = rrb.Spatial3DView(name=title, origin="/world", time_ranges=[up_to_now],
                              eye_controls=eye)  # fmt: skip
    side = rrb.Vertical(
        rrb.Spatial2DView(name="camera", origin="/camera/image"),
        rrb.TimeSeriesView(name="features tracked", origin="/series/tracked"),
        rrb.TimeSeriesView(name="position sigma (m)", origin="/series/sigma_m"),
        rrb.TextLogView(name="events", origin="/events"),
        row_shares=[4, 2, 2, 2],
    )
    return rrb.Blueprint(
        rrb.Horizontal(world, side, column_shares=[3, 2]),
        rrb.TimePanel(timeline="t", play_state="following", expanded=False),
        collapse_panels=True,
    )


def _start(files: OdometryRunFiles) -> int:
    """The timeline's zero: the run's first stamp (its ground truth's, estimate's, images')."""
    firsts = [int(x.t_ns[0]) for x in (files.truth, files.estimate, files.keyframes)
              if x is not None and len(x)]  # fmt: skip
    if files.capture is not None and len(files.capture.frame_t_ns):
        firsts.append(int(files.capture.frame_t_ns[0]))
    return min(firsts, default=0)


def recording_kind(files: OdometryRunFiles) -> str:
    """``slam``, ``vio_loop`` (loop closure ran) or ``vio``."""
    if files.kind == "slam":
        return "slam"
    return "vio_loop" if files.keyframes_loop is not None else "vio"


def write_odometry_recording(files: OdometryRunFiles, path: Path) -> RecordingInfo:
    """Write the recording of a VIO or SLAM run to ``path`` (an ``.rrd``), replaced whole."""
    blueprint = odometry_blueprint(recording_kind(files), files.estimate.p_W_B)
    with open_recording(path, files.run_dir.name, blueprint, t0_ns=_start(files)) as log:
        _trajectories(log, files)
        _vehicle(log, files)
        _keyframes(log, files)
        _loops(log, files)
        cap = files.capture
        if cap is not None:
            _map(log, cap)
            _ellipsoids(log, files, cap)
            _camera(log, cap)
            _series(log, cap)
        _events(log, files)
    return finish_info(log, path)
