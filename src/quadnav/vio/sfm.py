"""Vision-only structure from motion over an initialisation window, up to scale (thesis 003
§3.2, VINS-Mono's ``initial_sfm``).

The oldest frame with enough parallax against the newest (VINS: at least ``min_common`` shared
features, an average parallax over ``min_parallax_px`` at ``focal_px``) and a motion the
essential matrix can explain is the reference ``L``; that pair gives the first structure (its
baseline has length 1, which sets the scale). The frames between are put in by PnP and
triangulated against the newest and against ``L``, the older ones by PnP and against ``L``,
every other track seen twice is triangulated from its first and last views, and a bundle
adjustment (GTSAM projection factors on normalised coordinates, Huber loss) refines it all.
The result is expressed in the first frame's camera ``C0``.

A pure rotation has parallax but no baseline: a pair is also refused when the best rotation
alone (Kabsch on the bearings) leaves less than ``min_translation_px`` of median parallax.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.geometry import Pose
from quadnav.geometry.gtsam_bridge import pose3, to_pose
from quadnav.geometry.multiview import (
    essential_pose,
    kabsch,
    pnp,
    projection,
    reprojection_errors,
    triangulate,
)
from quadnav.odometry import FrameFeatures

__all__ = [
    "SfmResult",
    "average_parallax_px",
    "refine_with_rotations",
    "relative_pose",
    "rotation_only_parallax_px",
    "vision_sfm",
]

FloatArray = NDArray[np.float64]
Observations = list[dict[int, FloatArray]]

#: The smallest count of correspondences for an essential matrix or a PnP to be trusted.
MIN_INLIERS = 12
MIN_PNP = 10


@dataclass(frozen=True, slots=True, kw_only=True)
class SfmResult:
    """The window's cameras ``T_C0_C`` (one per frame, in the first frame's camera, positions up
    to one common scale), the triangulated tracks (id -> point in ``C0``), the reference frame
    that started it with its parallax to the newest, and the RMS reprojection error after the
    bundle adjustment (pixels at the focal length the window was judged with)."""

    T_C0_C: tuple[Pose, ...]
    points_C0: Mapping[int, FloatArray]
    reference: int
    parallax_px: float
    reprojection_px: float


def _xy(frame: FrameFeatures) -> FloatArray:
    return np.asarray(frame.xy, dtype=np.float64)[:, :2]


def _observations(frames: Sequence[FrameFeatures]) -> Observations:
    obs: Observations = []
    for f in frames:
        xy = _xy(f)
        good = np.asarray(np.isfinite(xy).all(axis=1), dtype=bool)
        obs.append({int(i): xy[k] for k, i in enumerate(f.ids) if bool(good[k])})
    return obs


def _common(
    a: dict[int, FloatArray], b: dict[int, FloatArray]
) -> tuple[list[int], FloatArray, FloatArray]:
    ids = sorted(a.keys() & b.keys())
    xa = np.array([a[i] for i in ids]).reshape(-1, 2)
    xb = np.array([b[i] for i in ids]).reshape(-1, 2)
    return ids, xa, xb


def average_parallax_px(xa: FloatArray, xb: FloatArray, *, focal_px: float) -> float:
    """VINS' parallax: the mean distance between the normalised coordinates, times the focal."""
    if len(xa) == 0:
        return 0.0
    return float(np.mean(np.linalg.norm(xb - xa, axis=1)) * focal_px)


def _bearings(x: FloatArray) -> FloatArray:
    b = np.column_stack([x, np.ones(len(x))])
    return np.asarray(b / np.linalg.norm(b, axis=1, keepdims=True), dtype=np.float64)


def rotation_only_parallax_px(xa: FloatArray, xb: FloatArray, *, focal_px: float) -> float:
    """The median parallax left once the rotation that best maps ``xa``'s bearings onto
    ``xb``'s is taken out: about the pixel noise for a pure rotation."""
    if len(xa) < 3:
        return 0.0
    ba, bb = _bearings(xa), _bearings(xb)
    R_b_a, _ = kabsch(ba, bb)
    angle = np.linalg.norm(np.cross(ba @ R_b_a.T, bb), axis=1)
    return float(np.median(angle) * focal_px)


def relative_pose(
    xa: FloatArray, xb: FloatArray, *, focal_px: float, rng_seed: int = 0
) -> tuple[Pose, NDArray[np.bool_]] | None:
    """``T_Ca_Cb`` (unit baseline) from normalised correspondences, by the essential matrix with
    RANSAC and the cheirality check; None with fewer than ``MIN_INLIERS`` inliers."""
    two = essential_pose(xa, xb, threshold=1.0 / focal_px, min_inliers=MIN_INLIERS, seed=rng_seed)
    return None if two is None else (two.T_Ca_Cb, two.inliers)


