"""The structure of an initialisation window from a stereo rig (VINS-Fusion's stereo start):
metric from the first frame, no parallax needed over time.

The first frame's corners found in the second camera are triangulated with the pair's baseline
(points in the first left camera ``C0``); each later frame is placed by PnP with RANSAC on the
points it sees, and its own stereo corners not yet in the map are added. The result is an
:class:`~quadnav.vio.sfm.SfmResult` in ``C0`` whose scale is 1 (metres), for the same gyro bias
and alignment as the monocular start, with the scale held."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from quadnav.geometry import Pose
from quadnav.geometry.multiview import pnp, projection, reprojection_errors, triangulate
from quadnav.odometry import FrameFeatures
from quadnav.vio.sfm import SfmResult

__all__ = ["stereo_structure"]

FloatArray = NDArray[np.float64]

#: The nearest and farthest a stereo point may be, in baselines: ORB-SLAM's close points are
#: within 40 baselines. Where the first frame has too few of them (a large hall, a corridor's far
#: end), far points up to ``FAR_DEPTH_BASELINES`` are taken as well (ORB-SLAM2's stereo start
#: takes every point with a depth): at EuRoC's 0.11 m baseline and 458 px focal length, 150
#: baselines is a disparity of 3 px.
MIN_DEPTH_BASELINES = 1.0
MAX_DEPTH_BASELINES = 40.0
FAR_DEPTH_BASELINES = 150.0
#: The largest reprojection error (px) of a new stereo point in either view.
MAX_REPROJECTION_PX = 1.5


def _stereo_points(
    frame: FrameFeatures,
    T_C0_C: Pose,
    T_L_R: Pose,
    points: dict[int, FloatArray],
    focal_px: float,
    max_depth_baselines: float = MAX_DEPTH_BASELINES,
) -> None:
    """Add the frame's stereo corners that have no point yet (in ``C0``), checked for depth
    and reprojection in both views (``MAX_REPROJECTION_PX`` at ``focal_px``)."""
    at = {int(j): k for k, j in enumerate(frame.ids)}
    new = [k for k, j in enumerate(frame.stereo_ids.tolist()) if int(j) not in points]
    if not new:
        return
    ids = [int(frame.stereo_ids[k]) for k in new]
    left = np.array([frame.xy[at[j], :2] for j in ids], np.float64)
    right = np.asarray(frame.stereo_xy, np.float64)[new, :2]
    P = np.array([projection(T_C0_C), projection(T_C0_C @ T_L_R)])
    pts, z = triangulate(np.stack([left, right], axis=1), P)
    b = float(np.linalg.norm(T_L_R.p_A_B))
    err = np.maximum(
        reprojection_errors(P[0], pts, left)[0], reprojection_errors(P[1], pts, right)[0]
    )
    ok = (
        np.isfinite(pts).all(axis=1)
        & (np.nan_to_num(z[:, 0]) > MIN_DEPTH_BASELINES * b)
        & (np.nan_to_num(z[:, 0]) < max_depth_baselines * b)
        & (err * focal_px < MAX_REPROJECTION_PX)
    )
    for k in np.flatnonzero(ok):
        points[ids[k]] = pts[k]


def stereo_structure(
    frames: Sequence[FrameFeatures],
    T_L_R: Pose,
    *,
    focal_px: float = 460.0,
    min_points: int = 20,
) -> SfmResult | str:
    """The window's cameras ``T_C0_C`` and points in ``C0``, metric; or why not (too few stereo
    points in the first frame, a frame PnP could not place)."""
    if len(frames) < 2:
        return f"a stereo window needs at least 2 frames, got {len(frames)}"
    points: dict[int, FloatArray] = {}
    poses = [Pose.identity()]
    far = MAX_DEPTH_BASELINES
    _stereo_points(frames[0], poses[0], T_L_R, points, focal_px, far)
    if len(points) < min_points:
        far = FAR_DEPTH_BASELINES
        _stereo_points(frames[0], poses[0], T_L_R, points, focal_px, far)
    if len(points) < min_points:
        return f"the first frame has {len(points)} stereo points within {far:g} baselines, under {min_points}"
    for k, f in enumerate(frames[1:], start=1):
        ids = [int(j) for j in f.ids if int(j) in points]
        at = {int(j): i for i, j in enumerate(f.ids)}
        if len(ids) < min_points:
            return f"window frame {k} sees {len(ids)} of the stereo points, under {min_points}"
        res = pnp(
            np.array([points[j] for j in ids]), np.array([f.xy[at[j], :2] for j in ids]),
            ransac_threshold=2.0 / focal_px, min_points=min_points, seed=k,
        )  # fmt: skip
        if res is None:
            return f"PnP could not place window frame {k} on {len(ids)} stereo points"
        poses.append(res.T_W_C)
        _stereo_points(f, res.T_W_C, T_L_R, points, focal_px, far)
    rms = _rms_px(frames, poses, points, focal_px)
    return SfmResult(
        T_C0_C=tuple(poses), points_C0=points, reference=0, parallax_px=0.0, reprojection_px=rms
    )


def _rms_px(
    frames: Sequence[FrameFeatures], poses: list[Pose], points: dict[int, FloatArray], focal: float
) -> float:
    err = []
    for f, T in zip(frames, poses, strict=True):
        ids = [k for k, j in enumerate(f.ids) if int(j) in points]
        if ids:
            X = np.array([points[int(f.ids[k])] for k in ids])
            e, _ = reprojection_errors(projection(T), X, f.xy[ids, :2])
            err.append(e[np.isfinite(e)])
    e = np.concatenate(err) if err else np.zeros(0)
    return float(np.sqrt(np.mean(e**2)) * focal) if len(e) else float("inf")
