"""Marker detection on OpenCV's ArUco module: single markers of any predefined or custom
dictionary (ArUco, AprilTag), ChArUco boards and diamonds.

Pure functions on images (numpy arrays); files are read in :mod:`quadnav.io`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VisionError

__all__ = [
    "CharucoDetections",
    "CharucoSpec",
    "CharucoTarget",
    "Diamond",
    "DiamondSpec",
    "DiamondTarget",
    "MarkerDetections",
    "MarkerDetector",
    "custom_dictionary",
    "detect_diamonds",
    "detector_parameters",
    "get_dictionary",
    "opencv_board_to_face",
    "to_gray",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Predefined dictionaries by name (``DICT_4X4_250``, ``DICT_APRILTAG_36h11``...).
PREDEFINED: dict[str, int] = {
    name: int(getattr(cv2.aruco, name))
    for name in dir(cv2.aruco)
    if name.startswith("DICT_") and isinstance(getattr(cv2.aruco, name), int)
}


def get_dictionary(name: str | int) -> cv2.aruco.Dictionary:
    """A predefined dictionary by name (case of the family suffix ignored) or OpenCV's number
    (the thesis's ``dict_type: 2`` is DICT_4X4_250)."""
    if isinstance(name, int) or (isinstance(name, str) and name.strip().isdigit()):
        code = int(name)
        if code not in PREDEFINED.values():
            raise VisionError(f"no predefined ArUco dictionary number {code}")
        return cv2.aruco.getPredefinedDictionary(code)
    key = name.strip()
    key = key if key.startswith("DICT_") else f"DICT_{key}"
    for candidate, code in PREDEFINED.items():
        if candidate.upper() == key.upper():
            return cv2.aruco.getPredefinedDictionary(code)
    known = ", ".join(sorted({n for n in PREDEFINED if not n.endswith(("H5", "H9", "H10", "H11"))}))
    raise VisionError(f"unknown ArUco dictionary {name!r}; known: {known}")


def custom_dictionary(
    bits: list[str], marker_size: int, max_correction_bits: int | None = None
) -> cv2.aruco.Dictionary:
    """A dictionary from each marker's bits as a row-major string of 0/1 (OpenCV's custom
    dictionary file: ``nmarkers``, ``markersize``, ``marker_<i>``)."""
    if marker_size < 2 or not bits:
        raise VisionError("a custom dictionary needs markers of at least 2x2 bits")
    rows = []
    for i, b in enumerate(bits):
        if len(b) != marker_size * marker_size or set(b) - {"0", "1"}:
            raise VisionError(
                f"custom dictionary marker {i}: expected {marker_size**2} bits of 0/1"
            )
        grid = np.array([int(c) for c in b], dtype=np.uint8).reshape(marker_size, marker_size)
        rows.append(cv2.aruco.Dictionary.getByteListFromBits(grid))
    byte_list = np.concatenate(rows, axis=0)
    corr = (
        max(0, (marker_size * marker_size) // 8 - 1)
        if max_correction_bits is None
        else max_correction_bits
    )
    return cv2.aruco.Dictionary(byte_list, marker_size, corr)


def detector_parameters(
    values: Mapping[str, object] | None = None,
) -> tuple[cv2.aruco.DetectorParameters, list[str]]:
    """``cv2.aruco.DetectorParameters`` from a mapping as in the thesis's ``detector_params.yml``.
    Returns the parameters and the keys this OpenCV does not know (ignored, for a warning)."""
    params = cv2.aruco.DetectorParameters()
    unknown: list[str] = []
    for key, value in (values or {}).items():
        if not hasattr(params, key):
            unknown.append(key)
            continue
        current = getattr(params, key)
        try:
            if not isinstance(value, int | float | str):  # a matrix, a section, nothing
                raise TypeError("not a number")
            if isinstance(current, bool):
                setattr(params, key, bool(value))
            elif isinstance(current, int):
                setattr(params, key, int(value))
            else:
                setattr(params, key, float(value))
        except (TypeError, ValueError) as exc:
            raise VisionError(f"detector parameter {key}: bad value {value!r} ({exc})") from None
    return params, unknown


def to_gray(image: NDArray[Any]) -> NDArray[np.uint8]:
    """A single-channel 8-bit view of an image (BGR, BGRA or gray)."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        img = cv2.cvtColor(img, code)
    if img.ndim != 2 or img.size == 0:
        raise VisionError(f"not an image: shape {img.shape}")
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    return img


@dataclass(frozen=True, slots=True)
class MarkerDetections:
    """Detected markers: ``ids`` (N,), ``corners`` (N, 4, 2) pixels in OpenCV's corner order
    (top-left, top-right, bottom-right, bottom-left of the marker), ``n_rejected`` candidates."""

    ids: IntArray
    corners: FloatArray
    n_rejected: int = 0

    def __len__(self) -> int:
        return len(self.ids)

    @staticmethod
    def from_opencv(corners: Any, ids: Any, rejected: Any = ()) -> MarkerDetections:
        if ids is None or len(ids) == 0:
            return MarkerDetections(np.zeros(0, np.int64), np.zeros((0, 4, 2)), len(rejected))
        c = np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)
        return MarkerDetections(np.asarray(ids, np.int64).ravel(), c, len(rejected))

    def as_opencv(self) -> tuple[tuple[NDArray[np.float32], ...], NDArray[np.int32]]:
        corners = tuple(c.reshape(1, 4, 2).astype(np.float32) for c in self.corners)
        return corners, self.ids.reshape(-1, 1).astype(np.int32)


class MarkerDetector:
    """``cv2.aruco.ArucoDetector`` with quadnav's types."""

    def __init__(
        self, dictionary: cv2.aruco.Dictionary, params: cv2.aruco.DetectorParameters | None = None
    ) -> None:
        self.dictionary = dictionary
        self.params = params if params is not None else cv2.aruco.DetectorParameters()
        self._detector = cv2.aruco.ArucoDetector(dictionary, self.params)

    def detect(self, image: NDArray[Any]) -> MarkerDetections:
        corners, ids, rejected = self._detector.detectMarkers(to_gray(image))
        return MarkerDetections.from_opencv(corners, ids, rejected)


@dataclass(frozen=True, slots=True)
class CharucoSpec:
    """A ChArUco board: squares across (x) and down (y), square and marker side (m)."""

    squares_x: int
    squares_y: int
    square_m: float
    marker_m: float
    dictionary: str | int = "DICT_4X4_250"
    legacy_pattern: bool = False

    def __post_init__(self) -> None:
        if self.squares_x < 2 or self.squares_y < 2:
            raise VisionError("a ChArUco board needs at least 2x2 squares")
        if not 0 < self.marker_m < self.square_m:
            raise VisionError("a ChArUco marker must be smaller than its square")


@dataclass(frozen=True, slots=True)
class CharucoDetections:
    """Interpolated chessboard corners (``corner_ids`` (M,), ``corners`` (M, 2)) and the
    markers they came from."""

    corner_ids: IntArray
    corners: FloatArray
    markers: MarkerDetections


def opencv_board_to_face(points: FloatArray, height_m: float) -> FloatArray:
    """Points of OpenCV's board frame (origin at the top-left corner of the pattern, x right,
    y down the printed image, so z into the board) in the board's face frame (origin at the
    bottom-left corner, x right, y up, z out of the printed face, as a single marker's and
    as OpenCV's boards before 4.6, the thesis's): a half turn about x, then up by the height."""
    p = np.asarray(points, np.float64)
    return np.stack([p[..., 0], height_m - p[..., 1], -p[..., 2]], axis=-1)


class CharucoTarget:
    """A ChArUco board and its detector (``cv2.aruco.CharucoDetector``). Its points are in the
    board's face frame (:func:`opencv_board_to_face`): z out of the printed face, as every
    target's."""

    def __init__(
        self,
        spec: CharucoSpec,
        params: cv2.aruco.DetectorParameters | None = None,
        *,
        dictionary: cv2.aruco.Dictionary | None = None,
        refine: bool = True,
        min_markers: int = 2,
    ) -> None:
        """``min_markers``: markers next to a chessboard corner needed to interpolate it
        (OpenCV's default 2; 1 finds more corners, less precisely)."""
        self.spec = spec
        self.dictionary = dictionary if dictionary is not None else get_dictionary(spec.dictionary)
        self.board = cv2.aruco.CharucoBoard(
            (spec.squares_x, spec.squares_y), spec.square_m, spec.marker_m, self.dictionary
        )
        self.board.setLegacyPattern(spec.legacy_pattern)
        cp = cv2.aruco.CharucoParameters()
        cp.tryRefineMarkers = refine
        cp.minMarkers = min_markers
        self.height_m = spec.squares_y * spec.square_m
        self._marker_obj = opencv_board_to_face(
            np.asarray(self.board.getObjPoints(), np.float64).reshape(-1, 4, 3), self.height_m
        )
        self._chessboard = opencv_board_to_face(
            np.asarray(self.board.getChessboardCorners(), np.float64).reshape(-1, 3),
            self.height_m,
        )
        self._marker_index = {
            int(i): k for k, i in enumerate(np.asarray(self.board.getIds()).ravel())
        }
        self.params = params if params is not None else cv2.aruco.DetectorParameters()
        self._detector = cv2.aruco.CharucoDetector(self.board, cp, self.params)

    def marker_corners(self, ids: IntArray) -> FloatArray:
        """The corners (N, 4, 3) of the board's markers ``ids`` in the face frame, in detection
        order (top-left, top-right, bottom-right, bottom-left); NaN for an id the board does
        not have."""
        out = np.full((len(ids), 4, 3), np.nan)
        for k, i in enumerate(ids):
            j = self._marker_index.get(int(i))
            if j is not None:
                out[k] = self._marker_obj[j]
        return out

    @property
    def chessboard_corners(self) -> FloatArray:
        """The board's inner corners (K, 3) in the face frame (m), by corner id."""
        return self._chessboard

    def detect(self, image: NDArray[Any]) -> CharucoDetections:
        ch_corners, ch_ids, m_corners, m_ids = self._detector.detectBoard(to_gray(image))
        markers = MarkerDetections.from_opencv(m_corners, m_ids)
        if ch_ids is None or len(ch_ids) == 0:
            return CharucoDetections(np.zeros(0, np.int64), np.zeros((0, 2)), markers)
        return CharucoDetections(
            np.asarray(ch_ids, np.int64).ravel(),
            np.asarray(ch_corners, np.float64).reshape(-1, 2),
            markers,
        )


@dataclass(frozen=True, slots=True)
class Diamond:
    """A ChArUco diamond: its four marker ids and its four corners (4, 2) px."""

    ids: tuple[int, int, int, int]
    corners: FloatArray = field(repr=False)


@dataclass(frozen=True, slots=True)
class DiamondSpec:
    """A ChArUco diamond (a 3x3 ChArUco board of 4 markers): square and marker side (m), and
    the ids of the one that is the target (OpenCV's order; None: any diamond in view)."""

    square_m: float
    marker_m: float
    ids: tuple[int, int, int, int] | None = None

    def __post_init__(self) -> None:
        if not 0 < self.marker_m < self.square_m:
            raise VisionError("a diamond's markers must be smaller than its squares")


class DiamondTarget:
    """Detects ChArUco diamonds (``CharucoDetector.detectDiamonds``); the detector is built
    once. A diamond's corners come in a marker's order (top-left, top-right, bottom-right,
    bottom-left of its centre square), so its frame is a marker's of side ``square_m``."""

    def __init__(
        self,
        dictionary: cv2.aruco.Dictionary,
        square_to_marker_ratio: float,
        params: cv2.aruco.DetectorParameters | None = None,
    ) -> None:
        if not square_to_marker_ratio > 1.0:
            raise VisionError("a diamond's square must be larger than its markers (ratio > 1)")
        board = cv2.aruco.CharucoBoard((3, 3), square_to_marker_ratio, 1.0, dictionary)
        self.params = params if params is not None else cv2.aruco.DetectorParameters()
        self._detector = cv2.aruco.CharucoDetector(
            board, cv2.aruco.CharucoParameters(), self.params
        )

    def detect(
        self, image: NDArray[Any], markers: MarkerDetections | None = None
    ) -> tuple[list[Diamond], MarkerDetections]:
        """The diamonds in view and the markers found on the way (or given: ``markers``, from
        a detection already made on this image)."""
        if markers is not None and len(markers):
            mc, mi = markers.as_opencv()
            corners, ids, m_corners, m_ids = self._detector.detectDiamonds(
                to_gray(image), markerCorners=mc, markerIds=mi
            )
        else:
            corners, ids, m_corners, m_ids = self._detector.detectDiamonds(to_gray(image))
        markers = MarkerDetections.from_opencv(m_corners, m_ids)
        if ids is None:
            return [], markers
        out = []
        for c, i in zip(corners, ids, strict=True):
            v = np.asarray(i).ravel()
            out.append(
                Diamond(
                    (int(v[0]), int(v[1]), int(v[2]), int(v[3])),
                    np.asarray(c, np.float64).reshape(4, 2),
                )
            )
        return out, markers


def detect_diamonds(
    image: NDArray[Any],
    dictionary: cv2.aruco.Dictionary,
    square_to_marker_ratio: float,
    params: cv2.aruco.DetectorParameters | None = None,
) -> list[Diamond]:
    """Every ChArUco diamond in view (``square_to_marker_ratio`` = square / marker side)."""
    return DiamondTarget(dictionary, square_to_marker_ratio, params).detect(image)[0]
