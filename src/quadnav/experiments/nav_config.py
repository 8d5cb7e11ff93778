"""The main job's scenario (``quadnav run``): :class:`NavScenario`, the YAML configuration of
a navigation flight. Every field has a default: the indoor flight of thesis 000 (take off to
1.5 m, hold, a 2 m square, hold, land, two 2 s vision dropouts). Each sensor section is read by
its channel's builder in :mod:`quadnav.experiments.nav_channels`; the loop is
:func:`quadnav.experiments.nav.run_nav`.
"""

from __future__ import annotations

from typing import Annotated, Literal, Self

from pydantic import Field, model_validator

from quadnav.config_model import (
    MAX_DELAY_S,
    MAX_DURATION_S,
    MAX_RATE_HZ,
    MAX_SIM_STEPS,
    MIN_SIGMA,
    ConfigModel,
)
from quadnav.control.trajectories import Waypoints
from quadnav.errors import GeometryError
from quadnav.geometry.navsat import GeoDatum
from quadnav.vio.config import VioConfig

__all__ = ["RANGE_MIN_M", "NavScenario", "VioSection"]

Vec3 = tuple[float, float, float]

#: The range finder's shortest reading (m).
RANGE_MIN_M = 0.05


class ImuSection(ConfigModel):
    rate_hz: float = Field(250.0, gt=0, le=MAX_RATE_HZ)
    gyro_sigma_rad_s: float = Field(0.005, ge=MIN_SIGMA, description="white noise per sample")
    accel_sigma_m_s2: float = Field(0.05, ge=MIN_SIGMA, description="white noise per sample")
    gyro_bias_rw_rad_s_sqrt_s: float = Field(1e-4, gt=0)
    accel_bias_rw_m_s2_sqrt_s: float = Field(1e-3, gt=0)
    gyro_bias0_sigma_rad_s: float = Field(0.01, ge=0, description="turn-on bias spread")
    accel_bias0_sigma_m_s2: float = Field(0.05, ge=0, description="turn-on bias spread")
    lever_arm_m: Vec3 = Field(
        (0.0, 0.0, 0.0), description="IMU mount offset from the centre of mass (body FLU)"
    )


class VisionSection(ConfigModel):
    enabled: bool = True
    source: Literal["camera", "pose"] = Field(
        "camera",
        description="camera: rendered images of a marker field, detected and posed (thesis 000); "
        "pose: the true pose plus noise (the fast shortcut)",
    )
    marker_grid: int = Field(6, ge=1, le=15, description="camera: n x n markers on the floor")
    marker_spacing_m: float = Field(0.6, gt=0, description="camera: distance between markers")
    marker_length_m: float = Field(0.2335, gt=0, description="camera: printed marker side")
    marker_origin_m: tuple[float, float] = Field((-0.6, -0.6), description="camera: first marker")
    image_noise: float = Field(2.0, ge=0, description="camera: grey-level noise of the images")
    min_sigma_m: float = Field(
        0.002, ge=0, description="camera: noise added to the pose's covariance (exposure, timing)"
    )
    rate_hz: float = Field(30.0, gt=0, le=MAX_RATE_HZ)
    delay_s: float = Field(0.25, ge=0, le=MAX_DELAY_S)
    sigma_m: float = Field(0.01, ge=MIN_SIGMA)
    yaw_sigma_rad: float = Field(0.01, ge=MIN_SIGMA)
    dropouts_s: list[tuple[float, float]] = Field(
        default_factory=lambda: [(9.0, 11.0), (15.0, 17.0)],
        description="[start, end) windows with no vision",
    )
    frame_yaw_deg: float = Field(0.0, description="yaw of the vision frame in the world")
    frame_offset_m: Vec3 = Field((0.0, 0.0, 0.0), description="vision frame origin in the world")
    jumps: list[tuple[float, float, float, float, float]] = Field(
        default_factory=list,
        description="[t_s, yaw_deg, dx_m, dy_m, dz_m]: the vision frame re-initialises (reset counter + 1)",
    )


OdometryPart = Literal["pos", "vel", "yaw"]
_ODOMETRY_PARTS: tuple[OdometryPart, ...] = ("pos", "vel", "yaw")


