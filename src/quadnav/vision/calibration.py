"""Camera calibration from ChArUco views (``cv2.calibrateCameraExtended`` on the interpolated
chessboard corners), rejecting views that would spoil it: too few corners, corners on one
line, or a reprojection error far above the others'.

The result is then judged as a user would judge it (:func:`judge_calibration`): it is refused
when the views cannot determine the camera (fewer than :data:`MIN_VIEWS` good views, or fewer
distinct poses; a focal length or principal point the solver knows only to 10 %; a principal
point outside the image; a radial distortion that folds back over the board's own corners),
and carries warnings when it is weak (a reprojection error above 1 px, a board that covered
less than half the image, a focal length known only to 2 %, fx and fy more than 5 % apart, a
board seen at nearly one angle, a distortion that folds between the board and the image's
corners)."""

from __future__ import annotations

import itertools
import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VisionError
from quadnav.geometry.camera import PinholeCamera
from quadnav.vision.markers import CharucoDetections, CharucoTarget, get_dictionary

__all__ = [
    "MIN_VIEWS",
    "BoardNames",
    "Calibration",
    "Judgement",
    "calibrate_charuco",
    "charuco_board_problem",
    "judge_calibration",
    "rejection_summary",
]

FloatArray = NDArray[np.float64]

MIN_VIEWS = 3  # Zhang's method: three views of a plane in general poses fix the five intrinsics
INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")  # OpenCV's order
REFUSE_FOCAL_STD = 0.10  # the solver's 1-sigma of fx or fy, relative
WARN_FOCAL_STD = 0.02
REFUSE_PP_STD = 0.10  # the 1-sigma of cx (cy) as a fraction of the width (height)
WARN_RMS_PX = 1.0
WARN_COVERAGE = 0.5  # fraction of the 8x6 cells of the image the used corners reach
WARN_ASPECT, REFUSE_ASPECT = 0.05, 0.10  # |fx/fy - 1|: square pixels are the rule
WARN_SPREAD_DEG = 10.0  # the board's normals all within this angle of one another
SAME_POSE_DEG, SAME_POSE_FRACTION = 1.0, 0.01  # two views this close are one pose


@dataclass(frozen=True, slots=True)
class Calibration:
    """The camera, the overall RMS reprojection error (px), each used view's RMS error, the
    views left out with the reason; the solver's 1-sigma of each intrinsic (``fx`` ... ``k3``),
    the fraction of the image the used corners cover, the largest angle between two views'
    board normals (deg), and the warnings of :func:`judge_calibration`."""

    camera: PinholeCamera
    rms_px: float
    per_view_rms_px: dict[int, float]
    rejected: dict[int, str]
    std_intrinsics: Mapping[str, float] = field(default_factory=dict)
    coverage: float = math.nan
    spread_deg: float = math.nan
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class BoardNames:
    """What the user calls a ChArUco board's settings (options or configuration keys)."""

    squares_x: str
    squares_y: str
    square_m: str
    marker_m: str
    dictionary: str


def charuco_board_problem(
    squares: tuple[int, int],
    square_m: float,
    marker_m: float,
    dictionary: str | int,
    names: BoardNames,
) -> str | None:
    """Why this ChArUco board cannot exist, in the user's own ``names``; ``None`` if it can.

    Checked before any work: at least 2x2 squares, positive finite sides with the marker
    inside its square, a known dictionary with a marker for every white square."""
    nx, ny = squares
    if min(nx, ny) < 2:
        if names.squares_x == names.squares_y:
            return f"{names.squares_x} must be at least 2 2 (across, down), got {nx} {ny}"
        name, n = (names.squares_x, nx) if nx < 2 else (names.squares_y, ny)
        return f"{name} must be at least 2, got {n}"
    for name, v in ((names.square_m, square_m), (names.marker_m, marker_m)):
        if not math.isfinite(v):
            return f"{name} must be a finite number of metres, got {v}"
        if v <= 0:
            return f"{name} must be positive, got {v:g}"
    if marker_m >= square_m:
        return (
            f"{names.marker_m} ({marker_m:g} m) must be smaller than "
            f"{names.square_m} ({square_m:g} m): the marker sits inside its square"
        )
    try:
        size = int(get_dictionary(dictionary).bytesList.shape[0])
    except VisionError as exc:
        return f"{names.dictionary}: {exc}"
    if nx * ny // 2 > size:
        squares_names = " and ".join(dict.fromkeys((names.squares_x, names.squares_y)))
        return (
            f"a {nx}x{ny} board needs {nx * ny // 2} markers, the dictionary {dictionary} has "
            f"{size}: fewer {squares_names} or a larger {names.dictionary}"
        )
    return None


