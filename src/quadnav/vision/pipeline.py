"""From an image to the vehicle's pose: detection, PnP against what is known of the scene
(a single marker, a ChArUco board, a diamond or a marker map), the camera mount, and the
covariance. Every target has z out of its printed face.

:class:`MarkerMap` places markers and boards in the world (the thesis's first future-work item:
navigating over a field of markers); :class:`MarkerPipeline` turns a frame into a
:class:`FramePose` with per-stage timing.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import GeometryError, VisionError
from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.units import ns_to_s, s_to_ns
from quadnav.vision.markers import (
    CharucoSpec,
    CharucoTarget,
    DiamondSpec,
    DiamondTarget,
    MarkerDetections,
    MarkerDetector,
    get_dictionary,
    to_gray,
)
from quadnav.vision.pose import (
    DegeneratePoseError,
    PnpResult,
    VehiclePose,
    check_point_set,
    marker_corners_3d,
    refine_pnp,
    solve_pnp,
    vehicle_pose,
)

__all__ = [
    "FallbackGate",
    "FramePose",
    "MapBoard",
    "MapDiamond",
    "MapMarker",
    "MarkerMap",
    "MarkerPipeline",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class MapMarker:
    """A marker of side ``length_m`` at ``T_W_M`` (centre; x right, y up, z out of the face)."""

    id: int
    length_m: float
    T_W_M: Pose


@dataclass(frozen=True, slots=True)
class MapBoard:
    """A ChArUco board at ``T_W_O``, its face frame: origin at the bottom-left corner of the
    printed pattern, x right, y up, z out of the face (see
    :func:`~quadnav.vision.markers.opencv_board_to_face`)."""

    spec: CharucoSpec
    T_W_O: Pose


@dataclass(frozen=True, slots=True)
class MapDiamond:
    """A ChArUco diamond at ``T_W_D`` (centre of its middle square; x right, y up, z out of the
    face, as a marker of side ``spec.square_m``)."""

    spec: DiamondSpec
    T_W_D: Pose


@dataclass(frozen=True, slots=True)
class MarkerMap:
    """Markers, boards and diamonds with known poses in the world, all of one dictionary."""

    dictionary: str | int
    markers: dict[int, MapMarker] = field(default_factory=dict)
    boards: list[MapBoard] = field(default_factory=list)
    diamonds: list[MapDiamond] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.markers and not self.boards and not self.diamonds:
            raise VisionError("a marker map needs at least one marker, board or diamond")
        for m in self.markers.values():
            if not m.length_m > 0:
                raise VisionError(f"marker {m.id}: length must be > 0")

    @staticmethod
    def single_marker(marker_id: int, length_m: float, dictionary: str | int) -> MarkerMap:
        """One marker at the world origin (the thesis's setting: the marker frame is the world)."""
        return MarkerMap(dictionary, {marker_id: MapMarker(marker_id, length_m, Pose.identity())})


@dataclass(frozen=True, slots=True)
class FramePose:
    """What one frame gave: the markers seen, and the vehicle pose if there was one; if not,
    why (``reason``: a short key to count, ``note``: the message)."""

    t_ns: int
    detections: MarkerDetections
    pose: VehiclePose | None
    rms_px: float
    n_points: int
    detect_ms: float
    pose_ms: float
    note: str = ""
    reason: str = ""
    fallback: bool = False  # the pose is from a board's marker corners, not its chessboard's


@dataclass(frozen=True, slots=True, kw_only=True)
class FallbackGate:
    """When a board's marker corners stand in for its chessboard corners (close up, a partial
    view), a pose from them is used only if

    - its position's standard deviation (the largest of the PnP covariance, which for an
      ambiguous planar pose spans both solutions: a marker seen small or head-on fits a tilted
      mirror image almost as well) is at most ``max_sigma_m``, and
    - it agrees with the run's last pose, if that is no older than ``memory_s``: within
      ``max_speed_m_s`` and ``max_rate_deg_s`` of it over the time between them, plus
      ``slack_m`` and ``slack_deg``. Of an ambiguous pose's two solutions, the one that
      agrees is taken."""

    max_sigma_m: float = 0.05
    max_speed_m_s: float = 1.0
    max_rate_deg_s: float = 90.0
    slack_m: float = 0.03
    slack_deg: float = 5.0
    memory_s: float = 0.25

    def __post_init__(self) -> None:
        values = (self.max_sigma_m, self.max_speed_m_s, self.max_rate_deg_s, self.slack_m,
                  self.slack_deg, self.memory_s)  # fmt: skip
        if not all(math.isfinite(v) and v >= 0 for v in values):
            raise VisionError(f"fallback gate: every bound must be finite and >= 0, got {values}")

    def misfit(self, T_last: Pose, dt_s: float, T: Pose) -> float:
        """How far ``T`` is from ``T_last`` (``dt_s`` earlier) in units of the bounds: at
        most 1 agrees."""
        d_m = float(np.linalg.norm(T.p_A_B - T_last.p_A_B))
        d_deg = math.degrees((T_last.R_A_B.inv() * T.R_A_B).magnitude())
        return max(
            d_m / (self.max_speed_m_s * dt_s + self.slack_m + 1e-12),
            d_deg / (self.max_rate_deg_s * dt_s + self.slack_deg + 1e-12),
        )


@dataclass(slots=True)
class _Observed:
    """Object points in the world and their pixels gathered from one frame; ``square``: the
    first square target (marker or diamond) seen, for IPPE_SQUARE when it is all there is."""

    obj_W: list[FloatArray] = field(default_factory=list)
    img: list[FloatArray] = field(default_factory=list)
    square: tuple[float, FloatArray, Pose] | None = None
    # a board's marker corners to use instead of its chessboard corners (entry k) if those
    # give no pose
    instead: dict[int, tuple[FloatArray, FloatArray]] = field(default_factory=dict)
    fallback: bool = False  # a board's marker corners are in, for its chessboard corners

    def with_markers_instead(self) -> _Observed:
        obj_W, img = list(self.obj_W), list(self.img)
        for k, (o, i) in self.instead.items():
            obj_W[k], img[k] = o, i
        return _Observed(obj_W, img, self.square, fallback=True)

    def add(self, obj_W: FloatArray, img: FloatArray) -> None:
        self.obj_W.append(obj_W)
        self.img.append(img)

    def add_square(self, side_m: float, corners: FloatArray, T_W_O: Pose) -> None:
        self.add(T_W_O @ marker_corners_3d(side_m), corners)
        self.square = (side_m, corners, T_W_O) if self.square is None else self.square

    @property
    def n(self) -> int:
        return sum(len(o) for o in self.obj_W)


def _poseable(obj: FloatArray, img: FloatArray) -> bool:
    try:
        check_point_set(obj, img)
    except DegeneratePoseError:
        return False
    return True


class MarkerPipeline:
    """Detection + pose for a camera mounted at ``T_B_C`` over a :class:`MarkerMap`."""

    def __init__(
        self,
        camera: PinholeCamera,
        marker_map: MarkerMap,
        T_B_C: Pose,
        *,
        params: cv2.aruco.DetectorParameters | None = None,
        dictionary: cv2.aruco.Dictionary | None = None,
        prior_sigma_px: float = 0.25,
        max_rms_px: float = 3.0,
        min_charuco_corners: int = 4,
        board_marker_fallback: bool = True,
        charuco_min_markers: int = 2,
        fallback_gate: FallbackGate | None = None,
    ) -> None:
        self.camera = camera
        self.map = marker_map
        self.T_B_C = T_B_C
        self.dictionary = (
            dictionary if dictionary is not None else get_dictionary(marker_map.dictionary)
        )
        if params is None:
            params = cv2.aruco.DetectorParameters()
            params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        self.params = params
        self.detector = MarkerDetector(self.dictionary, params)
        self.boards = [
            (
                # OpenCV's refinement of missed board markers cost a third more time per frame
                # and gave no extra pose on the thesis video (88 of 200 frames either way): off.
                CharucoTarget(
                    b.spec,
                    params,
                    dictionary=self.dictionary,
                    min_markers=charuco_min_markers,
                    refine=False,
                ),
                b.T_W_O,
            )
            for b in marker_map.boards
        ]
        ratios = sorted({d.spec.square_m / d.spec.marker_m for d in marker_map.diamonds})
        self.diamond_targets = [DiamondTarget(self.dictionary, r, params) for r in ratios]
        self.min_charuco_corners = max(4, min_charuco_corners)
        self.board_marker_fallback = board_marker_fallback
        self.prior_sigma_px = prior_sigma_px
        self.max_rms_px = max_rms_px
        self.fallback_gate = fallback_gate if fallback_gate is not None else FallbackGate()
        self._last: tuple[int, Pose] | None = None  # the last pose given: t_ns, T_W_B

    def _board_marker_points(
        self, target: CharucoTarget, T_W_O: Pose, markers: MarkerDetections
    ) -> tuple[FloatArray, FloatArray] | None:
        """The board's marker corners in view, in the world, and their pixels."""
        if not (self.board_marker_fallback and len(markers)):
            return None
        mobj = target.marker_corners(markers.ids)
        keep = np.isfinite(mobj[:, 0, 0])
        if not keep.any():
            return None
        return T_W_O @ mobj[keep].reshape(-1, 3), markers.corners[keep].reshape(-1, 2)

    def _observe_boards(self, gray: NDArray[np.uint8], seen: _Observed) -> MarkerDetections:
        markers = MarkerDetections.from_opencv((), None)
        for target, T_W_O in self.boards:
            det = target.detect(gray)
            markers = det.markers if len(det.markers) > len(markers) else markers
            obj = target.chessboard_corners[det.corner_ids]
            marker_pts = self._board_marker_points(target, T_W_O, det.markers)
            if len(det.corner_ids) >= self.min_charuco_corners and _poseable(obj, det.corners):
                if marker_pts is not None:
                    seen.instead[len(seen.obj_W)] = marker_pts
                seen.add(T_W_O @ obj, det.corners)
            elif marker_pts is not None:
                # Too few chessboard corners (close up, partial view) or all on one line (one
                # column in view): the board's marker corners still fix its pose, less precisely.
                seen.add(*marker_pts)
                seen.fallback = True
            elif len(det.corner_ids) >= self.min_charuco_corners:
                seen.add(T_W_O @ obj, det.corners)  # for the PnP to refuse, with its reason
        return markers

    def _observe_diamonds(
        self, gray: NDArray[np.uint8], markers: MarkerDetections | None, seen: _Observed
    ) -> MarkerDetections:
        found = []
        for target in self.diamond_targets:
            diamonds, markers = target.detect(gray, markers)
            found.extend(diamonds)
        found.sort(key=lambda d: d.ids)
        used: set[tuple[int, int, int, int]] = set()
        for md in self.map.diamonds:
            match = next(
                (d for d in found if d.ids not in used and md.spec.ids in (None, d.ids)), None
            )
            if match is not None:
                used.add(match.ids)
                seen.add_square(md.spec.square_m, match.corners, md.T_W_D)
        return markers if markers is not None else MarkerDetections.from_opencv((), None)

    def _observe(self, gray: NDArray[np.uint8]) -> tuple[MarkerDetections, _Observed]:
        seen = _Observed()
        markers: MarkerDetections | None = None
        if self.boards:
            markers = self._observe_boards(gray, seen)
        if self.diamond_targets:
            markers = self._observe_diamonds(gray, markers, seen)
        if markers is None:
            markers = self.detector.detect(gray)
        if self.map.markers:
            for mid, corners in zip(markers.ids, markers.corners, strict=True):
                m = self.map.markers.get(int(mid))
                if m is not None:
                    seen.add_square(m.length_m, corners, m.T_W_M)
        return markers, seen

    def _solve(self, seen: _Observed) -> tuple[VehiclePose, float, VehiclePose | None]:
        """The pose, its RMS reprojection error and, for an ambiguous planar pose of a marker
        fallback, the other solution refined (None otherwise)."""
        if seen.n == 4 and seen.square is not None:
            # One square target: IPPE_SQUARE in its own frame, then into the world.
            side_m, corners, T_W_O = seen.square
            pnp = solve_pnp(
                marker_corners_3d(side_m),
                corners,
                self.camera,
                square=True,
                prior_sigma_px=self.prior_sigma_px,
            )
            return vehicle_pose(pnp, T_W_O, self.T_B_C), pnp.rms_px, None
        obj, img = np.concatenate(seen.obj_W), np.concatenate(seen.img)
        pnp = solve_pnp(obj, img, self.camera, prior_sigma_px=self.prior_sigma_px)
        vp = vehicle_pose(pnp, Pose.identity(), self.T_B_C)
        return vp, pnp.rms_px, self._other_solution(obj, img, pnp) if seen.fallback else None

    def _other_solution(
        self, obj: FloatArray, img: FloatArray, pnp: PnpResult
    ) -> VehiclePose | None:
        if pnp.alternative is None:
            return None
        mine = np.concatenate([pnp.rvec, pnp.tvec])
        try:
            alt = refine_pnp(
                obj,
                img,
                self.camera,
                pnp.alternative[0:3],
                pnp.alternative[3:6],
                prior_sigma_px=self.prior_sigma_px,
                alternative=mine,
            )
        except (VisionError, GeometryError):
            return None
        if not alt.rms_px <= self.max_rms_px:
            return None
        return vehicle_pose(alt, Pose.identity(), self.T_B_C)

    def _gate(
        self, t_ns: int, vp: VehiclePose, other: VehiclePose | None
    ) -> tuple[VehiclePose | None, str, str]:
        """A marker fallback's pose (or its other solution) that passes the
        :class:`FallbackGate`, or None with the reason key and the message."""
        gate = self.fallback_gate
        last = self._last
        pick = vp
        if last is not None and 0 <= t_ns - last[0] <= s_to_ns(gate.memory_s):
            dt_s = ns_to_s(t_ns - last[0])
            fits = [(gate.misfit(last[1], dt_s, c.T_W_B), k, c) for k, c in enumerate((vp, other)) if c]  # fmt: skip
            misfit, _, pick = min(fits, key=lambda x: (x[0], x[1]))
            if misfit > 1.0:
                jump = float(np.linalg.norm(vp.T_W_B.p_A_B - last[1].p_A_B))
                msg = f"marker fallback: {jump:.3f} m from the last pose, {dt_s:.3f} s before"
                return None, "fallback_jump", msg
        sigma_m = math.sqrt(max(float(np.linalg.eigvalsh(pick.cov_position)[-1]), 0.0))
        if not sigma_m <= gate.max_sigma_m:
            msg = f"marker fallback: position sigma {sigma_m:.3f} m > {gate.max_sigma_m:g} m"
            return None, "fallback_uncertain", msg
        return pick, "", ""

    def process(self, image: NDArray[Any], t_ns: int = 0) -> FramePose:
        """One frame's pose, or the reason there is none; a degenerate view (too few points,
        collinear, a non-finite PnP result) is refused here, never raised."""
        gray = to_gray(image)
        t0 = time.perf_counter()
        markers, seen = self._observe(gray)
        t1 = time.perf_counter()
        detect_ms = (t1 - t0) * 1e3
        n = seen.n
        if n < 4:
            return FramePose(
                t_ns, markers, None, float("nan"), n, detect_ms, 0.0, "no known marker", "no_target"
            )
        try:
            try:
                vp, rms_px, other = self._solve(seen)
            except DegeneratePoseError:
                if not seen.instead:
                    raise
                seen = seen.with_markers_instead()
                vp, rms_px, other = self._solve(seen)
        except (VisionError, GeometryError) as exc:
            pose_ms = (time.perf_counter() - t1) * 1e3
            reason = exc.reason if isinstance(exc, DegeneratePoseError) else "pose_error"
            return FramePose(
                t_ns, markers, None, float("nan"), n, detect_ms, pose_ms, str(exc), reason
            )
        pose_ms = (time.perf_counter() - t1) * 1e3
        if not rms_px <= self.max_rms_px:
            return FramePose(
                t_ns,
                markers,
                None,
                rms_px,
                n,
                detect_ms,
                pose_ms,
                f"reprojection error {rms_px:.2f} px > {self.max_rms_px}",
                "reprojection",
            )
        if seen.fallback:
            picked, reason, note = self._gate(t_ns, vp, other)
            if picked is None:
                return FramePose(
                    t_ns, markers, None, rms_px, n, detect_ms, pose_ms, note, reason, True
                )
            vp = picked
        self._last = (t_ns, vp.T_W_B)
        return FramePose(t_ns, markers, vp, rms_px, n, detect_ms, pose_ms, fallback=seen.fallback)