#: The ``vio`` keys only the odometry shortcut (``vio.source=odometry``) reads.
SHORTCUT_ONLY_VIO_KEYS = (
    "rate_hz", "sigma_m", "sigma_vel_m_s", "yaw_sigma_rad", "drift_m_sqrt_s",
    "drift_yaw_rad_sqrt_s", "scale_error", "resets_s",
)  # fmt: skip
#: The ``vio`` keys only an odometry on rendered images (``vio.source=camera``) reads, beside
#: the VIO's own settings.
CAMERA_ONLY_VIO_KEYS = ("odometry", "camera_rate_hz", "sensors", "loop", "load_map", "save_map")
#: The ``vio`` keys only the VIO reads (``vio.odometry=vio``), beside its own settings: the SLAM
#: closes its own loops.
VIO_ONLY_VIO_KEYS = ("loop", "load_map", "save_map")
#: The rigs with two cameras, the stereo SLAM's (``vio.odometry=slam``).
STEREO_RIGS = ("euroc", "zed")
#: The ``vio`` keys only ``vio.odometry_mode=relative`` reads.
RELATIVE_ONLY_VIO_KEYS = (
    "frame_drift_m_sqrt_s", "frame_drift_yaw_rad_sqrt_s", "frame_scale_sigma",
    "frame_scale_rw_sqrt_s", "frame_drift_from_covariance",
)  # fmt: skip


