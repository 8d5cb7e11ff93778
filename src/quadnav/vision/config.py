"""The marker pipeline's settings (``quadnav markers``, vision in the loop), and the mapping
from thesis 000's ``vision_params.yml`` onto them."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Literal, Self

from pydantic import Field, model_validator
from scipy.spatial.transform import Rotation

from quadnav.config_model import ConfigModel
from quadnav.errors import VisionError
from quadnav.geometry.rotations import Pose
from quadnav.vision.calibration import BoardNames, charuco_board_problem
from quadnav.vision.markers import CharucoSpec, DiamondSpec, get_dictionary
from quadnav.vision.pipeline import FallbackGate, MapBoard, MapDiamond, MapMarker, MarkerMap
from quadnav.vision.pose import mount_pose

__all__ = ["MarkersConfig", "from_thesis_vision_params"]

Vec3 = tuple[float, float, float]


class CharucoSection(ConfigModel):
    squares_x: int = Field(12, ge=2)
    squares_y: int = Field(17, ge=2)
    square_m: float = Field(0.066, gt=0)
    marker_m: float = Field(0.0397, gt=0)
    legacy_pattern: bool = False
    min_markers: int = Field(
        2, ge=1, le=2, description="markers next to a corner to interpolate it (OpenCV: 2)"
    )
    marker_fallback: bool = Field(
        True, description="with < 4 chessboard corners, the pose from the board's marker corners"
    )
    fallback_max_sigma_m: float = Field(
        0.05,
        gt=0,
        le=10,
        description="a marker fallback's pose is used only with a position sigma up to this "
        "(an ambiguous one's spans both solutions)",
    )
    fallback_max_speed_m_s: float = Field(
        1.0, ge=0, le=100, description="and only within this speed of the run's last pose"
    )
    fallback_max_rate_deg_s: float = Field(
        90.0, ge=0, le=3600, description="and only within this turn rate of the run's last pose"
    )

    def fallback_gate(self) -> FallbackGate:
        return FallbackGate(
            max_sigma_m=self.fallback_max_sigma_m,
            max_speed_m_s=self.fallback_max_speed_m_s,
            max_rate_deg_s=self.fallback_max_rate_deg_s,
        )


class DiamondSection(ConfigModel):
    """A ChArUco diamond (thesis 000 sec. 3.3): square and marker side; the world is the centre
    of its middle square (x right, y up, z out of the face)."""

    square_m: float = Field(0.066, gt=0)
    marker_m: float = Field(0.0397, gt=0)
    ids: tuple[int, int, int, int] | None = Field(
        None, description="the diamond's four marker ids (None: any diamond in view)"
    )

    @model_validator(mode="after")
    def _check(self) -> Self:
        if self.marker_m >= self.square_m:
            raise ValueError("diamond.marker_m must be smaller than diamond.square_m")
        return self

    def spec(self) -> DiamondSpec:
        return DiamondSpec(self.square_m, self.marker_m, self.ids)


class MapMarkerEntry(ConfigModel):
    id: int = Field(ge=0)
    length_m: float = Field(gt=0)
    position_m: Vec3 = (0.0, 0.0, 0.0)
    rpy_deg: Vec3 = (0.0, 0.0, 0.0)


class MapBoardEntry(ConfigModel):
    charuco: CharucoSection
    position_m: Vec3 = (0.0, 0.0, 0.0)
    rpy_deg: Vec3 = (0.0, 0.0, 0.0)


class MapDiamondEntry(ConfigModel):
    diamond: DiamondSection
    position_m: Vec3 = (0.0, 0.0, 0.0)
    rpy_deg: Vec3 = (0.0, 0.0, 0.0)


def _pose(position_m: Vec3, rpy_deg: Vec3) -> Pose:
    r, p, y = rpy_deg
    return Pose(Rotation.from_euler("ZYX", [y, p, r], degrees=True), list(position_m))  # type: ignore[arg-type]


class MarkersConfig(ConfigModel):
    """What the camera looks at and how the pipeline runs (defaults: thesis 000's rig)."""

    dictionary: str | int = "DICT_4X4_250"
    target: Literal["marker", "charuco", "diamond", "map"] = Field(
        "marker",
        description="marker: one marker is the world; charuco: a board is; diamond: a ChArUco "
        "diamond is; map: markers/boards/diamonds placed in the world. Every target's frame "
        "has z out of its printed face",
    )
    marker_id: int | None = Field(
        None, description="the world's marker (None: the lowest id in view)"
    )
    marker_length_m: float = Field(0.2335, gt=0)
    charuco: CharucoSection = CharucoSection()
    diamond: DiamondSection = DiamondSection()
    map_markers: list[MapMarkerEntry] = Field(default_factory=list)
    map_boards: list[MapBoardEntry] = Field(default_factory=list)
    map_diamonds: list[MapDiamondEntry] = Field(default_factory=list)
    camera_file: str | None = Field(
        None, description="OpenCV YAML calibration (camera_matrix, distortion_coefficients)"
    )
    detector_file: str | None = Field(None, description="OpenCV YAML detector parameters")
    detector: dict[str, float] = Field(
        default_factory=lambda: {"cornerRefinementMethod": 1.0},
        description="detector parameters (override the file's); default: sub-pixel corners",
    )
    mount_rpy_deg: Vec3 = Field(
        (180.0, 0.0, 180.0), description="camera in the body (thesis: down, turned 180 deg)"
    )
    mount_xyz_m: Vec3 = (0.0, 0.0, 0.0)
    fps: float = Field(
        30.0,
        gt=0,
        description="frame rate of an image folder or a stream without timestamps (raw .h264); "
        "asked of a live camera when set",
    )
    frame_width_px: int | None = Field(None, ge=1, description="asked of a live camera")
    frame_height_px: int | None = Field(None, ge=1, description="asked of a live camera")
    exposure_time_100us: int | None = Field(
        None, ge=0, description="asked of a live camera, V4L2 unit (100 us); 0: automatic"
    )
    show: bool = Field(False, description="show the overlay in a window (needs a display)")
    show_rejected: bool = Field(False, description="draw the rejected marker candidates")
    write_images: bool = Field(False, description="save every overlay frame to images/")
    max_images_mb: float = Field(
        200.0, gt=0, le=1e7, description="write_images stops before images/ passes this (MB)"
    )
    max_rms_px: float = Field(
        3.0, gt=0, description="poses with a larger reprojection error are refused"
    )
    prior_sigma_px: float = Field(
        0.25, gt=0, description="corner noise prior of the pose covariance"
    )
    video: bool = Field(True, description="write the overlay video")
    max_frames: int | None = Field(None, ge=1)

    @model_validator(mode="after")
    def _check(self) -> Self:
        if self.target == "map" and not (self.map_markers or self.map_boards or self.map_diamonds):
            raise ValueError("target=map needs map_markers, map_boards or map_diamonds")
        if self.charuco.marker_m >= self.charuco.square_m:
            raise ValueError("charuco.marker_m must be smaller than charuco.square_m")
        if problem := self._board_problem():
            raise ValueError(problem)
        return self

    def _board_problem(self) -> str | None:
        """The dictionary, the world marker's id and each board, in the configuration's keys."""
        try:
            size = int(get_dictionary(self.dictionary).bytesList.shape[0])
        except VisionError as exc:
            return f"dictionary: {exc}"
        ids = [("marker_id", self.marker_id)] + [
            (f"map_markers[{i}].id", m.id) for i, m in enumerate(self.map_markers)
        ]
        for key, i in ids:
            if i is not None and i >= size:
                return f"{key} ({i}) is not in {self.dictionary} (ids 0 to {size - 1})"
        boards = [("charuco", self.charuco)] if self.target == "charuco" else []
        boards += [(f"map_boards[{i}].charuco", b.charuco) for i, b in enumerate(self.map_boards)]
        for key, c in boards:
            names = BoardNames(
                f"{key}.squares_x",
                f"{key}.squares_y",
                f"{key}.square_m",
                f"{key}.marker_m",
                "dictionary",
            )
            if problem := charuco_board_problem(
                (c.squares_x, c.squares_y), c.square_m, c.marker_m, self.dictionary, names
            ):
                return problem
        return None

    def T_B_C(self) -> Pose:
        return mount_pose(self.mount_rpy_deg, self.mount_xyz_m)

    def marker_map(self, seen_id: int | None = None) -> MarkerMap:
        """The scene; for ``target=marker`` with no ``marker_id``, ``seen_id`` is the world."""
        if self.target == "marker":
            mid = (
                self.marker_id
                if self.marker_id is not None
                else (seen_id if seen_id is not None else 0)
            )
            return MarkerMap.single_marker(mid, self.marker_length_m, self.dictionary)
        if self.target == "charuco":
            return MarkerMap(
                self.dictionary, boards=[MapBoard(self.charuco_spec(self.charuco), Pose.identity())]
            )
        if self.target == "diamond":
            return MarkerMap(
                self.dictionary, diamonds=[MapDiamond(self.diamond.spec(), Pose.identity())]
            )
        return MarkerMap(
            self.dictionary,
            {
                m.id: MapMarker(m.id, m.length_m, _pose(m.position_m, m.rpy_deg))
                for m in self.map_markers
            },
            [
                MapBoard(self.charuco_spec(b.charuco), _pose(b.position_m, b.rpy_deg))
                for b in self.map_boards
            ],
            [
                MapDiamond(d.diamond.spec(), _pose(d.position_m, d.rpy_deg))
                for d in self.map_diamonds
            ],
        )

    def charuco_spec(self, c: CharucoSection) -> CharucoSpec:
        return CharucoSpec(
            c.squares_x, c.squares_y, c.square_m, c.marker_m, self.dictionary, c.legacy_pattern
        )


def _thesis_bool(value: object) -> bool:
    """The thesis program reads a flag as the string ``"true"`` (anything else is false)."""
    return str(value).strip().lower() in ("true", "1")


def from_thesis_vision_params(
    values: Mapping[str, object],
) -> tuple[dict[str, object], list[str]]:
    """Thesis 000's ``vision_params.yml`` (dict_type, marker_length, charuco, squaresX...)
    as :class:`MarkersConfig` keys (a raw configuration, for ``load_config``'s ``base``);
    returns them and the keys left out."""
    out: dict[str, object] = {}
    used = {"charuco", "diamond", "squaresX", "squaresY", "squareLength", "markerLength"}
    for theirs, ours, cast in (
        ("dict_type", "dictionary", int),
        ("marker_length", "marker_length_m", float),
        ("fps", "fps", float),
        ("camera_parameters", "camera_file", str),
        ("frame_width", "frame_width_px", int),
        ("frame_height", "frame_height_px", int),
        ("exposure_time", "exposure_time_100us", int),
        ("open_window", "show", _thesis_bool),
        ("show_rejected", "show_rejected", _thesis_bool),
        ("write_images", "write_images", _thesis_bool),
    ):
        if theirs in values:
            out[ours] = _thesis_value(values, theirs, cast)
            used.add(theirs)
    lengths = {
        "square_m": _thesis_value(values, "squareLength", float, 0.066),
        "marker_m": _thesis_value(values, "markerLength", float, 0.0397),
    }
    # The thesis's program tries a board first, then a diamond (its squareLength and
    # markerLength are the diamond's too), then single markers.
    if values.get("charuco"):
        out["target"] = "charuco"
        out["charuco"] = {
            "squares_x": _thesis_value(values, "squaresX", int, 12),
            "squares_y": _thesis_value(values, "squaresY", int, 17),
            **lengths,
        }
    elif values.get("diamond"):
        out["target"] = "diamond"
        out["diamond"] = lengths
    return out, sorted(set(values) - used)


def _thesis_value(
    values: Mapping[str, object],
    key: str,
    cast: Callable[[Any], object],
    default: object = None,
) -> object:
    """``values[key]`` read as ``cast`` wants; a value it cannot read names the thesis key."""
    value = values.get(key, default)
    try:
        return cast(value)
    except (TypeError, ValueError):
        names: dict[object, str] = {int: "a whole number", float: "a number", str: "a file name"}
        what = names.get(cast, "a flag")
        raise VisionError(f"{key} must be {what}, got {value!r}") from None
