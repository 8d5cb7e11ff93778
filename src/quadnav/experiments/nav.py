"""The main job's flight: the rigid body flown by the cascaded PID on the navigation EKF's
output predictor (or on the truth), with a delayed external pose (vision), a barometer and a
biased IMU, ground alignment before take-off, and vision dropouts.

:class:`NavScenario` is the YAML scenario (every field has a default: the indoor flight of
thesis 000 — take off to 1.5 m, hold, a 2 m square, hold, land, two 2 s vision dropouts).
:func:`run_nav` returns arrays; files and plots belong to ``io`` and ``eval``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal, Self

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, model_validator
from scipy.spatial.transform import Rotation

from quadnav.config_model import (
    MAX_DELAY_S,
    MAX_DURATION_S,
    MAX_RATE_HZ,
    MAX_SIM_STEPS,
    MIN_SIGMA,
    ConfigModel,
)
from quadnav.control.base import Setpoint, truth_estimate
from quadnav.control.cascaded_pid import CascadedPid
from quadnav.control.trajectories import Waypoints
from quadnav.errors import ExperimentError, SimError
from quadnav.estimation.horizon import DelayedHorizonEstimator, HorizonConfig
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.experiments.marker_camera import MarkerCameraSensor, marker_field, thesis_mount
from quadnav.geometry.rotations import quat_xyzw_from_matrix, rotation_matrix_xyzw, so3_log
from quadnav.messages import (
    GpsSample,
    HeightSample,
    ImuSample,
    MagSample,
    PoseSample,
    RangeSample,
    Sample,
    VelocitySample,
)
from quadnav.sim.rigid_body import RigidBodyQuadrotor
from quadnav.sim.sensors import (
    BaroSensor,
    DelayLine,
    GpsSensor,
    IntegratingImu,
    MagSensor,
    RangeFinder,
    VisionFrameJump,
    VisionPoseSensor,
)
from quadnav.vehicle import RigidBodyParams

__all__ = ["NavRunResult", "NavScenario", "ground_alignment", "run_nav"]

FloatArray = NDArray[np.float64]
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
        lat, lon, alt = self.datum_lla
        if not -90.0 <= lat <= 90.0:
            raise ValueError(f"datum_lla[0] (latitude) must be within +-90 degrees, got {lat:g}")
        if not -180.0 <= lon <= 180.0:
            raise ValueError(f"datum_lla[1] (longitude) must be within +-180 degrees, got {lon:g}")
        if not -1000.0 <= alt <= 100_000.0:
            raise ValueError(f"datum_lla[2] (altitude) must be within -1000..100000 m, got {alt:g}")
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
    height_m: float = Field(1.5, gt=0)
    square_m: float = Field(2.0, gt=0)
    speed_m_s: float = Field(1.0, gt=0)
    accel_m_s2: float = Field(1.0, gt=0)
    hold_s: float = Field(2.0, ge=0, le=MAX_DURATION_S)
    yaw: Literal["fixed", "along_track"] = Field(
        "fixed", description="fixed: face +x throughout; along_track: face the direction of travel"
    )
    yaw_rate_deg_s: float = Field(45.0, gt=0, description="turn rate of the along-track heading")


class EstimatorSection(ConfigModel):
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
    baro: BaroSection = BaroSection()
    gps: GpsSection = GpsSection()
    mag: MagSection = MagSection()
    range: RangeSection = RangeSection()
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
        if not (self.vision.enabled or self.gps.enabled):
            raise ValueError(
                "vision and gps are both disabled: nothing bounds the horizontal position"
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
        return self

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
        rates = [(key, sec.enabled, sec.rate_hz) for key, sec in (("vision", self.vision), ("baro", self.baro), ("gps", self.gps), ("mag", self.mag), ("range", self.range))]  # fmt: skip
        for key, enabled, rate_hz in rates:
            if enabled and rate_hz * self.flight_s < 1.0:
                return (
                    f"{key}.rate_hz ({rate_hz:g} Hz) gives no sample during the "
                    f"{self.flight_s:.4g} s flight"
                )
        return None

    def waypoints(self) -> Waypoints:
        h, s = self.plan.height_m, self.plan.square_m
        pts: list[Vec3] = [
            (0, 0, 0),
            (0, 0, h),
            (s, 0, h),
            (s, s, h),
            (0, s, h),
            (0, 0, h),
            (0, 0, 0),
        ]
        return Waypoints(
            points_m=pts,
            speed_m_s=self.plan.speed_m_s,
            accel_m_s2=self.plan.accel_m_s2,
            hold_s=self.plan.hold_s,
        )

    @property
    def flight_s(self) -> float:
        return self.estimator.align_s + self.waypoints().duration_s + 1.0


@dataclass(frozen=True, slots=True, kw_only=True)
class NavRunResult:
    """Per IMU step after alignment (current horizon ``t_ns``), plus fusion records."""

    scenario: NavScenario
    seed: int
    t_ns: NDArray[np.int64]
    truth_p: FloatArray
    truth_v: FloatArray
    truth_q: FloatArray
    ref_p: FloatArray
    output_p: FloatArray
    output_v: FloatArray
    output_q: FloatArray
    t_delayed_ns: NDArray[np.int64]
    delayed_x: FloatArray  # p (3), v (3), q (4), bg (3), ba (3)
    delayed_err: FloatArray  # (N, 15) true minus estimate (attitude as a body rotation vector)
    delayed_P: FloatArray
    vision_t_ns: NDArray[np.int64]
    fusion: dict[str, dict[str, NDArray[np.float64]]]
    counts: dict[str, dict[str, int]]
    t_align_ns: int
    events: list[tuple[int, str]] | None = None  # the filter's own log (re-anchors, resets)
    stream: list[Sample] | None = (
        None  # every sample the estimator got, in arrival order, if recorded
    )


def heading_reference(
    v: FloatArray, dt_s: float, mode: str, max_rate_rad_s: float, min_speed_m_s: float = 0.2
) -> FloatArray:
    """Yaw setpoints per step: 0, or the direction of horizontal travel (held while slow),
    turned towards at no more than ``max_rate_rad_s``."""
    n = len(v)
    out = np.zeros(n)
    if mode == "fixed":
        return out
    target, yaw, step = 0.0, 0.0, max_rate_rad_s * dt_s
    for k in range(n):
        if math.hypot(v[k, 0], v[k, 1]) > min_speed_m_s:
            target = math.atan2(v[k, 1], v[k, 0])
        yaw += min(max(math.remainder(target - yaw, 2 * math.pi), -step), step)
        out[k] = yaw
    return out


def _stack_padded(rows: list[FloatArray]) -> FloatArray:
    """Innovations of one source as rows (a source's size may vary: padded with NaN)."""
    width = max((len(r) for r in rows), default=0)
    out = np.full((len(rows), width), np.nan)
    for k, r in enumerate(rows):
        out[k, : len(r)] = r
    return out


def ground_alignment(
    imu: list[ImuSample],
    pose: PoseSample | None,
    *,
    mag: list[MagSample] | None = None,
    declination_rad: float = 0.0,
    gps_enu_m: FloatArray | None = None,
) -> tuple[Rotation, FloatArray]:
    """Initial attitude and position on the ground: roll and pitch from the mean specific
    force (gravity); heading from the external pose, else from the magnetometer; position from
    the external pose, else from a GNSS fix (already in ENU), else the origin."""
    if not imu:
        raise ExperimentError("alignment needs IMU samples on the ground")
    f = np.mean([s.accel_m_s2 for s in imu], axis=0)
    roll = math.atan2(f[1], f[2])
    pitch = math.atan2(-f[0], math.hypot(f[1], f[2]))
    yaw = 0.0
    if pose is not None:
        yaw = float(Rotation.from_quat(pose.q_W_B_xyzw).as_euler("ZYX")[0])
    elif mag:
        m = Rotation.from_euler("ZYX", [0.0, pitch, roll]).apply(
            np.mean([s.field_B for s in mag], axis=0)
        )
        yaw = math.remainder(math.pi / 2 - declination_rad - math.atan2(m[1], m[0]), 2 * math.pi)
    if pose is not None:
        p0 = pose.p_W_B.copy()
    elif gps_enu_m is not None:
        p0 = np.asarray(gps_enu_m, dtype=np.float64).copy()
    else:
        p0 = np.zeros(3)
    return Rotation.from_euler("ZYX", [yaw, pitch, roll]), p0


def run_nav(sc: NavScenario, seed: int, *, record_stream: bool = False) -> NavRunResult:
    """Align on the ground, fly the plan, and log truth, estimates and fusions."""
    rng = np.random.default_rng(seed)
    rng_sens, rng_bias = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    del rng
    params = RigidBodyParams()
    dt = sc.sim_dt_s
    sim = RigidBodyQuadrotor(params, dt_s=dt)
    ctrl = CascadedPid(params, dt_s=dt)
    ic = sc.imu
    imu_period_ns = round(1e9 / ic.rate_hz)
    imu = IntegratingImu(
        period_ns=imu_period_ns,
        gyro_sigma_rad_s=ic.gyro_sigma_rad_s,
        accel_sigma_m_s2=ic.accel_sigma_m_s2,
        gyro_bias_rw_rad_s_sqrt_s=ic.gyro_bias_rw_rad_s_sqrt_s,
        accel_bias_rw_m_s2_sqrt_s=ic.accel_bias_rw_m_s2_sqrt_s,
        gyro_bias0_rad_s=tuple(ic.gyro_bias0_sigma_rad_s * rng_bias.standard_normal(3)),
        accel_bias0_m_s2=tuple(ic.accel_bias0_sigma_m_s2 * rng_bias.standard_normal(3)),
        gravity_m_s2=params.gravity_m_s2,
        lever_arm_m=ic.lever_arm_m,
    )
    vs = sc.vision
    vision: VisionPoseSensor | MarkerCameraSensor | None
    if vs.enabled and vs.source == "camera":
        vision = MarkerCameraSensor(
            period_ns=round(1e9 / vs.rate_hz),
            markers=marker_field(vs.marker_grid, vs.marker_spacing_m, vs.marker_length_m, vs.marker_origin_m),
            T_B_C=thesis_mount(), dropouts_ns=[(round(a * 1e9), round(b * 1e9)) for a, b in vs.dropouts_s],
            noise_sigma=vs.image_noise, seed=seed,
        )  # fmt: skip
    else:
        vision = VisionPoseSensor(
        period_ns=round(1e9 / vs.rate_hz), sigma_m=vs.sigma_m, yaw_sigma_rad=vs.yaw_sigma_rad,
        frame_yaw_rad=math.radians(vs.frame_yaw_deg), frame_offset_m=vs.frame_offset_m,
        dropouts_ns=[(round(a * 1e9), round(b * 1e9)) for a, b in vs.dropouts_s],
        jumps=[VisionFrameJump(round(t * 1e9), math.radians(y), (dx, dy, dz)) for t, y, dx, dy, dz in vs.jumps],
        ) if vs.enabled else None  # fmt: skip
    vision_line: DelayLine[PoseSample] = DelayLine(delay_ns=round(vs.delay_s * 1e9))
    late_vision = sorted((round(t * 1e9), round(d * 1e9)) for t, d in sc.faults.vision_late_s)
    baro = BaroSensor(period_ns=round(1e9 / sc.baro.rate_hz), sigma_m=sc.baro.sigma_m,
                      drift_m_sqrt_s=sc.baro.drift_m_sqrt_s) if sc.baro.enabled else None  # fmt: skip
    baro_line: DelayLine[HeightSample] = DelayLine(delay_ns=round(sc.baro.delay_s * 1e9))
    rangefinder = RangeFinder(period_ns=round(1e9 / sc.range.rate_hz), sigma_m=sc.range.sigma_m, min_m=RANGE_MIN_M,
                              max_m=sc.range.max_m) if sc.range.enabled else None  # fmt: skip
    range_line: DelayLine[RangeSample] = DelayLine(delay_ns=round(sc.range.delay_s * 1e9))
    gps = GpsSensor(
        datum_lla=sc.gps.datum_lla, period_ns=round(1e9 / sc.gps.rate_hz), sigma_h_m=sc.gps.sigma_h_m,
        sigma_v_m=sc.gps.sigma_v_m, sigma_vel_m_s=sc.gps.sigma_vel_m_s,
        outages_ns=[(round(a * 1e9), round(b * 1e9)) for a, b in sc.gps.outages_s],
        glitches=[(round(a * 1e9), round(b * 1e9), (e, n, 0.0)) for a, b, e, n in sc.faults.gps_glitch],
    ) if sc.gps.enabled else None  # fmt: skip
    gps_line: DelayLine[GpsSample] = DelayLine(delay_ns=round(sc.gps.delay_s * 1e9))
    mag = MagSensor(period_ns=round(1e9 / sc.mag.rate_hz), declination_rad=sc.mag.declination_rad,
                    noise_sigma=sc.mag.noise_sigma, sigma_heading_rad=sc.mag.sigma_heading_rad) if sc.mag.enabled else None  # fmt: skip
    imu_nan = sorted(round(t * 1e9) for t in sc.faults.imu_nan_s)
    imu_repeat = sorted(round(t * 1e9) for t in sc.faults.imu_repeat_s)
    rotate = sc.estimator.vision_frame == "rotate"
    align_mag: list[MagSample] = []
    first_fix: GpsSample | None = None
    plan = sc.waypoints()
    align_ns = round(sc.estimator.align_s * 1e9)
    n_steps = round(sc.flight_s / dt)
    ref_all = plan.reference(np.arange(n_steps + 1) * dt - sc.estimator.align_s)
    yaw_ref = heading_reference(ref_all.v, dt, sc.plan.yaw, math.radians(sc.plan.yaw_rate_deg_s))

    est: DelayedHorizonEstimator | None = None
    ekf: NavEkf | None = None
    align_imu: list[ImuSample] = []
    last_pose: PoseSample | None = None
    last_gyro = np.zeros(3)
    truth_hist: dict[int, tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]] = {}
    rows: dict[str, list[object]] = {
        k: [] for k in ("t", "tp", "tv", "tq", "ref", "op", "ov", "oq", "td", "xd", "err", "P")
    }
    vision_times: list[int] = []
    landed = False
    n_imu_ground = 0
    stream: list[Sample] | None = [] if record_stream else None
    try:
        for i in range(n_steps):
            truth = sim.state()
            t = truth.t_ns
            # -- sensors ---------------------------------------------------------------------
            if vision is not None:
                pose = vision.sample(truth, t, rng_sens)
                if pose is not None:
                    late = 0
                    if late_vision and t >= late_vision[0][0]:
                        late = late_vision.pop(0)[1]
                    vision_line.push(pose, extra_delay_ns=late)
                    vision_times.append(t)
            if gps is not None:
                fix = gps.sample(truth, t, rng_sens)
                if fix is not None:
                    gps_line.push(fix)
            mag_now = mag.sample(truth, t, rng_sens) if mag is not None else None
            if baro is not None:
                h = baro.sample(truth, t, rng_sens)
                if h is not None:
                    baro_line.push(h)
            if rangefinder is not None:
                rs = rangefinder.sample(truth, t, rng_sens)
                if rs is not None:
                    range_line.push(rs)
            # -- estimator -------------------------------------------------------------------
            sample = imu.accumulate(truth, dt, rng_sens) if i > 0 else None
            arrived_pose = vision_line.pop_arrived(t)
            arrived_baro = baro_line.pop_arrived(t)
            arrived_gps = gps_line.pop_arrived(t)
            arrived_range = range_line.pop_arrived(t)
            if est is None:
                if sample is not None:
                    align_imu.append(sample)
                for _, pz in arrived_pose:
                    last_pose = pz
                for _, fx in arrived_gps:
                    first_fix = first_fix or fx
                if mag_now is not None:
                    align_mag.append(mag_now)
                if t >= align_ns and align_imu:
                    gps_enu = None
                    if first_fix is not None:
                        import pymap3d

                        gps_enu = np.array(
                            pymap3d.geodetic2enu(
                                first_fix.lat_deg,
                                first_fix.lon_deg,
                                first_fix.alt_m,
                                *sc.gps.datum_lla,
                            )
                        )
                    # Rotated vision: the heading is the magnetometer's, the origin where it stands.
                    align_pose = None if rotate else last_pose
                    R0, p0 = ground_alignment(
                        align_imu,
                        align_pose,
                        mag=align_mag,
                        declination_rad=sc.mag.declination_rad,
                        gps_enu_m=gps_enu,
                    )
                    yaw_sig = (
                        sc.vision.yaw_sigma_rad * 3 if align_pose else (0.1 if align_mag else 1.0)
                    )
                    pos_sig = (
                        sc.vision.sigma_m * 3
                        if align_pose
                        else (sc.gps.sigma_h_m * 2 if first_fix else 0.1)
                    )
                    sig = np.array([0.02, 0.02, yaw_sig] + [0.05] * 3 + [pos_sig] * 3
                                   + [max(ic.gyro_bias0_sigma_rad_s, 1e-4)] * 3 + [max(ic.accel_bias0_sigma_m_s2, 1e-3)] * 3)  # fmt: skip
                    ekf = NavEkf(
                        NavEkfConfig(
                            gyro_sigma_rad_s=ic.gyro_sigma_rad_s * sc.estimator.imu_noise_inflation,
                            accel_sigma_m_s2=ic.accel_sigma_m_s2 * sc.estimator.imu_noise_inflation,
                            gyro_bias_rw_rad_s_sqrt_s=ic.gyro_bias_rw_rad_s_sqrt_s * sc.estimator.bias_rw_inflation,
                            accel_bias_rw_m_s2_sqrt_s=ic.accel_bias_rw_m_s2_sqrt_s * sc.estimator.bias_rw_inflation,
                            gravity_m_s2=params.gravity_m_s2,
                            gate_probability=sc.estimator.gate_probability,
                            datum_lla=sc.gps.datum_lla,
                            mag_declination_rad=sc.mag.declination_rad,
                            vision_frame=sc.estimator.vision_frame,
                            reset_after_s=sc.estimator.reset_after_s,
                        ),
                        p0=p0, v0=np.zeros(3), q0_xyzw=R0.as_quat(), P0=np.diag(sig**2),
                    )  # fmt: skip
                    max_delay = max(
                        sc.vision.delay_s if sc.vision.enabled else 0.0,
                        sc.baro.delay_s if sc.baro.enabled else 0.0,
                        sc.gps.delay_s if sc.gps.enabled else 0.0,
                        sc.range.delay_s if sc.range.enabled else 0.0,
                    )
                    est = DelayedHorizonEstimator(
                        ekf,
                        HorizonConfig(
                            imu_period_ns=imu_period_ns,
                            max_delay_ns=round(max_delay * 1e9),
                            tau_vel_s=sc.estimator.tau_vel_s,
                            tau_pos_s=sc.estimator.tau_pos_s,
                        ),
                        t0_ns=t,
                    )
            else:
                batch: list[Sample] = [o for _, o in arrived_pose]
                batch.extend(o for _, o in arrived_baro)
                batch.extend(o for _, o in arrived_gps)
                batch.extend(o for _, o in arrived_range)
                if mag_now is not None:
                    batch.append(mag_now)
                on_ground = landed or (ref_all.p[i][2] <= 0.0 and i < n_steps // 2)
                if sample is not None and on_ground and sc.estimator.zero_velocity_on_ground:
                    n_imu_ground += 1
                    if n_imu_ground % 10 == 0:  # 25 Hz of "standing still"
                        batch.append(VelocitySample(t_ns=t, v_W_B=np.zeros(3), sigma_m_s=0.02))
                if sample is not None and imu_nan and t >= imu_nan[0]:
                    # A corrupted reading from the driver: refused at the boundary and counted.
                    imu_nan.pop(0)
                    gyro = sample.gyro_rad_s.copy()
                    gyro[1] = math.nan
                    est.push_raw(ImuSample, t_ns=t, gyro_rad_s=gyro, accel_m_s2=sample.accel_m_s2)
                elif sample is not None:
                    batch.append(sample)
                    if imu_repeat and t >= imu_repeat[0]:
                        imu_repeat.pop(0)
                        batch.append(sample)  # delivered twice: the copy is out of order
                for item in batch:
                    est.push(item)
                if stream is not None:
                    stream.extend(batch)
            if sample is not None:
                last_gyro = sample.gyro_rad_s
            # -- logging at IMU steps after alignment ----------------------------------------
            if sample is not None and est is not None and ekf is not None and t > est.t_delayed_ns:
                truth_hist[t] = (
                    truth.p_W_B,
                    truth.v_W_B,
                    truth.q_W_B_xyzw,
                    imu.bias_g.copy(),
                    imu.bias_a.copy(),
                )
                out = est.output_nav()
                rows["t"].append(t)
                rows["tp"].append(truth.p_W_B)
                rows["tv"].append(truth.v_W_B)
                rows["tq"].append(truth.q_W_B_xyzw)
                rows["ref"].append(ref_all.p[i])
                rows["op"].append(out.pos)
                rows["ov"].append(out.vel)
                rows["oq"].append(quat_xyzw_from_matrix(out.att.reshape(3, 3)))
                td = est.t_delayed_ns
                rows["td"].append(td)
                rows["xd"].append(np.concatenate([ekf.p, ekf.v, ekf.q_xyzw, ekf.bg, ekf.ba]))
                if td in truth_hist:
                    p_t, v_t, q_t, bg_t, ba_t = truth_hist[td]
                    dth = so3_log(ekf.R.T @ rotation_matrix_xyzw(q_t))
                    rows["err"].append(
                        np.concatenate(
                            [dth, v_t - ekf.v, p_t - ekf.p, bg_t - ekf.bg, ba_t - ekf.ba]
                        )
                    )
                else:
                    rows["err"].append(np.full(15, np.nan))
                rows["P"].append(ekf.P.copy())
            # -- control ---------------------------------------------------------------------
            ref_i = ref_all.p[i]
            # Motors stay off on the ground until the plan starts to climb (and after touch-down).
            if t < align_ns or landed or (ref_i[2] <= 0.0 and i < n_steps // 2):
                cmd = np.zeros(4)
            else:
                if sc.closed_loop and est is not None and ekf is not None:
                    state = est.output()
                    if state.w_B is None:  # the output predictor carries no body rate yet
                        state = replace(state, w_B=last_gyro - ekf.bg)
                else:
                    state = truth_estimate(truth)
                cmd = ctrl(
                    t,
                    state,
                    Setpoint(p=ref_i, v=ref_all.v[i], a=ref_all.a[i], yaw_rad=float(yaw_ref[i])),
                ).rotors()
                # Touch-down: the plan has come down and the vehicle sits low: cut the motors.
                if i > n_steps // 2 and ref_i[2] <= 0.0 and state.p_W_B[2] < 0.05:
                    landed = True
                    cmd = np.zeros(4)
            sim.step(cmd)
    except SimError as exc:
        raise ExperimentError(f"scenario {sc.name!r} seed {seed}: {exc}") from None
    if est is None or ekf is None:
        raise ExperimentError(
            f"scenario {sc.name!r}: the flight ended before the filter was aligned"
        )
    fusion: dict[str, dict[str, NDArray[np.float64]]] = {}
    for src in est.sources:
        recs = [r for r in est.fusion_log if r.source == src]
        fusion[src] = {
            "t_obs_ns": np.array([r.t_obs_ns for r in recs], dtype=np.float64),
            "nis": np.array([r.result.nis for r in recs]),
            "test_ratio": np.array([r.result.test_ratio for r in recs]),
            "accepted": np.array([r.result.accepted for r in recs], dtype=np.float64),
            "dof": np.array([len(r.result.innovation) for r in recs], dtype=np.float64),
            "innovation": _stack_padded([r.result.innovation for r in recs]),
        }
    counts = {
        src: {
            "received": s.received,
            "fused": s.fused,
            "rejected_gate": s.rejected_gate,
            "rejected_too_old": s.rejected_too_old,
            "rejected_unsupported": s.rejected_unsupported,
        }
        for src in est.sources
        for s in [est.stats(src)]
    }
    counts["imu"] = {
        "rejected_out_of_order": est.imu_rejected_out_of_order,
        "rejected_invalid": est.rejected_invalid.get("ImuSample", 0),
    }
    return NavRunResult(
        scenario=sc,
        seed=seed,
        t_ns=np.array(rows["t"], dtype=np.int64),
        truth_p=np.array(rows["tp"]),
        truth_v=np.array(rows["tv"]),
        truth_q=np.array(rows["tq"]),
        ref_p=np.array(rows["ref"]),
        output_p=np.array(rows["op"]),
        output_v=np.array(rows["ov"]),
        output_q=np.array(rows["oq"]),
        t_delayed_ns=np.array(rows["td"], dtype=np.int64),
        delayed_x=np.array(rows["xd"]),
        delayed_err=np.array(rows["err"]),
        delayed_P=np.array(rows["P"]),
        vision_t_ns=np.array(vision_times, dtype=np.int64),
        fusion=fusion,
        counts=counts,
        t_align_ns=align_ns,
        events=list(ekf.events),
        stream=stream,
    )