class VioSection(VioConfig):
    """Visual-inertial odometry as an external-odometry source (PX4's ODOMETRY): the rig's
    camera rendered in a 3-D world and its IMU, fed to the VIO, whose estimate (converted to
    the vehicle's body) the EKF fuses; or the shortcut of the true pose and velocity plus noise
    and a slow drift.

    The section holds the VIO's own settings too, :class:`~quadnav.vio.config.VioConfig`'s
    fields under their names (``vio.keyframe_parallax_px``, ``vio.tracker.max_features``),
    validated as there and given to the estimator with ``source=camera``
    (:meth:`estimator_config`). A scenario that runs no VIO refuses them (see
    :meth:`NavScenario.unused_vio_key`)."""

    enabled: bool = False
    source: Literal["camera", "odometry"] = Field(
        "camera",
        description="camera: rendered images and the rig's IMU into the odometry; odometry: the "
        "true pose and velocity plus noise and drift (the fast shortcut, no images)",
    )
    odometry: Literal["vio", "slam"] = Field(
        "vio",
        description="camera: the odometry on the rendered images: vio, the monocular VIO (its "
        "settings below); slam, the stereo SLAM (quadnav.slam, its default settings; a stereo "
        "vio.rig; no IMU; its pose covariance a stated 1 cm and 0.5 degree)",
    )
    rig: Literal["thesis003_sim", "euroc_mono", "euroc", "zed"] = Field(
        "thesis003_sim",
        description="camera: the camera-IMU rig (its cameras, IMU and mount); the odometry "
        "gets the cameras it uses",
    )
    camera_rate_hz: float | None = Field(
        None,
        gt=0,
        le=MAX_RATE_HZ,
        description="camera: frames per second into the odometry, at most the rig camera's "
        "(None: the camera's rate)",
    )
    world: Literal["hall", "room", "yard"] = Field("hall", description="camera: the 3-D world")
    world_seed: int = Field(0, ge=0, description="camera: the world's layout and textures")
    image_noise: float = Field(2.0, ge=0, description="camera: grey-level read noise")
    sensors: Literal["ideal", "realistic"] = Field(
        "ideal",
        description="camera: ideal (the IMU at the rig's stated noise, small turn-on biases, "
        "the odometry given the true calibration) or realistic (quadnav dataset make's profile: "
        "the IMU at its in-flight level with turn-on biases from the rig's spread, the "
        "odometry given a calibration off as a real one is)",
    )
    delay_s: float = Field(
        0.05, ge=0, le=MAX_DELAY_S, description="processing latency of the odometry"
    )
    rate_hz: float = Field(20.0, gt=0, le=MAX_RATE_HZ, description="odometry: its rate")
    sigma_m: float = Field(0.02, ge=MIN_SIGMA, description="odometry: position noise")
    sigma_vel_m_s: float = Field(0.02, ge=MIN_SIGMA, description="odometry: velocity noise")
    yaw_sigma_rad: float = Field(0.01, ge=MIN_SIGMA, description="odometry: attitude noise")
    drift_m_sqrt_s: float = Field(
        0.005, ge=0, description="odometry: random-walk drift of the frame's origin"
    )
    drift_yaw_rad_sqrt_s: float = Field(
        0.0, ge=0, le=1.0, description="odometry: random-walk drift of the frame's yaw"
    )
    scale_error: float = Field(
        0.0, gt=-0.5, lt=0.5, description="odometry: its motion scaled by 1 + this (mono VIO)"
    )
    resets_s: list[Annotated[float, Field(ge=0, le=MAX_DURATION_S)]] = Field(
        default_factory=list,
        description="odometry: times (s) it re-initialises: position from zero, a random yaw, "
        "the reset counter up",
    )
    pos_noise_m: float = Field(
        0.05, ge=MIN_SIGMA, description="EKF: floor of the position sigma (EKF2_EVP_NOISE)"
    )
    vel_noise_m_s: float = Field(
        0.05, ge=MIN_SIGMA, description="EKF: floor of the velocity sigma (EKF2_EVV_NOISE)"
    )
    yaw_noise_rad: float = Field(
        0.02, ge=MIN_SIGMA, description="EKF: floor of the yaw sigma (EKF2_EVA_NOISE)"
    )
    gate_sigma: float = Field(5.0, gt=0, description="EKF: innovation gate (EKF2_EVP_GATE)")
    fuse: list[OdometryPart] = Field(
        default_factory=lambda: list(_ODOMETRY_PARTS),
        min_length=1,
        description="EKF: what is fused (EKF2_EV_CTRL)",
    )
    odometry_mode: Literal["absolute", "relative"] = Field(
        "relative",
        description="EKF: absolute: the odometry's position and yaw as fixes of the navigation "
        "frame (PX4); relative: its frame's drift (position and yaw) estimated beside the state "
        "as a random walk, so its motion is taken and its drift is not averaged as noise",
    )
    # indoor_vio's VIO alone is 0.03-0.09 m RMS off the truth over its 37 s flight (5 seeds,
    # 2026-12-05 session 31): a random walk of 5-7 mm/sqrt(s) per axis gives that. At the
    # old 0.02 m and 0.004 rad (fitted to a VIO four times worse, 2026-12-02) the filter took
    # the VIO's corrections of its own position for its frame drifting and followed its
    # integrated velocity instead: output 0.067 m against the VIO's own 0.052 m (mean of 5);
    # at these, 0.055 m against 0.050 m, NEES median 10.6 for 15 states. The outdoor
    # scenarios' shortcut drifts at the old rates and keeps them.
    frame_drift_m_sqrt_s: float = Field(
        0.005, ge=MIN_SIGMA, description="EKF, relative: random walk of the odometry frame's origin"
    )
    frame_drift_yaw_rad_sqrt_s: float = Field(
        0.001, ge=MIN_SIGMA, description="EKF, relative: random walk of the odometry frame's yaw"
    )
    frame_scale_sigma: float = Field(
        0.0,
        ge=0,
        le=1,
        description="EKF, relative: the odometry's scale error as a state, its sigma where the "
        "frame is anchored (a monocular VIO's scale: a few per cent; 0: not estimated)",
    )
    frame_scale_rw_sqrt_s: float = Field(
        0.0, ge=0, le=1, description="EKF, relative: random walk of the odometry's scale error"
    )
    frame_drift_from_covariance: bool = Field(
        False,
        description="EKF, relative: the frame's drift also grows as the odometry's own "
        "covariance does (a VIO's grows with its drift), and its noise is its floors alone",
    )

    loop: bool = Field(
        False,
        description="camera: loop closure around the VIO (place recognition, a 4-DoF pose "
        "graph, relocalization); the EKF follows its corrections as PX4's EKF2 does (reset to "
        "the odometry when its reset counter changes)",
    )
    load_map: str | None = Field(
        None,
        description="camera: a map saved by quadnav vio --save-map or by a run with "
        "vio.save_map=true, in the same world (turns loop closure on): the flight localises in "
        "it from its first recognised place",
    )
    save_map: bool = Field(
        False,
        description="camera, with loop closure: save each seed's map in the run folder "
        "(maps/seed_<seed>), for a later flight's vio.load_map",
    )

    @property
    def loop_closure(self) -> bool:
        """Whether the VIO runs with loop closure (``loop``, or a map to load)."""
        return self.loop or self.load_map is not None

    @property
    def corrects_in_place(self) -> bool:
        """Whether the odometry's reset counter marks a correction of itself in the same world
        (loop closure's around the VIO, the SLAM's closed loops; a relocalization keeps the
        SLAM's world and its counter) rather than a new start: the EKF then follows it."""
        return self.source == "camera" and (self.loop_closure or self.odometry == "slam")

    def estimator_config(self) -> VioConfig:
        """The VIO's own settings, as the estimator takes them."""
        return VioConfig.model_validate(self.model_dump(include=set(VioConfig.model_fields)))


