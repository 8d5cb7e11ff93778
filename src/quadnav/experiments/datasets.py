"""``quadnav dataset make``: a visual-inertial dataset rendered in a 3-D world along a motion.

A motion (a built-in sequence's flight, a trajectory file through a smooth spline, or a
simulated flight) moves a camera-IMU rig through a textured world. Each camera is rendered at
its own rate, with its time offset, motion blur over its exposure, lighting changes and sensor
noise; the IMU is synthesized from the same spline with its noise and bias random walks. The
result is an EuRoC ASL folder (``mav0/``) that VINS-Mono, OpenVINS, ORB-SLAM3 and Kimera read as
they read EuRoC, with ``dataset.json`` (what was made and how) and ``groundtruth.tum`` (for evo).
Everything is deterministic per seed: every stream has its own generator keyed by its name.

Sensors are realistic by default (``sensors: realistic``; ``ideal`` gives what the data was made
with, exactly): the IMU's turn-on biases are drawn from its rig's stated spread, its white noise is
the level a real one shows in flight (:meth:`~quadnav.rig.ImuNoiseModel.euroc_adis16448_in_flight`)
while ``imu0/sensor.yaml`` states the datasheet's, each camera is late or early on the IMU by an
offset the calibration does not state, and its stated ``T_B_C`` and intrinsics carry a
calibration error. The calibration the data was made with is written to ``truth/`` beside ``mav0/``
(``quadnav vio DIR --calibration DIR/truth`` runs on it); ``dataset.json`` says what was drawn.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.random import Generator
from numpy.typing import NDArray
from pydantic import Field
from scipy.spatial.transform import Rotation

from quadnav.config_model import ConfigModel
from quadnav.errors import ConfigError, ExperimentError, GeometryError
from quadnav.experiments.dataset_motions import FlightPath, flight_path_trajectory
from quadnav.experiments.nav_channels import channel_rng
from quadnav.geometry.rotations import Pose
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.config import load_config
from quadnav.io.run_folder import write_text
from quadnav.io.trajectory_io import write_tum
from quadnav.rig import CameraSpec, DepthSpec, ImuNoiseModel, ImuSpec, Rig, rig_named
from quadnav.sim.motion import ImuSeries, SplineMotion, synthesize_imu
from quadnav.sim.render import RenderedFrame, RenderEffects, depth_noise
from quadnav.units import NS_PER_S, s_to_ns

if TYPE_CHECKING:
    from quadnav.io.datasets import EurocWriter, VisualInertialDataset
    from quadnav.sim.scene import Scene

__all__ = [
    "SEQUENCES",
    "DatasetMade",
    "DatasetPlan",
    "SequenceSpec",
    "make_dataset",
    "miscalibrated_cameras",
    "plan_dataset",
    "rendered_dataset",
    "sequence_spec",
    "stream_rng",
    "synthesize_dataset_imu",
]

FloatArray = NDArray[np.float64]
U8 = NDArray[np.uint8]
#: The first stamp of a built-in flight (2023-11-14, in the Unix-epoch nanoseconds EuRoC uses).
T0_NS = 1_700_000_000 * NS_PER_S

Vec3 = tuple[float, float, float]
Progress = Callable[[int, int, str], None]


#: The longest sequence ``dataset make`` writes (s): 30 minutes.
MAX_DURATION_S = 1800.0


class SequenceSpec(ConfigModel):
    """What a sequence is made of: the world, the rig, the motion and the image conditions.

    ``motion`` is ``flight_path`` (the Lissajous flight of ``flight_*`` and ``mean_speed_m_s``,
    standing still for ``still_s`` first, as EuRoC's sequences do), ``laps`` (laps of the box's
    ellipse, the later ones higher and turned: see :mod:`quadnav.experiments.dataset_motions`),
    a trajectory file (TUM, EuRoC ground truth...) or a ``quadnav run``/``sim`` scenario name.
    ``exposure_s`` sets the motion blur (0: none), ``lighting`` the depth of the slow exposure
    changes (0: constant, 0.5: from half to one and a half), ``texture_poor`` the fraction of
    surfaces without texture; left out (None), they are the profile's: a realistic ``exposure_s``
    of 5 ms and ``lighting`` of 0.15 (``room_medium``'s), the ideal 2 ms and 0.
    ``sensors`` is the profile (see the module): ``realistic`` draws the IMU's turn-on biases
    (``imu_bias0_scale`` times the rig's spread), scales the white noise the rotors add in flight
    over the IMU's level on the ground by ``imu_vibration`` (1: the rig's in-flight level; 0:
    the ground level throughout), a camera-IMU time offset the calibration does
    not state (``time_offset_error_s`` at most, half of it at least, of either sign; on top of the
    stated ``time_offset_s``), and a calibration error: the cameras' common camera-IMU extrinsic
    (rotation ``calib_rotation_deg`` and lever arm ``calib_translation_m``, RMS norms), each
    camera's own (``calib_stereo_rotation_deg``, ``calib_stereo_translation_m``: a stereo pair's
    relative pose is calibrated far better), focal lengths ``calib_focal`` relative and principal
    point ``calib_principal_px``, per coordinate, both cameras of a pair alike but for their own
    ``calib_stereo_focal`` and ``calib_stereo_principal_px``; all normal. A motion file's gaps up
    to ``max_gap_s`` are bridged; ``knot_spacing_s`` sets its spline's smoothing (None: the
    larger of 0.1 s and 4 pose periods). ``motion_frame`` says whose poses the motion gives: a vehicle's
    (FLU; the rig rides on it at its ``T_V_B``) or the rig body's itself (a dataset's ground
    truth); ``auto``: the vehicle's for ``flight_path`` and scenarios, the body's for files.
    ``read_noise`` the sensor's read noise in grey levels,
    ``shot_noise_dn`` its photon noise (variance per grey level: 0.03 gives 2 grey levels at
    mid-grey), ``target_grey`` and ``auto_exposure_s`` the mean its auto exposure aims at and how
    fast it gets there (0: no auto exposure, the light as it is), ``vignetting`` the light lost in
    the corners (EuRoC's MT9M034 images darken towards them). ``world_seed`` draws the world
    (its textures and furniture, clear of the flight of that seed): a second flight in the
    world of another (None: ``seed``'s own), as thesis 003's flights on a saved map."""

    world: str
    rig: str = "euroc"
    motion: str = "flight_path"
    duration_s: float = Field(default=60.0, gt=0.0, le=MAX_DURATION_S)
    mean_speed_m_s: float = Field(default=0.5, gt=0.0, le=10.0)
    yaw_sway_deg: float = Field(default=20.0, ge=0.0, le=180.0)
    yaw_sway_period_s: float = Field(default=6.0, gt=0.5, le=600.0)
    flight_centre_m: Vec3 = (0.0, 0.0, 1.4)
    flight_half_extent_m: Vec3 = (2.0, 1.6, 0.5)
    still_s: float = Field(default=2.0, ge=0.0, le=600.0)
    exposure_s: float | None = Field(default=None, ge=0.0, le=0.05)
    lighting: float | None = Field(default=None, ge=0.0, le=0.9)
    texture_poor: float = Field(default=0.0, ge=0.0, le=1.0)
    read_noise: float = Field(default=2.0, ge=0.0, le=50.0)
    shot_noise_dn: float = Field(default=0.03, ge=0.0, le=10.0)
    target_grey: float = Field(default=120.0, gt=0.0, le=255.0)
    auto_exposure_s: float = Field(default=1.0, ge=0.0, le=60.0)
    vignetting: float = Field(default=0.15, ge=0.0, le=0.9)
    time_offset_s: float = Field(default=0.0, ge=-0.1, le=0.1)
    motion_frame: Literal["auto", "vehicle", "body"] = "auto"
    imu_noise: bool = True
    sensors: Literal["realistic", "ideal"] = "realistic"
    imu_bias0_scale: float = Field(default=1.0, ge=0.0, le=10.0)
    imu_vibration: float = Field(default=1.0, ge=0.0, le=10.0)
    time_offset_error_s: float = Field(default=0.005, ge=0.0, le=0.05)
    calib_rotation_deg: float = Field(default=0.5, ge=0.0, le=10.0)
    calib_translation_m: float = Field(default=0.005, ge=0.0, le=0.5)
    calib_stereo_rotation_deg: float = Field(default=0.05, ge=0.0, le=10.0)
    calib_stereo_translation_m: float = Field(default=0.0005, ge=0.0, le=0.5)
    calib_focal: float = Field(default=0.005, ge=0.0, le=0.2)
    calib_principal_px: float = Field(default=1.0, ge=0.0, le=50.0)
    calib_stereo_focal: float = Field(default=0.0005, ge=0.0, le=0.2)
    calib_stereo_principal_px: float = Field(default=0.2, ge=0.0, le=50.0)
    knot_spacing_s: float | None = Field(default=None, gt=0.0, le=10.0)
    max_gap_s: float = Field(default=1.0, gt=0.0, le=60.0)
    seed: int = Field(default=0, ge=0, le=2**31 - 1)
    world_seed: int | None = Field(default=None, ge=0, le=2**31 - 1)
    description: str = ""


#: The built-in motions through the flight box, by ``SequenceSpec.motion``: the kind of path.
BUILT_IN_PATHS: Mapping[str, str] = {"flight_path": "lissajous", "laps": "laps"}


def _seq(**kw: object) -> SequenceSpec:
    return SequenceSpec.model_validate(kw)


#: The built-in sequences, graded like EuRoC's (V1_01 easy: 0.41 m/s and 16 deg/s; V1_02
#: medium: 0.91 m/s, 32 deg/s; V1_03 difficult: 0.75 m/s, 77 deg/s, blur and dark parts).
SEQUENCES: Mapping[str, SequenceSpec] = {
    "room_easy": _seq(
        world="room", duration_s=60.0, mean_speed_m_s=0.45, yaw_sway_deg=15.0,
        exposure_s=0.002, lighting=0.0, read_noise=1.5,
        description="the room, slow (0.45 m/s), steady light, little blur",
    ),
    "room_medium": _seq(
        world="room", duration_s=70.0, mean_speed_m_s=0.9, yaw_sway_deg=35.0,
        yaw_sway_period_s=4.0, exposure_s=0.005, lighting=0.15,
        description="the room at 0.9 m/s, faster turns, some blur and light changes",
    ),
    "room_difficult": _seq(
        world="room", duration_s=60.0, mean_speed_m_s=1.2, yaw_sway_deg=60.0,
        yaw_sway_period_s=3.0, exposure_s=0.01, lighting=0.4, texture_poor=0.35, read_noise=3.0,
        description="the room at 1.2 m/s, fast turns, strong blur, dark and bright spells, bare walls",
    ),
    "hall_easy": _seq(
        world="hall", duration_s=90.0, mean_speed_m_s=0.6, yaw_sway_deg=20.0,
        flight_centre_m=(0.0, 0.0, 2.0), flight_half_extent_m=(5.0, 3.5, 1.0), exposure_s=0.003,
        lighting=0.0, description="the machine hall, slow (0.6 m/s) through a large space",
    ),
    "hall_difficult": _seq(
        world="hall", duration_s=90.0, mean_speed_m_s=1.3, yaw_sway_deg=50.0,
        yaw_sway_period_s=4.0, flight_centre_m=(0.0, 0.0, 2.0),
        flight_half_extent_m=(5.0, 3.5, 1.2), exposure_s=0.008, lighting=0.5, texture_poor=0.3,
        read_noise=3.0, description="the hall at 1.3 m/s, blur, dark spells, bare surfaces",
    ),
    "room_laps": _seq(
        world="room", motion="laps", duration_s=42.0, mean_speed_m_s=0.6, yaw_sway_deg=10.0,
        exposure_s=0.003, lighting=0.1,
        description="two laps of the room at 0.6 m/s, the second 0.3 m higher and turned "
        "25 degrees (loop closure)",
    ),
    "hall_laps": _seq(
        world="hall", motion="laps", duration_s=75.0, mean_speed_m_s=0.8, yaw_sway_deg=10.0,
        flight_centre_m=(0.0, 0.0, 2.0), flight_half_extent_m=(5.0, 3.5, 1.0), exposure_s=0.003,
        lighting=0.1,
        description="two laps of the hall at 0.8 m/s, the second 0.6 m higher and turned 25 "
        "degrees (loop closure)",
    ),
    "yard": _seq(
        world="yard", duration_s=120.0, mean_speed_m_s=1.5, yaw_sway_deg=25.0,
        flight_centre_m=(0.0, 0.0, 4.0), flight_half_extent_m=(15.0, 10.0, 2.0),
        exposure_s=0.002, lighting=0.2,
        description="outdoors among buildings and trees, 1.5 m/s at 2-6 m",
    ),
}  # fmt: skip


def sequence_spec(
    name: str, fields: Mapping[str, object] | None = None, overrides: Iterable[str] = ()
) -> SequenceSpec:
    """A built-in sequence, or a world name with defaults; ``fields`` replace fields (the
    command's own options), then ``overrides`` (``key=value``, the ``--set`` options)."""
    from quadnav.sim.scene import WORLDS

    if name in SEQUENCES:
        base = SEQUENCES[name].model_dump()
    elif name in WORLDS:
        base = {"world": name}
    else:
        raise ConfigError(
            f"unknown sequence or world {name!r}; sequences: {', '.join(SEQUENCES)}; "
            f"worlds: {', '.join(WORLDS)}"
        )
    base.update(fields or {})
    overrides = list(overrides)
    if "duration_s" not in (fields or {}) and _whole_motion(base, overrides):
        base["duration_s"] = MAX_DURATION_S  # (the span stops at the motion's end)
    spec = with_profile(load_config(SequenceSpec, None, overrides, base=base))
    if spec.world not in WORLDS:
        raise ConfigError(f"world must be one of {', '.join(WORLDS)}, got {spec.world!r}")
    try:
        rig_named(spec.rig)  # an unknown rig is said now, not after the motion is built
    except GeometryError as exc:
        raise ConfigError(f"--rig: {exc}") from None
    return spec


def _whole_motion(base: Mapping[str, object], overrides: Sequence[str]) -> bool:
    """Whether a sequence is made to its motion's end: a motion file or scenario (not a
    built-in flight) with no duration given, by ``--duration`` or ``--set duration_s=``; a
    motion file used to be cut at the built-in flights' 60 s without a word."""
    from quadnav.io.config import apply_override

    asked: dict[str, object] = {}
    for o in overrides:
        if o.partition("=")[0].strip() in ("motion", "duration_s"):
            apply_override(asked, o)
    motion = asked.get("motion", base.get("motion"))
    return "duration_s" not in asked and isinstance(motion, str) and motion not in BUILT_IN_PATHS


#: The image conditions a sequence without its own takes, by sensor profile: the realistic
#: ones are ``room_medium``'s (5 ms of exposure, lighting from 0.85 to 1.15), the ideal ones the
#: steady light and short exposure motion files were made with before.
PROFILE_IMAGES: Mapping[str, Mapping[str, float]] = {
    "realistic": {"exposure_s": 0.005, "lighting": 0.15},
    "ideal": {"exposure_s": 0.002, "lighting": 0.0},
}


def with_profile(spec: SequenceSpec) -> SequenceSpec:
    """``spec`` with the image conditions it leaves out (None) taken from its sensor profile."""
    fill = {k: v for k, v in PROFILE_IMAGES[spec.sensors].items() if getattr(spec, k) is None}
    return spec.model_copy(update=fill) if fill else spec


def stream_rng(seed: int, name: str) -> Generator:
    """The generator of one stream (``imu``, ``cam0``, ``lighting``...), keyed by its name as
    the main job's channels are (:func:`~quadnav.experiments.nav_channels.channel_rng`), so
    adding a camera changes no other stream."""
    return channel_rng(seed, name)


@dataclass(frozen=True, slots=True, kw_only=True)
class DatasetMade:
    """What ``make_dataset`` wrote: the folder, its counts, the motion's figures and the cost."""

    root: Path
    sequence: str
    world: str
    rig: str
    duration_s: float
    frames: int
    imu_samples: int
    distance_m: float
    mean_speed_m_s: float
    mean_rate_deg_s: float
    size_bytes: int
    seconds: float

    def to_json(self) -> dict[str, object]:
        d = asdict(self)
        d["root"] = str(self.root)
        return d


def _lighting_gain(t_s: FloatArray, depth: float, rng: Generator) -> FloatArray:
    """A slow exposure gain around 1 (three sines of 5-20 s periods), within 1 +- depth."""
    if depth == 0.0:
        return np.ones_like(t_s)
    periods = rng.uniform(5.0, 20.0, 3)
    phases = rng.uniform(0.0, 2.0 * math.pi, 3)
    wave = sum(np.sin(2.0 * math.pi * t_s / p + f) for p, f in zip(periods, phases, strict=True))
    return np.asarray(1.0 + depth * np.asarray(wave) / 3.0 * 1.5, dtype=np.float64).clip(
        1.0 - depth, 1.0 + depth
    )


def _motion_figures(p: FloatArray, q_xyzw: FloatArray, dt_s: float) -> tuple[float, float, float]:
    """Distance (m), mean speed (m/s) and mean rotation rate (deg/s) of sampled poses."""
    from scipy.spatial.transform import Rotation

    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    R = Rotation.from_quat(q_xyzw)
    ang = (R[:-1].inv() * R[1:]).magnitude()
    span = dt_s * max(len(p) - 1, 1)
    return float(step.sum()), float(step.sum() / span), float(np.degrees(ang.sum() / span))


def _folder_size(root: Path) -> int:
    return sum(f.stat().st_size for f in root.rglob("*") if f.is_file())


def _write_manifest(
    root: Path, spec: SequenceSpec, name: str, made: DatasetMade, sensors: Mapping[str, object]
) -> None:
    doc = {"sequence": name, "spec": spec.model_dump(), "sensors": sensors, "made": made.to_json()}
    write_text(root / "dataset.json", json.dumps(doc, indent=2) + "\n")


def _camera_times(t0_ns: int, t1_ns: int, cam: CameraSpec) -> NDArray[np.int64]:
    period = round(NS_PER_S / cam.rate_hz)
    return np.arange(t0_ns, t1_ns + 1, period, dtype=np.int64)


def _body_poses(motion: SplineMotion, t_ns: NDArray[np.int64]) -> list[Pose]:
    p, q = motion.pose(t_ns)
    return [Pose.from_quat_xyzw(qi, pi) for pi, qi in zip(p, q, strict=True)]


def check_rig(rig: Rig) -> None:
    if rig.imu is None:
        raise ConfigError(f"--rig {rig.name}: a dataset needs an IMU")
    if not np.allclose(rig.imu.T_B_I.matrix(), np.eye(4)):
        raise ConfigError(f"--rig {rig.name}: the IMU must be the body frame (T_B_I identity)")


def resolve_rig(name: str) -> Rig:
    rig = rig_named(name)
    check_rig(rig)
    return rig


@dataclass(frozen=True, slots=True, kw_only=True)
class _Shot:
    """One camera at one stamp: the IMU-time poses over its exposure and its gain."""

    camera: CameraSpec
    t_ns: int
    poses: list[Pose]
    gain: float


def _blur_poses(motion: SplineMotion, cam: CameraSpec, t_mid_ns: int, depth_m: float) -> list[Pose]:
    """Camera poses over the exposure centred on ``t_mid_ns``: one per ~1.5 px of image motion
    (from the rotation rate and the speed over the scene's depth), at most 9. Where the
    exposure reaches past either end of the motion (a sequence made to a motion file's end),
    the pose at that end holds."""
    T_B_C = cam.T_B_C
    if cam.exposure_s <= 0.0:
        return [pose @ T_B_C for pose in _body_poses(motion, np.array([t_mid_ns]))]
    w = np.linalg.norm(motion.angular_rate_B(np.array([t_mid_ns]))[0])
    v = np.linalg.norm(motion.velocity(np.array([t_mid_ns]))[0])
    f = float(cam.camera.K[0, 0])
    blur_px = f * cam.exposure_s * (w + v / max(depth_m, 0.3))
    n = int(min(max(math.ceil(blur_px / 1.5), 1), 9))
    half = 0.5 * cam.exposure_s * NS_PER_S
    ts = np.round(t_mid_ns + np.linspace(-half, half, n) if n > 1 else np.array([t_mid_ns]))
    ts = np.clip(ts.astype(np.int64), int(motion.t_start_ns), int(motion.t_end_ns))
    return [pose @ T_B_C for pose in _body_poses(motion, ts)]


def _motion(spec: SequenceSpec) -> SplineMotion:
    """The spline the rig follows: the built-in flight, a file's poses, or a flight's truth."""
    from quadnav.experiments.motions import (
        SCENARIO_KNOT_SPACING_S,
        motion_from_file,
        motion_from_scenario,
        motion_scenarios,
    )

    if spec.motion in BUILT_IN_PATHS:
        path = FlightPath(
            kind=BUILT_IN_PATHS[spec.motion],
            centre_m=spec.flight_centre_m,
            half_extent_m=spec.flight_half_extent_m,
            mean_speed_m_s=spec.mean_speed_m_s,
            yaw_sway_deg=spec.yaw_sway_deg,
            yaw_sway_period_s=spec.yaw_sway_period_s,
            still_s=spec.still_s,
            duration_s=spec.duration_s + 1.0,
            seed=spec.seed,
        )
        return SplineMotion.fit(flight_path_trajectory(path, t0_ns=T0_NS), knot_spacing_s=0.05)
    try:
        if spec.motion in motion_scenarios():
            knots = spec.knot_spacing_s or SCENARIO_KNOT_SPACING_S
            return motion_from_scenario(spec.motion, spec.seed, knot_spacing_s=knots)
        path_ = Path(spec.motion)
        if not path_.exists():
            raise ConfigError(
                f"--motion {spec.motion!r} is neither flight_path, laps, a scenario "
                f"({', '.join(motion_scenarios())}) nor a file"
            )
        return motion_from_file(path_, max_gap_s=spec.max_gap_s, knot_spacing_s=spec.knot_spacing_s)
    except ExperimentError as exc:
        if "knot_spacing_s" in str(exc) and "--set" not in str(exc):
            raise ExperimentError(f"--motion: {exc} (--set knot_spacing_s=S)") from None
        raise


def _vehicle_motion(spec: SequenceSpec) -> bool:
    if spec.motion_frame != "auto":
        return spec.motion_frame == "vehicle"
    from quadnav.experiments.motions import motion_scenarios

    return spec.motion in BUILT_IN_PATHS or spec.motion in motion_scenarios()


def _rig_body_motion(motion: SplineMotion, T_V_B: Pose) -> SplineMotion:
    """The motion of a rig carried at ``T_V_B`` by a vehicle that makes ``motion``: its poses
    sampled at 1 kHz and fitted again (the rig's lever arm and turned axes included), a chunk
    at a time (:meth:`~quadnav.sim.motion.SplineMotion.fit_sampled`: 30 minutes of 1 kHz
    poses in one piece took ~500 MB)."""
    if np.allclose(T_V_B.matrix(), np.eye(4)):
        return motion

    def body(t: NDArray[np.int64]) -> tuple[FloatArray, FloatArray]:
        p, q = motion.pose(t)
        R_W_V = Rotation.from_quat(q)
        return p + R_W_V.apply(T_V_B.p_A_B), (R_W_V * T_V_B.R_A_B).as_quat()

    return SplineMotion.fit_sampled(
        body, motion.t_start_ns, motion.t_end_ns, s_to_ns(0.001),
        knot_spacing_s=motion.knot_spacing_s, name=motion.name,
    )  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class DatasetPlan:
    """What a sequence is made from: the rig the data is made with (the sequence's exposure,
    the true time offset and calibration, the IMU noise it is synthesized with), the rig the
    dataset states (``mav0/``'s calibration files), the IMU's noise model with its turn-on
    biases (None: an exact IMU; its in-flight level when ``ground_noise`` gives the one on the
    ground before take-off), the motion of the body frame, the span of IMU time it covers
    (ns), and what the sensor profile drew (for ``dataset.json``)."""

    rig: Rig
    stated: Rig
    imu_noise: ImuNoiseModel | None
    motion: SplineMotion
    span: tuple[int, int]
    sensors: Mapping[str, object]
    ground_noise: ImuNoiseModel | None = None


def plan_dataset(spec: SequenceSpec) -> DatasetPlan:
    """The rigs, the body's motion and the span ``make_dataset`` renders (no images)."""
    spec = with_profile(spec)
    rig, stated, imu_noise, drawn = _rigs_for(spec)
    motion = _motion(spec)
    if _vehicle_motion(spec):
        motion = _rig_body_motion(motion, rig.T_V_B)
    imu = resolve_rig(spec.rig).imu
    realistic = spec.sensors == "realistic" and imu_noise is not None and imu is not None
    return DatasetPlan(
        rig=rig,
        stated=stated,
        imu_noise=imu_noise,
        motion=motion,
        span=_span(spec, motion),
        sensors=drawn,
        ground_noise=imu.ground_noise if realistic and imu is not None else None,
    )


def _span(spec: SequenceSpec, motion: SplineMotion) -> tuple[int, int]:
    t0 = int(motion.t_start_ns)
    t1 = min(int(motion.t_end_ns), t0 + s_to_ns(spec.duration_s))
    if t1 - t0 < s_to_ns(1.0):
        raise ConfigError(
            f"--motion {spec.motion}: only {(t1 - t0) / NS_PER_S:.2f} s of motion; a dataset needs 1 s"
        )
    return t0, t1


def _world(spec: SequenceSpec, motion: SplineMotion, t0: int, t1: int) -> Scene:
    from quadnav.sim.scene import WORLDS, WorldPlan

    if spec.world_seed is not None and spec.world_seed != spec.seed:  # another flight's world
        other = spec.model_copy(update={"seed": spec.world_seed, "world_seed": None})
        motion = _motion(other)
        t0, t1 = _span(other, motion)
    t = np.arange(t0, t1, s_to_ns(0.1), dtype=np.int64)
    p, _ = motion.pose(t)
    plan = WorldPlan(
        flight_min_m=tuple(p.min(axis=0)),
        flight_max_m=tuple(p.max(axis=0)),
        seed=spec.seed if spec.world_seed is None else spec.world_seed,
        path_W=p,
        texture_poor=spec.texture_poor,
    )
    return WORLDS[spec.world](plan)


def _drawn_time_offset_s(spec: SequenceSpec) -> float:
    """The offset the calibration does not state: between half ``time_offset_error_s`` and all
    of it, of either sign (a few milliseconds, as a camera's trigger or a driver's stamping)."""
    rng = stream_rng(spec.seed, "time_offset")
    size = spec.time_offset_error_s * rng.uniform(0.5, 1.0)
    return float(size if rng.random() < 0.5 else -size)


def _pose_error(rng: Generator, rotation_deg: float, translation_m: float) -> Pose:
    """A small rigid error: normal rotation and translation of these RMS norms."""
    rot = rng.normal(0.0, math.radians(rotation_deg) / math.sqrt(3.0), 3)
    return Pose(Rotation.from_rotvec(rot), rng.normal(0.0, translation_m / math.sqrt(3.0), 3))


def miscalibrated_cameras(
    spec: SequenceSpec, cameras: tuple[CameraSpec, ...]
) -> tuple[CameraSpec, ...]:
    """``cameras`` as a calibration states them: each ``T_B_C`` off by the rig's camera-IMU
    error (in the body frame, common to its cameras: ``calib_rotation_deg``,
    ``calib_translation_m``) and by a small error of its own (in its own frame: the stereo
    extrinsic a calibration gets far better, ``calib_stereo_rotation_deg`` and
    ``calib_stereo_translation_m``); the first camera's focal lengths (``calib_focal``,
    relative) and principal point (``calib_principal_px``, px per coordinate) off, and each other
    camera's off by as much again plus its own small part (``calib_stereo_focal``,
    ``calib_stereo_principal_px``): a stereo calibration fits the pair on the same views of its
    target, so what it leaves between the two cameras (the rows and disparities of the
    rectified pair) is far smaller than what it leaves in both. All normal (rotation and lever
    arm: RMS norms)."""
    rng = stream_rng(spec.seed, "calibration")
    common = _pose_error(rng, spec.calib_rotation_deg, spec.calib_translation_m)
    out: list[CameraSpec] = []
    focal0 = centre0 = np.zeros(2)
    for i, cam in enumerate(cameras):
        own = _pose_error(rng, spec.calib_stereo_rotation_deg, spec.calib_stereo_translation_m)
        if i == 0:  # the draws of before for the first camera: a mono dataset is unchanged
            focal0 = rng.normal(0.0, spec.calib_focal, 2)
            centre0 = rng.normal(0.0, spec.calib_principal_px, 2)
            focal, centre = focal0, centre0
        else:
            focal = focal0 + rng.normal(0.0, spec.calib_stereo_focal, 2)
            centre = centre0 + rng.normal(0.0, spec.calib_stereo_principal_px, 2)
        out.append(_with_errors(cam, common, own, focal, centre))
    return tuple(out)


def _with_errors(
    cam: CameraSpec,
    rig_error: Pose,
    own: Pose,
    focal: NDArray[np.float64],
    centre: NDArray[np.float64],
) -> CameraSpec:
    """``cam`` with its ``T_B_C`` off by ``rig_error`` (body frame) and ``own`` (its own), its
    focal lengths by the relative ``focal`` and its principal point by ``centre`` px."""
    K = cam.camera.K.copy()
    K[0, 0] *= 1.0 + focal[0]
    K[1, 1] *= 1.0 + focal[1]
    K[0, 2] += centre[0]
    K[1, 2] += centre[1]
    return replace(cam, camera=replace(cam.camera, K=K), T_B_C=rig_error @ cam.T_B_C @ own)


def _calibration_error(true: CameraSpec, stated: CameraSpec) -> dict[str, float]:
    """How far a stated camera is from the true one (for ``dataset.json``)."""
    d = true.T_B_C.inverse() @ stated.T_B_C
    Kt, Ks = true.camera.K, stated.camera.K
    return {
        "rotation_deg": float(np.degrees(d.R_A_B.magnitude())),
        "translation_m": float(np.linalg.norm(d.p_A_B)),
        "fx_rel": float(Ks[0, 0] / Kt[0, 0] - 1.0),
        "fy_rel": float(Ks[1, 1] / Kt[1, 1] - 1.0),
        "cx_px": float(Ks[0, 2] - Kt[0, 2]),
        "cy_px": float(Ks[1, 2] - Kt[1, 2]),
    }


def _imu_noise(spec: SequenceSpec, imu: ImuSpec) -> ImuNoiseModel | None:
    """The noise the IMU is synthesized with: none, the stated one (ideal), or its in-flight
    level with turn-on biases drawn from its spread (realistic)."""
    if not spec.imu_noise:
        return None
    if spec.sensors == "ideal":
        return imu.noise
    flight = imu.flight_noise or imu.noise
    if imu.ground_noise is not None and spec.imu_vibration != 1.0:
        flight = with_vibration(flight, imu.ground_noise, spec.imu_vibration)
    return flight.draw_turn_on_biases(stream_rng(spec.seed, "imu_bias0"), spec.imu_bias0_scale)


def with_vibration(flight: ImuNoiseModel, ground: ImuNoiseModel, scale: float) -> ImuNoiseModel:
    """``flight`` with the white noise it adds over ``ground`` (the rotors' vibration, in
    variance) times ``scale``: 0 gives the ground level, 1 ``flight`` itself."""

    def level(f: float, g: float) -> float:
        return math.sqrt(g**2 + scale**2 * max(f**2 - g**2, 0.0))

    return replace(
        flight,
        gyro_noise_density=level(flight.gyro_noise_density, ground.gyro_noise_density),
        accel_noise_density=level(flight.accel_noise_density, ground.accel_noise_density),
    )


def _ground_yaml(spec: SequenceSpec, imu: ImuSpec) -> dict[str, float] | None:
    ground = imu.ground_noise if spec.sensors == "realistic" else None
    return ground.sensor_yaml() if ground is not None else None


def _rigs_for(spec: SequenceSpec) -> tuple[Rig, Rig, ImuNoiseModel | None, dict[str, object]]:
    """The rig the data is made with, the rig the dataset states, the IMU's noise model and
    what was drawn (see :class:`DatasetPlan`)."""
    rig = resolve_rig(spec.rig)
    assert rig.imu is not None and spec.exposure_s is not None
    realistic = spec.sensors == "realistic"
    hidden = _drawn_time_offset_s(spec) if realistic else 0.0
    stated_td, true_td = s_to_ns(spec.time_offset_s), s_to_ns(spec.time_offset_s + hidden)
    stated = replace(
        rig,
        cameras=tuple(
            replace(c, exposure_s=min(spec.exposure_s, 1.0 / c.rate_hz), time_offset_ns=stated_td)
            for c in rig.cameras
        ),
        imu=replace(rig.imu, flight_noise=None),
    )
    imu_noise = _imu_noise(spec, rig.imu)
    true_cams = tuple(replace(c, time_offset_ns=true_td) for c in stated.cameras)
    true_imu = replace(rig.imu, flight_noise=None, noise=imu_noise or rig.imu.noise)
    true = replace(stated, cameras=true_cams, imu=true_imu)
    if realistic:
        stated = replace(stated, cameras=miscalibrated_cameras(spec, stated.cameras))
    drawn: dict[str, object] = {
        "profile": spec.sensors,
        "time_offset_s": {"true": true_td / NS_PER_S, "stated": stated_td / NS_PER_S},
        "imu_bias0": {
            "gyro_rad_s": list(imu_noise.gyro_bias0_rad_s) if imu_noise else [0.0] * 3,
            "accel_m_s2": list(imu_noise.accel_bias0_m_s2) if imu_noise else [0.0] * 3,
        },
        "imu_noise_density": {
            "synthesized": imu_noise.sensor_yaml() if imu_noise else None,
            "on_the_ground": _ground_yaml(spec, rig.imu) if imu_noise else None,
            "stated": rig.imu.noise.sensor_yaml(),
        },
        "calibration_error": {
            c.name: _calibration_error(c, s) for c, s in zip(true_cams, stated.cameras, strict=True)
        },
        "truth": "truth/ (quadnav vio DIR --calibration DIR/truth)",
    }
    return true, stated, imu_noise, drawn


#: A body moving faster than this (m/s, rad/s) is flying; its rotors run from a second before.
FLYING_SPEED_M_S, FLYING_RATE_RAD_S, ROTORS_AHEAD_S = 0.05, 0.05, 1.0


def flying(motion: SplineMotion, t_ns: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Whether the rotors run at ``t_ns``: within :data:`ROTORS_AHEAD_S` of the body moving."""
    from quadnav.sim.motion import CHUNK_ROWS

    moving = np.empty(len(t_ns), dtype=np.bool_)
    for a in range(0, len(t_ns), CHUNK_ROWS):  # a chunk at a time: bounded temporaries
        t = t_ns[a : a + CHUNK_ROWS]
        moving[a : a + CHUNK_ROWS] = (
            np.linalg.norm(motion.velocity(t), axis=1) > FLYING_SPEED_M_S
        ) | (np.linalg.norm(motion.angular_rate_B(t), axis=1) > FLYING_RATE_RAD_S)
    t_moving = t_ns[moving]
    if not t_moving.size:
        return np.zeros(len(t_ns), dtype=np.bool_)
    k = np.searchsorted(t_moving, t_ns)
    ahead = np.abs(t_moving[np.minimum(k, len(t_moving) - 1)] - t_ns)
    behind = np.abs(t_moving[np.maximum(k - 1, 0)] - t_ns)
    return np.asarray(np.minimum(ahead, behind) <= s_to_ns(ROTORS_AHEAD_S), dtype=np.bool_)


def synthesize_dataset_imu(plan: DatasetPlan, seed: int) -> ImuSeries:
    """The IMU ``make_dataset`` writes: :func:`~quadnav.sim.motion.synthesize_imu` with the
    plan's noise; with a ``ground_noise``, at that level, plus white noise up to the in-flight
    level where the rotors run (:func:`flying`; its own stream, ``imu_vibration``)."""
    imu_spec, noise, ground = plan.rig.imu, plan.imu_noise, plan.ground_noise
    assert imu_spec is not None
    base = noise
    if noise is not None and ground is not None:
        base = replace(
            noise,
            gyro_noise_density=ground.gyro_noise_density,
            accel_noise_density=ground.accel_noise_density,
        )
    imu = synthesize_imu(
        plan.motion, rate_hz=imu_spec.rate_hz, noise=base, rng=stream_rng(seed, "imu"),
        t_start_ns=plan.span[0], t_end_ns=plan.span[1],
    )  # fmt: skip
    if noise is None or ground is None:
        return imu
    on = flying(plan.motion, imu.t_true_ns)[:, None] * math.sqrt(imu_spec.rate_hz)
    extra = [
        math.sqrt(max(a**2 - b**2, 0.0))
        for a, b in (
            (noise.gyro_noise_density, ground.gyro_noise_density),
            (noise.accel_noise_density, ground.accel_noise_density),
        )
    ]
    rng = stream_rng(seed, "imu_vibration")
    for out, sigma in ((imu.gyro_rad_s, extra[0]), (imu.accel_m_s2, extra[1])):
        shake = rng.standard_normal(out.shape)
        shake *= sigma * on  # in place (the same numbers as with copies)
        out += shake
    return imu


def _write_imu(
    writer: EurocWriter, motion: SplineMotion, plan: DatasetPlan, spec: SequenceSpec
) -> int:
    """The IMU and the ground truth at its stamps (pose, velocity, the true biases)."""
    from quadnav.sim.motion import CHUNK_ROWS

    imu = synthesize_dataset_imu(plan, spec.seed)
    for s in imu.samples():
        writer.add_imu(s)
    for a in range(0, len(imu), CHUNK_ROWS):  # the truth's rows a chunk at a time
        t_chunk = imu.t_ns[a : a + CHUNK_ROWS]
        p, q = motion.pose(t_chunk)
        v = motion.velocity(t_chunk)
        for k, t in enumerate(t_chunk):
            writer.add_groundtruth(
                int(t), p[k], q[k], v[k], imu.gyro_bias_rad_s[a + k], imu.accel_bias_m_s2[a + k]
            )
    return len(imu)


def _depth_reading(
    depth_m: NDArray[np.float32], spec: DepthSpec, rng: Generator
) -> NDArray[np.float32]:
    """What the RGB-D sensor reads of the rendered depth: its noise, nothing out of its range."""
    return depth_noise(
        depth_m,
        rng,
        sigma0_m=spec.sigma0_m,
        sigma_per_m2=spec.sigma_per_m2,
        min_range_m=spec.min_range_m,
        max_range_m=spec.max_range_m,
    )


class _CameraStream:
    """One camera of the rig: its renderer, its noise generator, the scene depth it saw last
    (for the blur) and its auto-exposure gain, which follows the light with a lag."""

    def __init__(self, cam: CameraSpec, scene: Scene, spec: SequenceSpec) -> None:
        from quadnav.sim.render import Renderer

        self.cam = cam
        self.spec = spec
        self.renderer = Renderer(scene, cam.camera)
        self.rng = stream_rng(spec.seed, cam.name)
        self.depth_m = 2.0
        self.ae_gain: float | None = None

    def _exposure(self, scene_mean: float, light: float, dt_s: float) -> float:
        """The gain: ``light`` times the auto-exposure, which brings the mean grey level to
        ``target_grey`` with time constant ``auto_exposure_s`` (within 0.25-4x)."""
        s = self.spec
        if s.auto_exposure_s <= 0.0:
            return light
        want = float(np.clip(s.target_grey / max(scene_mean * light, 1.0), 0.25, 4.0))
        if self.ae_gain is None:
            self.ae_gain = want
        else:
            self.ae_gain += (want - self.ae_gain) * min(dt_s / s.auto_exposure_s, 1.0)
        return light * self.ae_gain

    def shoot(self, motion: SplineMotion, t_cam_ns: int, light: float) -> RenderedFrame:
        """The image as the camera gives it, and the depth at mid-exposure (noise-free)."""
        poses = _blur_poses(motion, self.cam, t_cam_ns + self.cam.time_offset_ns, self.depth_m)
        blur = poses if len(poses) > 1 else ()
        frame = self.renderer.render(poses[len(poses) // 2], blur_poses=blur)
        finite = frame.depth_m[np.isfinite(frame.depth_m)]
        self.depth_m = float(np.median(finite)) if finite.size else 10.0
        gain = self._exposure(float(frame.image.mean()), light, 1.0 / self.cam.rate_hz)
        effects = RenderEffects(
            exposure_gain=gain,
            read_noise_sigma=self.spec.read_noise,
            shot_noise_dn=self.spec.shot_noise_dn,
            vignetting=self.spec.vignetting,
        )
        return RenderedFrame(effects.apply(frame.image, self.rng), frame.depth_m)


def _frame_times(
    rig: Rig, spec: SequenceSpec, span: tuple[int, int]
) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
    """The cameras' stamps (their clock) in ``span`` of IMU time, the seconds from the first,
    and the lighting's gain at each."""
    td = rig.cameras[0].time_offset_ns
    stamps = _camera_times(span[0] + max(-td, 0), span[1] - max(td, 0), rig.cameras[0])
    t_s = (stamps - stamps[0]) / NS_PER_S
    light = _lighting_gain(t_s, spec.lighting or 0.0, stream_rng(spec.seed, "lighting"))
    return stamps, t_s, light


def _write_frames(
    writer: EurocWriter,
    motion: SplineMotion,
    rig: Rig,
    spec: SequenceSpec,
    scene: Scene,
    span: tuple[int, int],
    progress: Progress | None,
) -> int:
    """Every camera's images, rendered at its stamps (plus its time offset), blurred over its
    exposure, under the slow lighting changes and its auto exposure, with its own noise."""
    cameras = [_CameraStream(c, scene, spec) for c in rig.cameras]
    stamps, t_s, light = _frame_times(rig, spec, span)
    depth_rng = stream_rng(spec.seed, "depth0")
    written = 0
    for k, t_cam in enumerate(stamps):
        for cam in cameras:
            shot = cam.shoot(motion, int(t_cam), light[k])
            writer.add_frame(cam.cam.name, int(t_cam), shot.image)
            written += 1
            if rig.depth is not None and rig.depth.camera == cam.cam.name:
                writer.add_depth(int(t_cam), _depth_reading(shot.depth_m, rig.depth, depth_rng))
        if progress is not None and (k % 10 == 0 or k == len(stamps) - 1):
            progress(k + 1, len(stamps), f"{t_s[k]:.1f} s")
    return written


def make_dataset(
    spec: SequenceSpec,
    out: Path,
    *,
    name: str = "",
    progress: Progress | None = None,
    bag: bool = False,
) -> DatasetMade:
    """Render and synthesize ``spec`` into the EuRoC ASL folder ``out`` (see the module)."""
    from quadnav.io.datasets import EurocWriter

    start = time.perf_counter()
    spec = with_profile(spec)
    rig, motion, span = (plan := plan_dataset(spec)).rig, plan.motion, plan.span
    scene = _world(spec, motion, *span)
    with EurocWriter(out, plan.stated, truth=rig) as writer:
        n_imu = _write_imu(writer, motion, plan, spec)
        n_frames = _write_frames(writer, motion, rig, spec, scene, span, progress)
        root = writer.close()
    t = np.arange(span[0], span[1], s_to_ns(0.01), dtype=np.int64)
    p, q = motion.pose(t)
    write_tum(root / "groundtruth.tum", Trajectory(t_ns=t, p_W_B=p, q_W_B_xyzw=q, name=name))
    if bag:
        from quadnav.io.datasets import open_dataset, write_ros2_bag

        write_ros2_bag(open_dataset(root), root / "bag")
    dist, speed, rate = _motion_figures(p, q, 0.01)
    made = DatasetMade(
        root=root, sequence=name or spec.world, world=spec.world, rig=rig.name,
        duration_s=(span[1] - span[0]) / NS_PER_S, frames=n_frames, imu_samples=n_imu,
        distance_m=dist, mean_speed_m_s=speed, mean_rate_deg_s=rate,
        size_bytes=_folder_size(root), seconds=time.perf_counter() - start,
    )  # fmt: skip
    _write_manifest(root, spec, made.sequence, made, plan.sensors)
    return made


class _LiveCamera:
    """One camera's frames rendered when their pixels are read (:func:`rendered_dataset`)."""

    __slots__ = ("_light", "_motion", "_stamps", "_stream")

    def __init__(
        self,
        stream: _CameraStream,
        motion: SplineMotion,
        stamps: NDArray[np.int64],
        light: FloatArray,
    ) -> None:
        self._stream, self._motion, self._stamps, self._light = stream, motion, stamps, light

    def image(self, k: int) -> U8:
        return self._stream.shoot(self._motion, int(self._stamps[k]), float(self._light[k])).image


class _LiveFrame:
    """The loader of one rendered frame: its camera and index, ~50 bytes (a ``partial`` took
    ~150; a 30-minute sequence has 36,000 frames a camera)."""

    __slots__ = ("_camera", "_k")

    def __init__(self, camera: _LiveCamera, k: int) -> None:
        self._camera, self._k = camera, k

    def __call__(self) -> U8:
        return self._camera.image(self._k)


def _scaled_rig(rig: Rig, scale: float) -> Rig:
    """``rig`` with every camera's image ``scale`` times as wide and high (its intrinsics too)."""
    if scale == 1.0:
        return rig
    cams = tuple(
        replace(
            c, camera=c.camera.scaled(round(c.camera.width * scale), round(c.camera.height * scale))
        )
        for c in rig.cameras
    )
    return replace(rig, cameras=cams)


def rendered_dataset(
    spec: SequenceSpec, *, name: str = "", scale: float = 1.0
) -> VisualInertialDataset:
    """``spec`` as :func:`make_dataset` makes it, held in memory instead of written: the IMU as
    a table, the ground truth at 100 Hz (``groundtruth.tum``'s rate), and each frame rendered
    when its pixels are read, none kept (36,000 images for 30 minutes at 20 Hz would be
    ~13 GB). Read each camera's frames in time order, as a run does: its auto exposure and
    motion blur follow the frames before, as when the dataset is made. ``scale`` (0.25-1)
    shrinks the images (and the intrinsics) for a faster run."""
    from quadnav.io.datasets import GroundTruth, ImuTable, VisualInertialDataset
    from quadnav.messages import ImageFrame

    if not 0.25 <= scale <= 1.0:
        raise ConfigError(f"scale must be from 0.25 to 1, got {scale:g}")
    spec = with_profile(spec)
    plan = plan_dataset(spec)
    plan = replace(plan, rig=_scaled_rig(plan.rig, scale), stated=_scaled_rig(plan.stated, scale))
    motion = replace(plan.motion, poses=None)  # the poses it was fitted to: not needed to render
    scene = _world(spec, motion, *plan.span)
    imu = synthesize_dataset_imu(plan, spec.seed)
    stamps, _, light = _frame_times(plan.rig, spec, plan.span)
    live = [
        (c.name, _LiveCamera(_CameraStream(c, scene, spec), motion, stamps, light))
        for c in plan.rig.cameras
    ]
    origin = {cam: f"{cam} rendered" for cam, _ in live}  # one string, not one a frame
    frames = tuple(
        ImageFrame(t_ns=int(t), camera=cam, load=_LiveFrame(camera, k), origin=origin[cam])
        for k, t in enumerate(stamps)
        for cam, camera in live
    )
    t = np.arange(plan.span[0], plan.span[1], s_to_ns(0.01), dtype=np.int64)
    p, q = motion.pose(t)
    truth = Trajectory(t_ns=t, p_W_B=p, q_W_B_xyzw=q, name=name or spec.world)
    return VisualInertialDataset(
        name=name or spec.world, root=Path(name or spec.world), kind="rendered", rig=plan.stated,
        frames=frames, imu=ImuTable(imu.t_ns, imu.gyro_rad_s, imu.accel_m_s2),
        groundtruth=GroundTruth(truth, source="rendered"),
    )  # fmt: skip