def _triangulate(
    T_W_Ca: Pose, T_W_Cb: Pose, xa: FloatArray, xb: FloatArray
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Points in ``W`` from two views, and which lie in front of both cameras."""
    P = np.array([projection(T_W_Ca), projection(T_W_Cb)])
    pts, z = triangulate(np.stack([xa, xb], axis=1), P)
    ok = np.isfinite(pts).all(axis=1) & (np.nan_to_num(z, nan=-1.0) > 0).all(axis=1)
    return pts, np.asarray(ok, dtype=bool)


def _add_points(
    poses: dict[int, Pose], obs: Observations, points: dict[int, FloatArray], a: int, b: int
) -> None:
    """Triangulate the tracks frames ``a`` and ``b`` share that have no point yet."""
    ids, xa, xb = _common(obs[a], obs[b])
    new = [k for k, i in enumerate(ids) if i not in points]
    if not new:
        return
    P, ok = _triangulate(poses[a], poses[b], xa[new], xb[new])
    for m, k in enumerate(new):
        if ok[m]:
            points[ids[k]] = P[m]


def _pnp(obs: dict[int, FloatArray], points: dict[int, FloatArray], guess: Pose) -> Pose | None:
    """The camera ``T_W_C`` from the known points it sees, started from ``guess``."""
    ids = [i for i in obs if i in points]
    if len(ids) < MIN_PNP:
        return None
    X = np.array([points[i] for i in ids])
    x = np.array([obs[i] for i in ids])
    res = pnp(X, x, guess=guess, min_points=MIN_PNP)
    return None if res is None else res.T_W_C


def _pick_reference(
    obs: Observations,
    *,
    focal_px: float,
    min_parallax_px: float,
    min_common: int,
    min_translation_px: float,
) -> tuple[int, Pose, float] | str:
    """The oldest frame whose pair with the newest can start the structure, ``T_CL_Cn`` and the
    pair's parallax; or why none can."""
    newest, best, best_translation = len(obs) - 1, 0.0, 0.0
    for i in range(newest):
        _, xa, xb = _common(obs[i], obs[newest])
        if len(xa) < min_common:
            continue
        parallax = average_parallax_px(xa, xb, focal_px=focal_px)
        best = max(best, parallax)
        if parallax < min_parallax_px:
            continue
        translation = rotation_only_parallax_px(xa, xb, focal_px=focal_px)
        best_translation = max(best_translation, translation)
        if translation < min_translation_px:
            continue
        rel = relative_pose(xa, xb, focal_px=focal_px)
        if rel is not None:
            return i, rel[0], parallax
    why = (
        f"best {best:.1f} px"
        if best < min_parallax_px
        else f"frames with {min_parallax_px:g} px turned but hardly moved: at most "
        f"{best_translation:.1f} px of parallax from translation, {min_translation_px:g} px needed"
        if best_translation < min_translation_px
        else "no essential matrix from those that moved"
    )
    return (
        f"no frame has {min_common} features and a translation's parallax of "
        f"{min_parallax_px:g} px with the newest ({why})"
    )


def _structure(
    obs: Observations, ref: int, T_L_Cn: Pose
) -> tuple[dict[int, Pose], dict[int, FloatArray]] | str:
    """Poses and points in the reference camera ``L``, before the bundle adjustment."""
    n = len(obs) - 1
    poses: dict[int, Pose] = {ref: Pose.identity(), n: T_L_Cn}
    points: dict[int, FloatArray] = {}
    _add_points(poses, obs, points, ref, n)
    order = [*range(ref + 1, n), *range(ref - 1, -1, -1)]
    for i in order:
        guess = poses[i - 1] if i > ref else poses[i + 1]
        pose = _pnp(obs[i], points, guess)
        if pose is None:
            return f"PnP failed for window frame {i} (too few triangulated features)"
        poses[i] = pose
        _add_points(poses, obs, points, i, n if i > ref else ref)
        if i > ref:
            _add_points(poses, obs, points, ref, i)
    seen: dict[int, list[int]] = {}
    for k, o in enumerate(obs):
        for i in o:
            seen.setdefault(i, []).append(k)
    for i, ks in seen.items():
        if i not in points and len(ks) >= 2:
            P, ok = _triangulate(
                poses[ks[0]], poses[ks[-1]], obs[ks[0]][i][None], obs[ks[-1]][i][None]
            )
            if ok[0]:
                points[i] = P[0]
    return poses, points


def _X(k: int) -> int:
    return int(gtsam.symbol("x", k))


def _L(i: int) -> int:
    return int(gtsam.symbol("l", i))


def _bundle_adjust(
    obs: Observations,
    poses: dict[int, Pose],
    points: dict[int, FloatArray],
    *,
    ref: int,
    focal_px: float,
    iterations: int,
    rotations: tuple[Sequence[Rotation], float] | None = None,
) -> tuple[dict[int, Pose], dict[int, FloatArray], float]:
    """GTSAM LM over all cameras and points (normalised coordinates, sigma one pixel, Huber);
    the reference camera held by a tight prior and the newest's position by another (the
    gauge: origin, orientation and scale). ``rotations``: consecutive cameras' relative
    rotations ``R_Ck_Ck1`` from the gyro and their sigma (rad), as between-factors that leave
    the translations free."""
    n = len(obs) - 1
    K = gtsam.Cal3_S2(1.0, 1.0, 0.0, 0.0, 0.0)
    pixel = gtsam.noiseModel.Isotropic.Sigma(2, 1.0 / focal_px)
    robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.5), pixel)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k, T in poses.items():
        values.insert(_X(k), pose3(T))
    for i, P in points.items():
        values.insert(_L(i), np.asarray(P, dtype=np.float64))
    for k, o in enumerate(obs):
        for i, x in o.items():
            if i in points:
                graph.add(gtsam.GenericProjectionFactorCal3_S2(x, robust, _X(k), _L(i), K))
    tight = gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)
    graph.add(gtsam.PriorFactorPose3(_X(ref), pose3(poses[ref]), tight))
    graph.add(
        gtsam.PoseTranslationPrior3D(
            _X(n), pose3(poses[n]), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)
        )
    )
    if rotations is not None:
        free = gtsam.noiseModel.Diagonal.Sigmas(np.array([rotations[1]] * 3 + [1e4] * 3))
        for k, R in enumerate(rotations[0]):
            between = gtsam.Pose3(gtsam.Rot3(R.as_matrix()), np.zeros(3))
            graph.add(gtsam.BetweenFactorPose3(_X(k), _X(k + 1), between, free))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    new_poses = {k: to_pose(result.atPose3(_X(k))) for k in poses}
    new_points = {i: np.asarray(result.atPoint3(_L(i)), dtype=np.float64) for i in points}
    return new_poses, new_points, _rms_px(obs, new_poses, new_points, focal_px)