def _slam_problem(v: VioSection, changed: list[str]) -> str | None:
    """``vio.odometry=slam``: a stereo rig, and none of the VIO's settings (the SLAM runs on
    its own defaults and closes its own loops)."""
    if v.rig not in STEREO_RIGS:
        return (
            f"vio.odometry=slam needs a stereo rig, and vio.rig {v.rig} has one camera: set "
            f"vio.rig to one of {', '.join(STEREO_RIGS)}"
        )
    own = [k for k in changed if k in VioConfig.model_fields or k in VIO_ONLY_VIO_KEYS]
    if own:
        return (
            f"vio.{own[0]} is a setting of the VIO, which vio.odometry=slam does not run (the "
            "SLAM closes its own loops): set vio.odometry=vio or leave it out"
        )
    return None


class BaroSection(ConfigModel):
    enabled: bool = True
    rate_hz: float = Field(50.0, gt=0, le=MAX_RATE_HZ)
    delay_s: float = Field(0.02, ge=0, le=MAX_DELAY_S)
    sigma_m: float = Field(0.1, ge=MIN_SIGMA)
    drift_m_sqrt_s: float = Field(0.002, ge=0, description="random-walk drift of the offset")


class RangeSection(ConfigModel):
    enabled: bool = False
    rate_hz: float = Field(20.0, gt=0, le=MAX_RATE_HZ)
    delay_s: float = Field(0.01, ge=0, le=MAX_DELAY_S)
    sigma_m: float = Field(0.02, ge=MIN_SIGMA)
    max_m: float = Field(8.0, gt=RANGE_MIN_M, description=f"above the {RANGE_MIN_M} m it sees")


class FlowSection(ConfigModel):
    """A downward optical-flow sensor (PX4FLOW class: integrated flow and gyro, a range)."""

    enabled: bool = False
    rate_hz: float = Field(50.0, gt=0, le=MAX_RATE_HZ)
    delay_s: float = Field(0.015, ge=0, le=MAX_DELAY_S, description="thesis 000 fig 2.1c: 15 ms")
    flow_sigma_rad_s: float = Field(0.05, ge=MIN_SIGMA, description="flow-rate noise")
    gyro_sigma_rad_s: float = Field(0.005, ge=0, description="its own gyro's noise")
    min_height_m: float = Field(0.3, gt=0, description="no flow closer to the floor")
    max_height_m: float = Field(5.0, gt=0, description="quality 0 beyond")


class FaultsSection(ConfigModel):
    """Faults injected into the sensor streams (times in seconds of flight time)."""

    gps_glitch: list[tuple[float, float, float, float]] = Field(
        default_factory=list, description="[start_s, end_s, east_m, north_m]: fixes jump by this"
    )
    imu_nan_s: list[float] = Field(
        default_factory=list, description="an IMU sample carrying NaN at these times"
    )
    imu_repeat_s: list[float] = Field(
        default_factory=list, description="an IMU sample delivered twice (the copy is out of order)"
    )
    vision_late_s: list[tuple[float, float]] = Field(
        default_factory=list,
        description="[t_s, extra_delay_s]: the vision sample of t_s arrives this much later",
    )


class GpsSection(ConfigModel):
    enabled: bool = False
    rate_hz: float = Field(5.0, gt=0, le=MAX_RATE_HZ)
    delay_s: float = Field(0.2, ge=0, le=MAX_DELAY_S)
    sigma_h_m: float = Field(0.5, ge=MIN_SIGMA)
    sigma_v_m: float = Field(0.8, ge=MIN_SIGMA)
    sigma_vel_m_s: float = Field(0.1, ge=MIN_SIGMA)
    datum_lla: tuple[float, float, float] = Field(
        (47.397742, 8.545594, 488.0), description="lat deg, lon deg, alt m"
    )

    @model_validator(mode="after")
    def _datum(self) -> Self:
        try:
            GeoDatum(*self.datum_lla)
        except GeometryError as exc:  # (it names the coordinate: name its element too)
            parts = ("latitude", "longitude", "altitude")
            k = next((i for i, n in enumerate(parts) if n in str(exc)), 0)
            raise ValueError(f"datum_lla[{k}] ({parts[k]}): {exc}") from None
        return self

    outages_s: list[tuple[float, float]] = Field(
        default_factory=list, description="[start, end) without a fix"
    )