@dataclass(frozen=True, slots=True)
class Judgement:
    """What :func:`judge_calibration` found: reasons to refuse, warnings, and its measures."""

    refusals: tuple[str, ...]
    warnings: tuple[str, ...]
    coverage: float
    spread_deg: float
    distinct_poses: int


@dataclass(frozen=True, slots=True)
class _Solution:
    rms: float
    camera: PinholeCamera
    poses: list[tuple[FloatArray, FloatArray]]  # each used view's (rvec, tvec): T_C_board
    std: dict[str, float]
    per_view: dict[int, float]


def calibrate_charuco(
    views: list[CharucoDetections],
    target: CharucoTarget,
    image_size: tuple[int, int],
    *,
    min_corners: int = 8,
    outlier_factor: float = 3.0,
    min_views: int = MIN_VIEWS,
) -> Calibration:
    """Calibrate from ChArUco detections (one per view; ``image_size`` = (width, height)).

    A :class:`~quadnav.errors.VisionError` refuses it, with the reasons on one line, when
    fewer than ``min_views`` views are good (the rejections counted by reason) or when
    :func:`judge_calibration` finds the views do not determine the camera."""
    obj, img, rejected = _usable_views(views, target, min_corners)
    used = list(obj)
    for round_ in range(4):
        _require_views(len(used), len(views), rejected, min_views, min_corners)
        sol = _solve(obj, img, used, image_size)
        limit = max(outlier_factor * float(np.median(list(sol.per_view.values()))), 1.0)
        bad = [k for k, e in sol.per_view.items() if e > limit]
        if round_ == 3 or not bad or len(used) - len(bad) < min_views:
            break
        for k in bad:
            rejected[k] = (
                f"reprojection error far above the others': {sol.per_view[k]:.2f} px > {limit:.2f}"
            )
        used = [k for k in used if k not in bad]
    corners = [img[k].reshape(-1, 2).astype(np.float64) for k in used]
    verdict = judge_calibration(
        sol.camera, sol.std, sol.rms, sol.per_view, corners, sol.poses, min_views=min_views
    )
    if verdict.refusals:
        raise VisionError(
            f"calibration refused: {'; '.join(verdict.refusals)} ({len(used)} views used, "
            f"{rejection_summary(rejected)})"
        )
    return Calibration(
        camera=sol.camera,
        rms_px=sol.rms,
        per_view_rms_px=sol.per_view,
        rejected=rejected,
        std_intrinsics=sol.std,
        coverage=verdict.coverage,
        spread_deg=verdict.spread_deg,
        warnings=verdict.warnings,
    )


def _usable_views(
    views: list[CharucoDetections], target: CharucoTarget, min_corners: int
) -> tuple[dict[int, NDArray[np.float32]], dict[int, NDArray[np.float32]], dict[int, str]]:
    """Each usable view's board points and image points, and why the others are not."""
    rejected: dict[int, str] = {}
    obj: dict[int, NDArray[np.float32]] = {}
    img: dict[int, NDArray[np.float32]] = {}
    for k, det in enumerate(views):
        if len(det.corner_ids) < min_corners:
            rejected[k] = f"too few corners: {len(det.corner_ids)} (< {min_corners})"
            continue
        if target.board.checkCharucoCornersCollinear(
            det.corner_ids.reshape(-1, 1).astype(np.int32)
        ):
            rejected[k] = "corners on one line"
            continue
        obj[k] = target.chessboard_corners[det.corner_ids].astype(np.float32).reshape(-1, 1, 3)
        img[k] = det.corners.astype(np.float32).reshape(-1, 1, 2)
    return obj, img, rejected


def rejection_summary(rejected: Mapping[int, str]) -> str:
    """The rejected views counted by reason (the text before a reason's ``:``), most first:
    ``"53 rejected: 51 too few corners, 2 corners on one line"``; ``"none rejected"``."""
    if not rejected:
        return "none rejected"
    counts = Counter(why.split(":")[0] for why in rejected.values())
    return f"{len(rejected)} rejected: " + ", ".join(
        f"{n} {why}" for why, n in counts.most_common()
    )


def _require_views(
    n_used: int, n_views: int, rejected: Mapping[int, str], min_views: int, min_corners: int
) -> None:
    if n_used < min_views:
        raise VisionError(
            f"calibration needs at least {min_views} good views, got {n_used} of {n_views} "
            f"({rejection_summary(rejected)}); a good view shows {min_corners} or more of the "
            "board's corners, not on one line, each from a pose of its own"
        )