def _rms_px(
    obs: Observations, poses: dict[int, Pose], points: dict[int, FloatArray], focal_px: float
) -> float:
    """The RMS reprojection error in pixels (``inf`` with a point at or behind a camera)."""
    err: list[FloatArray] = []
    for k, o in enumerate(obs):
        ids = [i for i in o if i in points]
        if ids:
            e, _ = reprojection_errors(
                projection(poses[k]),
                np.array([points[i] for i in ids]),
                np.array([o[i] for i in ids]),
            )
            err.append(e)
    e = np.concatenate(err) if err else np.zeros(0)
    return float(np.sqrt(np.mean(e**2)) * focal_px) if len(e) and np.isfinite(e).all() else np.inf


def _in_first_camera(
    poses: dict[int, Pose],
    points: dict[int, FloatArray],
    ref: int,
    parallax_px: float,
    rms_px: float,
) -> SfmResult:
    """The adjusted cameras and points re-expressed in the first frame's camera."""
    T_C0_W = poses[0].inverse()
    return SfmResult(
        T_C0_C=tuple(T_C0_W @ poses[k] for k in range(len(poses))),
        points_C0={i: T_C0_W @ P for i, P in points.items()},
        reference=ref,
        parallax_px=parallax_px,
        reprojection_px=rms_px,
    )


def refine_with_rotations(
    frames: Sequence[FrameFeatures],
    sfm: SfmResult,
    R_Ck_Ck1: Sequence[Rotation],
    *,
    sigma_rad: float,
    focal_px: float = 460.0,
    ba_iterations: int = 30,
) -> SfmResult | str:
    """``sfm`` adjusted again with the gyro's relative rotations between consecutive frames
    (``R_Ck_Ck1``, sigma ``sigma_rad``): a short window's rotation and translation trade off
    against each other under pixel noise (the bas-relief ambiguity); the gyro pins the
    rotations. The first camera stays the origin and the newest's position the scale."""
    obs = _observations(frames)
    poses = dict(enumerate(sfm.T_C0_C))
    points = dict(sfm.points_C0)
    poses, points, rms = _bundle_adjust(
        obs,
        poses,
        points,
        ref=0,
        focal_px=focal_px,
        iterations=ba_iterations,
        rotations=(R_Ck_Ck1, sigma_rad),
    )
    if not np.isfinite(rms):
        return "the gyro-aided bundle adjustment put points behind a camera"
    return _in_first_camera(poses, points, sfm.reference, sfm.parallax_px, rms)


def vision_sfm(
    frames: Sequence[FrameFeatures],
    *,
    focal_px: float = 460.0,
    min_parallax_px: float = 30.0,
    min_common: int = 20,
    min_translation_px: float = 5.0,
    ba_iterations: int = 30,
) -> SfmResult | str:
    """The window's cameras and structure up to scale, in the first frame's camera; or a
    sentence saying why not (too little parallax, too few features, a failed PnP)."""
    if len(frames) < 3:
        return f"a window needs at least 3 frames, got {len(frames)}"
    obs = _observations(frames)
    picked = _pick_reference(
        obs,
        focal_px=focal_px,
        min_parallax_px=min_parallax_px,
        min_common=min_common,
        min_translation_px=min_translation_px,
    )
    if isinstance(picked, str):
        return picked
    ref, T_L_Cn, parallax = picked
    built = _structure(obs, ref, T_L_Cn)
    if isinstance(built, str):
        return built
    poses, points, rms = _bundle_adjust(
        obs, *built, ref=ref, focal_px=focal_px, iterations=ba_iterations
    )
    if not np.isfinite(rms):
        return "the bundle adjustment put points behind a camera"
    return _in_first_camera(poses, points, ref, parallax, rms)
