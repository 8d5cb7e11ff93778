"""From an image to the vehicle's pose: detection, PnP against what is known of the scene
(a single marker, a ChArUco board or a marker map), the camera mount, and the covariance.

:class:`MarkerMap` places markers and boards in the world (the thesis's first future-work item:
navigating over a field of markers); :class:`MarkerPipeline` turns a frame into a
:class:`FramePose` with per-stage timing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VisionError
from quadnav.geometry.rotations import Pose
from quadnav.vision.camera import PinholeCamera
from quadnav.vision.markers import (
    CharucoSpec,
    CharucoTarget,
    MarkerDetections,
    MarkerDetector,
    get_dictionary,
    to_gray,
)
from quadnav.vision.pose import VehiclePose, marker_corners_3d, solve_pnp, vehicle_pose

__all__ = ["FramePose", "MapBoard", "MapMarker", "MarkerMap", "MarkerPipeline"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class MapMarker:
    """A marker of side ``length_m`` at ``T_W_M`` (centre; x right, y up, z out of the face)."""

    id: int
    length_m: float
    T_W_M: Pose


@dataclass(frozen=True, slots=True)
class MapBoard:
    """A ChArUco board at ``T_W_O`` (OpenCV's board frame)."""

    spec: CharucoSpec
    T_W_O: Pose


@dataclass(frozen=True, slots=True)
class MarkerMap:
    """Markers and boards with known poses in the world, all of one dictionary."""

    dictionary: str | int
    markers: dict[int, MapMarker] = field(default_factory=dict)
    boards: list[MapBoard] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.markers and not self.boards:
            raise VisionError("a marker map needs at least one marker or board")
        for m in self.markers.values():
            if not m.length_m > 0:
                raise VisionError(f"marker {m.id}: length must be > 0")

    @staticmethod
    def single_marker(marker_id: int, length_m: float, dictionary: str | int) -> MarkerMap:
        """One marker at the world origin (the thesis's setting: the marker frame is the world)."""
        return MarkerMap(dictionary, {marker_id: MapMarker(marker_id, length_m, Pose.identity())})


@dataclass(frozen=True, slots=True)
class FramePose:
    """What one frame gave: the markers seen, and the vehicle pose if there was one."""

    t_ns: int
    detections: MarkerDetections
    pose: VehiclePose | None
    rms_px: float
    n_points: int
    detect_ms: float
    pose_ms: float
    note: str = ""


class MarkerPipeline:
    """Detection + pose for a camera mounted at ``T_B_C`` over a :class:`MarkerMap`."""

    def __init__(
        self,
        camera: PinholeCamera,
        marker_map: MarkerMap,
        T_B_C: Pose,
        *,
        params: Any | None = None,
        dictionary: cv2.aruco.Dictionary | None = None,
        prior_sigma_px: float = 0.25,
        max_rms_px: float = 3.0,
        min_charuco_corners: int = 4,
        board_marker_fallback: bool = True,
        charuco_min_markers: int = 2,
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
        self.min_charuco_corners = max(4, min_charuco_corners)
        self.board_marker_fallback = board_marker_fallback
        self.prior_sigma_px = prior_sigma_px
        self.max_rms_px = max_rms_px

    def process(self, image: NDArray[Any], t_ns: int = 0) -> FramePose:
        gray = to_gray(image)
        t0 = time.perf_counter()
        obj_W: list[FloatArray] = []
        img: list[FloatArray] = []
        single: tuple[MapMarker, FloatArray] | None = None
        if self.boards:
            markers = MarkerDetections.from_opencv((), None)
            for target, T_W_O in self.boards:
                det = target.detect(gray)
                markers = det.markers if len(det.markers) > len(markers) else markers
                if len(det.corner_ids) >= self.min_charuco_corners:
                    obj_W.append(T_W_O @ target.chessboard_corners[det.corner_ids])
                    img.append(det.corners)
                elif self.board_marker_fallback and len(det.markers):
                    # Too few chessboard corners (close up, partial view): the board's marker
                    # corners still fix its pose, less precisely.
                    obj = target.marker_corners(det.markers.ids)
                    keep = np.isfinite(obj[:, 0, 0])
                    if keep.any():
                        obj_W.append(T_W_O @ obj[keep].reshape(-1, 3))
                        img.append(det.markers.corners[keep].reshape(-1, 2))
        else:
            markers = self.detector.detect(gray)
        for mid, corners in zip(markers.ids, markers.corners, strict=True):
            m = self.map.markers.get(int(mid))
            if m is None:
                continue
            obj_W.append(m.T_W_M @ marker_corners_3d(m.length_m))
            img.append(corners)
            single = (m, corners) if single is None else single
        t1 = time.perf_counter()
        detect_ms = (t1 - t0) * 1e3
        n = sum(len(o) for o in obj_W)
        if n < 4:
            return FramePose(
                t_ns, markers, None, float("nan"), n, detect_ms, 0.0, "no known marker"
            )
        try:
            if n == 4 and single is not None:
                # One marker: IPPE_SQUARE in its own frame, then into the world.
                pnp = solve_pnp(marker_corners_3d(single[0].length_m), single[1], self.camera,
                                square=True, prior_sigma_px=self.prior_sigma_px)  # fmt: skip
                vp = vehicle_pose(pnp, single[0].T_W_M, self.T_B_C)
            else:
                pnp = solve_pnp(np.concatenate(obj_W), np.concatenate(img), self.camera,
                                prior_sigma_px=self.prior_sigma_px)  # fmt: skip
                vp = vehicle_pose(pnp, Pose.identity(), self.T_B_C)
        except VisionError as exc:
            pose_ms = (time.perf_counter() - t1) * 1e3
            return FramePose(t_ns, markers, None, float("nan"), n, detect_ms, pose_ms, str(exc))
        pose_ms = (time.perf_counter() - t1) * 1e3
        if not pnp.rms_px <= self.max_rms_px:
            return FramePose(t_ns, markers, None, pnp.rms_px, n, detect_ms, pose_ms,
                             f"reprojection error {pnp.rms_px:.2f} px > {self.max_rms_px}")  # fmt: skip
        return FramePose(t_ns, markers, vp, pnp.rms_px, n, detect_ms, pose_ms)