def _solve(
    obj: Mapping[int, NDArray[np.float32]],
    img: Mapping[int, NDArray[np.float32]],
    used: list[int],
    image_size: tuple[int, int],
) -> _Solution:
    try:
        rms, K, dist, rvecs, tvecs, std, _, errs = cv2.calibrateCameraExtended(
            [obj[k] for k in used], [img[k] for k in used], image_size, np.eye(3), np.zeros(5)
        )
    except cv2.error as exc:
        msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else "no solution"
        raise VisionError(f"calibration failed in OpenCV: {msg}") from None
    cam = PinholeCamera(
        np.asarray(K, np.float64), np.asarray(dist, np.float64).ravel(), *image_size
    )
    poses = [
        (np.asarray(r, np.float64).ravel(), np.asarray(t, np.float64).ravel())
        for r, t in zip(rvecs, tvecs, strict=True)
    ]
    sd = np.asarray(std, np.float64).ravel()
    return _Solution(
        rms=float(rms),
        camera=cam,
        poses=poses,
        std={name: float(sd[i]) for i, name in enumerate(INTRINSICS) if i < len(sd)},
        per_view={k: float(e) for k, e in zip(used, np.ravel(errs), strict=True)},
    )


def judge_calibration(
    camera: PinholeCamera,
    std: Mapping[str, float],
    rms_px: float,
    per_view_rms_px: Mapping[int, float],
    corners: Sequence[FloatArray],
    poses: Sequence[tuple[FloatArray, FloatArray]],
    *,
    min_views: int = MIN_VIEWS,
) -> Judgement:
    """Judge a calibration as a user would, from its views: the corners each used view gave
    (N, 2 pixels) and the board's pose in it (rvec, tvec); ``std`` the solver's 1-sigma of the
    intrinsics. Refusals: fewer distinct poses than ``min_views``, intrinsics the solver cannot
    pin down, a principal point outside the image, a distortion that folds back over the
    board's corners. Warnings: what makes a calibration weak (see the module's text)."""
    refusals: list[str] = []
    warnings: list[str] = []
    distinct = _distinct_poses(poses)
    if distinct < min_views:
        refusals.append(
            f"the {len(poses)} views show the board from only {distinct} distinct pose"
            f"{'s' if distinct != 1 else ''} (at least {min_views} needed): move the board "
            "or the camera between views"
        )
    refusals += _uncertainty_refusals(camera, std)
    w, h = camera.width, camera.height
    cx, cy = float(camera.K[0, 2]), float(camera.K[1, 2])
    if not (0 <= cx <= w and 0 <= cy <= h):
        refusals.append(f"the principal point ({cx:.0f}, {cy:.0f}) px is outside the {w}x{h} image")
    all_corners = np.concatenate([np.asarray(c, np.float64).reshape(-1, 2) for c in corners])
    fold = _distortion_fold(camera, all_corners)
    if fold is not None:
        refusals.append(fold)
    aspect = abs(camera.fx / camera.fy - 1)
    if aspect > REFUSE_ASPECT:
        refusals.append(_aspect_text(camera, aspect) + " (more than 10 % apart)")
    coverage = _coverage(all_corners, w, h)
    spread = _spread_deg(poses)
    warnings += _weakness_warnings(camera, std, rms_px, per_view_rms_px, coverage, spread)
    return Judgement(tuple(refusals), tuple(warnings), coverage, spread, distinct)


def _uncertainty_refusals(camera: PinholeCamera, std: Mapping[str, float]) -> list[str]:
    """The intrinsics the solver knows worse than 10 % (of the focal length, of the image's
    width or height for the principal point), as one reason."""
    loose = []
    for name, value, limit in (
        ("fx", camera.fx, REFUSE_FOCAL_STD * camera.fx),
        ("fy", camera.fy, REFUSE_FOCAL_STD * camera.fy),
        ("cx", float(camera.K[0, 2]), REFUSE_PP_STD * camera.width),
        ("cy", float(camera.K[1, 2]), REFUSE_PP_STD * camera.height),
    ):
        sigma = std.get(name, math.nan)
        if not math.isfinite(sigma) or sigma > abs(limit):
            loose.append(f"{name} {value:.0f} +- {sigma:.0f} px")
    if not loose:
        return []
    return [
        f"the views do not determine {', '.join(loose)} (the solver's 1-sigma, above 10 % of "
        "the focal length or of the image): add views with the board tilted differently"
    ]