class MagSection(ConfigModel):
    enabled: bool = False
    rate_hz: float = Field(50.0, gt=0, le=MAX_RATE_HZ)
    declination_rad: float = 0.05
    noise_sigma: float = Field(0.005, ge=0, description="per axis, in the field's unit (gauss)")
    sigma_heading_rad: float = Field(
        0.023, ge=MIN_SIGMA, description="heading noise the filter assumes"
    )


class PlanSection(ConfigModel):
    kind: Literal["square", "takeoff_forward"] = Field(
        "square",
        description="square: take off, hold, a square, hold, land (cascaded PID on a "
        "trajectory); takeoff_forward: thesis 003's take-off P controller to height_m, then "
        "forward_m ahead, then hover (10 Hz velocity commands)",
    )
    forward_m: float = Field(5.0, gt=0, description="takeoff_forward: distance ahead")
    takeoff_s: float = Field(
        3.0, ge=0, le=MAX_DURATION_S, description="takeoff_forward: on the ground after alignment"
    )
    duration_s: float = Field(
        40.0, gt=0, le=MAX_DURATION_S, description="takeoff_forward: flight after take-off"
    )
    height_m: float = Field(1.5, gt=0)
    square_m: float = Field(2.0, gt=0)
    laps: int = Field(
        1, ge=1, le=50, description="square: times round the square before the hold and landing"
    )
    speed_m_s: float = Field(1.0, gt=0)
    accel_m_s2: float = Field(1.0, gt=0)
    hold_s: float = Field(2.0, ge=0, le=MAX_DURATION_S)
    yaw: Literal["fixed", "along_track"] = Field(
        "fixed", description="fixed: face +x throughout; along_track: face the direction of travel"
    )
    yaw_rate_deg_s: float = Field(45.0, gt=0, description="turn rate of the along-track heading")


class EstimatorSection(ConfigModel):
    kind: Literal["ekf", "truth"] = Field(
        "ekf",
        description="ekf: the navigation EKF behind its delayed horizon; truth: perfect knowledge "
        "(the estimator's share of every error, by difference)",
    )
    init_tilt_sigma_rad: float = Field(0.02, ge=MIN_SIGMA, description="P0: roll and pitch")
    init_vel_sigma_m_s: float = Field(0.05, ge=MIN_SIGMA, description="P0: velocity")
    init_gyro_bias_sigma_rad_s: float | None = Field(
        None, ge=MIN_SIGMA, description="P0: gyro bias (None: imu.gyro_bias0_sigma_rad_s)"
    )
    init_accel_bias_sigma_m_s2: float | None = Field(
        None, ge=MIN_SIGMA, description="P0: accelerometer bias (None: imu.accel_bias0_sigma_m_s2)"
    )
    init_source_sigma_factor: float = Field(
        3.0, gt=0, description="P0 of heading and position levelled from a pose: its sigmas x this"
    )
    init_gps_sigma_factor: float = Field(
        2.0, gt=0, description="P0 of a position levelled from a GNSS fix: its sigma_h x this"
    )
    init_yaw_sigma_mag_rad: float = Field(
        0.1, ge=MIN_SIGMA, description="P0: heading from the magnetometer"
    )
    init_yaw_sigma_unknown_rad: float = Field(
        1.0, ge=MIN_SIGMA, description="P0: heading unobserved"
    )
    init_pos_sigma_unknown_m: float = Field(
        0.1, ge=MIN_SIGMA, description="P0: position unobserved"
    )
    start_pose: tuple[float, float, float, float] | None = Field(
        None,
        description="a surveyed start: x, y, z (m, the navigation frame) and heading (deg, "
        "counter-clockwise from +x) of the vehicle while it aligns, known to start_pos_sigma_m "
        "and start_yaw_sigma_deg; None: levelled from the sensors (GNSS, a pose, the origin)",
    )
    start_pos_sigma_m: float = Field(0.05, ge=MIN_SIGMA, description="P0: a surveyed start's")
    start_yaw_sigma_deg: float = Field(
        1.0, ge=MIN_SIGMA, le=180.0, description="P0: a surveyed start's heading"
    )
    gyro_bias_at_rest: bool = Field(
        False, description="start the gyro bias at the mean gyro reading on the ground (at rest)"
    )
    tau_vel_s: float = Field(0.1, gt=0)
    tau_pos_s: float = Field(0.1, gt=0)
    gate_probability: float = Field(0.9999, gt=0, lt=1)
    align_s: float = Field(
        0.5, gt=0, le=MAX_DURATION_S, description="time on the ground to level the filter"
    )
    imu_noise_inflation: float = Field(1.0, ge=1.0, description="filter's IMU noise / the sensor's")
    vision_frame: Literal["world", "rotate"] = Field(
        "world",
        description="world: the vision frame is the navigation frame (its yaw fused); rotate: "
        "PX4's rotated external vision, heading from the magnetometer (thesis 000 eqs 3.7-3.8)",
    )
    reset_after_s: float = Field(
        2.0, gt=0, le=MAX_DURATION_S, description="a source rejected this long resets"
    )
    zero_velocity_on_ground: bool = Field(
        True,
        description="fuse zero velocity while the motors are off on the ground (as PX4 at rest)",
    )
    bias_rw_inflation: float = Field(
        3.0,
        ge=1.0,
        description="filter's bias random walk / the sensor's (covers unmodelled IMU effects)",
    )


class NavScenario(ConfigModel):
    """A navigation flight; the defaults are the indoor vision flight of thesis 000."""

    name: str = "indoor_vision"
    closed_loop: bool = Field(True, description="fly on the output predictor (False: on the truth)")
    sim_dt_s: float = Field(0.002, gt=0, le=0.01)
    seed: int = Field(0, ge=0)
    seeds: int = Field(1, ge=1, le=1000)
    imu: ImuSection = ImuSection()
    vision: VisionSection = VisionSection()
    vio: VioSection = VioSection()
    baro: BaroSection = BaroSection()
    gps: GpsSection = GpsSection()
    mag: MagSection = MagSection()
    range: RangeSection = RangeSection()
    flow: FlowSection = FlowSection()
    faults: FaultsSection = FaultsSection()
    plan: PlanSection = PlanSection()
    estimator: EstimatorSection = EstimatorSection()

    @model_validator(mode="after")
    def _check(self) -> Self:
        if self.imu.rate_hz > 1.0 / self.sim_dt_s:
            raise ValueError(
                f"imu.rate_hz ({self.imu.rate_hz:g} Hz) is faster than the simulation step "
                f"(sim_dt_s = {self.sim_dt_s:g} s: at most {1.0 / self.sim_dt_s:g} Hz)"
            )
        if not (self.vision.enabled or self.gps.enabled or self.flow.enabled or self.vio.enabled):
            raise ValueError(
                "vision, vio, gps and flow are all disabled: nothing bounds the horizontal "
                "position or velocity"
            )
        frame_moved = self.vision.frame_yaw_deg != 0 or any(self.vision.frame_offset_m)
        if self.estimator.vision_frame == "world" and frame_moved:
            raise ValueError(
                "vision.frame_yaw_deg/frame_offset_m need estimator.vision_frame=rotate: with "
                "vision_frame=world the vision frame is the navigation frame"
            )
        if self.vision.source == "camera" and (self.vision.jumps or frame_moved):
            raise ValueError(
                "vision.jumps/frame_yaw_deg/frame_offset_m describe the pose shortcut: "
                "set vision.source=pose"
            )
        if (
            self.estimator.vision_frame == "rotate"
            and self.vio.enabled
            and self.vio.odometry_mode == "relative"
        ):
            raise ValueError(
                "vio.odometry_mode=relative estimates the odometry frame's yaw drift and needs "
                "estimator.vision_frame=world: set it, or vio.odometry_mode=absolute"
            )
        if self.estimator.vision_frame == "rotate" and not self.mag.enabled:
            raise ValueError(
                "estimator.vision_frame=rotate takes the heading from the magnetometer: "
                "set mag.enabled=true"
            )
        for a, b in self.vision.dropouts_s:
            if not b > a:
                raise ValueError(
                    f"vision.dropouts_s: a window must end after it starts, got ({a}, {b})"
                )
        if self.flight_s > MAX_DURATION_S:
            raise ValueError(
                f"the flight would last {self.flight_s:.4g} s, longer than {MAX_DURATION_S:g} s: "
                "shorten plan.hold_s or plan.square_m, or raise plan.speed_m_s"
            )
        if problem := self._timing_problem():
            raise ValueError(problem)
        if unused := self.unused_vio_key():
            raise ValueError(unused)
        return self

    def unused_vio_key(self) -> str | None:
        """A ``vio`` setting changed from its default that nothing would read: any of the
        section's without ``vio.enabled``; the VIO's own (``VioConfig``'s) with
        ``vio.source=odometry``, which runs no VIO. Refused rather than silently ignored."""
        v, default = self.vio, VioSection()
        changed = [k for k in VioSection.model_fields if getattr(v, k) != getattr(default, k)]
        if not v.enabled and changed:
            return (
                f"vio.{changed[0]} is set, but this scenario runs no VIO (vio.enabled=false): "
                "set vio.enabled=true or leave the vio section out"
            )
        own = [k for k in changed if k in VioConfig.model_fields or k in CAMERA_ONLY_VIO_KEYS]
        if v.source == "odometry" and own:
            return (
                f"vio.{own[0]} is a setting of the VIO, which vio.source=odometry does not run "
                "(the shortcut): set vio.source=camera or leave it out"
            )
        if v.source == "camera" and v.odometry == "slam" and (slam := _slam_problem(v, changed)):
            return slam
        if v.save_map and not v.loop_closure:
            return "vio.save_map saves loop closure's map: set vio.loop=true too"
        if v.final_smoothing and v.load_map is not None:
            return (
                "vio.final_smoothing: not with vio.load_map (the flight reports in the map's "
                "frame, which the smoothing does not hold); it refines a map vio.save_map saves"
            )
        drift = [k for k in changed if k in RELATIVE_ONLY_VIO_KEYS]
        if v.odometry_mode == "absolute" and drift:
            return (
                f"vio.{drift[0]} is a setting of vio.odometry_mode=relative, which "
                "vio.odometry_mode=absolute does not use: set vio.odometry_mode=relative or "
                f"leave it at its default ({getattr(default, drift[0])})"
            )
        shortcut = [k for k in changed if k in SHORTCUT_ONLY_VIO_KEYS]
        if v.source == "camera" and shortcut:
            return (
                f"vio.{shortcut[0]} is a setting of the odometry shortcut, which "
                "vio.source=camera does not use (the VIO on rendered images): set "
                "vio.source=odometry or leave it out"
            )
        return None

    def _timing_problem(self) -> str | None:
        """A step count too large for memory, or a sensor too slow to give a sample."""
        steps = self.flight_s / self.sim_dt_s
        if steps > MAX_SIM_STEPS:
            return (
                f"sim_dt_s ({self.sim_dt_s:g} s) would take {steps:.3g} steps for the "
                f"{self.flight_s:.4g} s flight, more than {MAX_SIM_STEPS:g}: raise sim_dt_s"
            )
        if self.imu.rate_hz * self.estimator.align_s < 1.0:
            return (
                f"imu.rate_hz ({self.imu.rate_hz:g} Hz) gives no IMU sample during "
                f"estimator.align_s ({self.estimator.align_s:g} s), which levels the filter"
            )
        rates = [
            (key, sec.enabled, sec.rate_hz)
            for key, sec in (
                ("vision", self.vision),
                ("vio", self.vio),
                ("baro", self.baro),
                ("gps", self.gps),
                ("mag", self.mag),
                ("range", self.range),
                ("flow", self.flow),
            )
        ]
        for key, enabled, rate_hz in rates:
            if enabled and rate_hz * self.flight_s < 1.0:
                return (
                    f"{key}.rate_hz ({rate_hz:g} Hz) gives no sample during the "
                    f"{self.flight_s:.4g} s flight"
                )
        return None

    def waypoints(self) -> Waypoints:
        h, s = self.plan.height_m, self.plan.square_m
        lap: list[Vec3] = [(s, 0, h), (s, s, h), (0, s, h), (0, 0, h)]
        pts: list[Vec3] = [(0, 0, 0), (0, 0, h), *(lap * self.plan.laps), (0, 0, 0)]
        return Waypoints(
            points_m=pts,
            speed_m_s=self.plan.speed_m_s,
            accel_m_s2=self.plan.accel_m_s2,
            hold_s=self.plan.hold_s,
        )

    @property
    def flight_s(self) -> float:
        if self.plan.kind == "takeoff_forward":
            return self.estimator.align_s + self.plan.takeoff_s + self.plan.duration_s
        return self.estimator.align_s + self.waypoints().duration_s + 1.0