def _weakness_warnings(
    camera: PinholeCamera,
    std: Mapping[str, float],
    rms_px: float,
    per_view_rms_px: Mapping[int, float],
    coverage: float,
    spread_deg: float,
) -> list[str]:
    out = []
    if rms_px > WARN_RMS_PX:
        out.append(
            f"RMS reprojection error {rms_px:.2f} px is above {WARN_RMS_PX:g} px (worst view "
            f"{max(per_view_rms_px.values()):.2f} px): blurred or mis-detected corners, or a "
            "board that is not flat"
        )
    if coverage < WARN_COVERAGE:
        out.append(
            f"the board's corners reach {coverage:.0%} of the image: the distortion is "
            "extrapolated elsewhere; show the board near the edges and corners too"
        )
    rel = max(std.get("fx", 0.0) / camera.fx, std.get("fy", 0.0) / camera.fy)
    if rel > WARN_FOCAL_STD:
        out.append(
            f"the focal length is known to +-{rel:.1%} only (the solver's 1-sigma): "
            "add views with the board tilted differently"
        )
    aspect = abs(camera.fx / camera.fy - 1)
    if WARN_ASPECT < aspect <= REFUSE_ASPECT:
        out.append(_aspect_text(camera, aspect))
    if spread_deg < WARN_SPREAD_DEG:
        out.append(
            f"the board faces the camera at nearly one angle in every view (normals within "
            f"{spread_deg:.1f} deg): tilt it by 20-40 deg in different directions"
        )
    return out


def _aspect_text(camera: PinholeCamera, aspect: float) -> str:
    return (
        f"fx and fy differ by {aspect:.0%} ({camera.fx:.0f} and {camera.fy:.0f} px): pixels "
        "are square on nearly every camera"
    )


def _distinct_poses(poses: Sequence[tuple[FloatArray, FloatArray]]) -> int:
    """Views whose board poses differ by more than 1 deg or 1 % of the distance from each
    earlier distinct one."""
    kept: list[tuple[FloatArray, FloatArray]] = []
    for rv, tv in poses:
        R = np.asarray(cv2.Rodrigues(rv)[0], np.float64)
        same = False
        for R0, t0 in kept:
            angle = math.degrees(cv2.norm(cv2.Rodrigues(R @ R0.T)[0]))
            near = float(np.linalg.norm(tv - t0)) < SAME_POSE_FRACTION * float(np.linalg.norm(t0))
            same = same or (angle < SAME_POSE_DEG and near)
        if not same:
            kept.append((R, tv))
    return len(kept)


def _spread_deg(poses: Sequence[tuple[FloatArray, FloatArray]]) -> float:
    """The largest angle between two views' board normals (deg); 0 for one view."""
    normals = [cv2.Rodrigues(rv)[0][:, 2] for rv, _ in poses]
    angles = [
        math.degrees(math.acos(min(1.0, abs(float(a @ b)))))
        for a, b in itertools.combinations(normals, 2)
    ]
    return max(angles, default=0.0)


def _coverage(
    corners: FloatArray, width: int, height: int, cells: tuple[int, int] = (8, 6)
) -> float:
    """The fraction of an 8x6 grid of the image's cells holding at least one corner."""
    nx, ny = cells
    ix = np.clip((corners[:, 0] / width * nx).astype(int), 0, nx - 1)
    iy = np.clip((corners[:, 1] / height * ny).astype(int), 0, ny - 1)
    return len(set(zip(ix.tolist(), iy.tolist(), strict=True))) / (nx * ny)


def _distortion_fold(camera: PinholeCamera, corners: FloatArray) -> str | None:
    """Why the radial distortion does not describe a lens, if it stops growing with the radius
    somewhere in the image (r_d'(r) <= 0: the model folds back, two radii map to one pixel and
    the image cannot be undistorted past that point); ``None`` if it grows everywhere."""
    k = np.zeros(3)
    d = np.asarray(camera.dist, np.float64).ravel()
    k[: min(2, len(d))] = d[:2]
    if len(d) >= 5:
        k[2] = d[4]
    f, c = np.array([camera.fx, camera.fy]), np.asarray(camera.K[:2, 2], np.float64)
    w, h = camera.width, camera.height
    r_board = float(np.max(np.linalg.norm((corners - c) / f, axis=1)))
    image_corners = np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]])
    r_image = max(float(np.max(np.linalg.norm((image_corners - c) / f, axis=1))), r_board)
    r = np.linspace(0.0, r_image, 400)
    u = r**2
    slope = 1 + 3 * k[0] * u + 5 * k[1] * u**2 + 7 * k[2] * u**3
    if np.all(slope > 0):
        return None
    r_fold = float(r[np.argmax(slope <= 0)])
    px, px_board = r_fold * float(np.mean(f)), r_board * float(np.mean(f))
    ks = " ".join(f"{v:.4g}" for v in k)
    where = "inside" if r_fold <= r_board else "past"
    return (
        f"the radial distortion (k1 k2 k3 {ks}) folds back {px:.0f} px from the principal "
        f"point, {where} the board's farthest corner ({px_board:.0f} px) but inside the image: "
        "no lens does that; show the board near the image's edges and corners"
    )
