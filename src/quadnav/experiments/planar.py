"""Thesis 000's planar experiment: the delayed-measurement problem, three ways.

A planar quadrotor climbs and tilts (its controller acts on the true state); an IMU and a
delayed GPS position measure it; the planar EKF estimates it:

* ``no_update``: IMU only, no GPS (thesis figure 2.3);
* ``naive``: each GPS fix fused when it arrives, as if it were current, and, as in the
  thesis, without an innovation gate (a gate would reject every delayed fix) (figure 2.4);
* ``handled``: the delayed-horizon core fuses each fix at its time of validity and the output
  predictor carries the estimate to the current time (figure 2.5).

Configuration is a pydantic model whose defaults are the thesis's parameters. Results are
arrays; writing files and plotting belong to ``io`` and ``eval``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Self

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, model_validator

from quadnav.config_model import MAX_DELAY_S, MAX_DURATION_S, MAX_SIM_STEPS, MIN_SIGMA, ConfigModel
from quadnav.control.base import truth_estimate
from quadnav.control.planar import PlanarSetpointProfile, ThesisPlanarController
from quadnav.errors import ExperimentError, SimError
from quadnav.estimation.floor import reintegration_floor
from quadnav.estimation.horizon import DelayedHorizonEstimator, HorizonConfig
from quadnav.estimation.planar_ekf import PlanarEkf, PlanarEkfConfig
from quadnav.messages import PositionSample
from quadnav.sim.planar import PlanarParams, PlanarQuadrotor
from quadnav.sim.sensors import DelayLine, ImuSensor, PositionSensor
from quadnav.units import GRAVITY_M_S2, s_to_ns

__all__ = [
    "EXPERIMENTS",
    "ExperimentName",
    "PlanarConfig",
    "PlanarRun",
    "run_planar",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
ExperimentName = Literal["no_update", "naive", "handled"]
EXPERIMENTS: tuple[ExperimentName, ...] = ("no_update", "naive", "handled")
T0_NS = 0  # every run starts at t = 0


class VehicleSection(ConfigModel):
    mass_kg: float = Field(1.0, ge=0.01, description="kg, 10 g at least")
    gravity_m_s2: float = Field(GRAVITY_M_S2, gt=0)
    inertia_kg_m2: float = Field(1.0 * 0.45**2 / 12.0, gt=0)


class ControllerSection(ConfigModel):
    k_climb: float = Field(2.0, gt=0, description="climb-rate gain (N per m/s)")
    k_tilt: float = Field(0.2, gt=0, description="attitude P gain (N m per rad)")
    kd_tilt: float = Field(0.1, gt=0, description="attitude D gain (N m per rad/s)")
    climb_rate_m_s: float = 2.0
    climb_end_s: float = Field(2.5, ge=0, le=MAX_DURATION_S)
    tilt_deg: float = Field(30.0, gt=-90, lt=90)
    tilt_start_s: float = Field(7.0, ge=0, le=MAX_DURATION_S)
    tilt_switch_s: float = Field(8.5, ge=0, le=MAX_DURATION_S)

    @model_validator(mode="after")
    def _order(self) -> Self:
        if self.tilt_switch_s < self.tilt_start_s:
            raise ValueError(
                "controller.tilt_switch_s must not come before controller.tilt_start_s"
            )
        return self


class ImuSection(ConfigModel):
    accel_sigma_m_s2: float = Field(
        0.25, ge=MIN_SIGMA, description="accelerometer noise per sample"
    )
    gyro_sigma_rad_s: float = Field(0.03, ge=MIN_SIGMA, description="gyroscope noise per sample")
    accel_model: Literal["specific_force", "kinematic"] = "specific_force"


class GpsSection(ConfigModel):
    sigma_m: float = Field(0.01, ge=MIN_SIGMA, description="position noise per axis")
    period_s: float = Field(0.3, gt=0, le=MAX_DURATION_S)
    delay_s: float = Field(1.0, ge=0, le=MAX_DELAY_S, description="time from validity to arrival")
    jitter_s: float = Field(
        0.0, ge=0, le=MAX_DELAY_S, description="extra uniform arrival delay in [0, jitter_s]"
    )


class EstimatorSection(ConfigModel):
    gate_probability: float | None = Field(0.9999, gt=0, lt=1)
    init_sigma_pos_m: float = Field(0.01, ge=MIN_SIGMA)
    init_sigma_vel_m_s: float = Field(0.01, ge=MIN_SIGMA)
    init_sigma_theta_rad: float = Field(0.005, ge=MIN_SIGMA)
    tau_vel_s: float = Field(0.1, gt=0, description="output predictor velocity time constant")
    tau_pos_s: float = Field(0.1, gt=0, description="output predictor position time constant")
    propagate_velocity_correction: bool = Field(
        True, description="shift buffered positions by velocity corrections (False: PX4 exactly)"
    )
    max_delay_s: float | None = Field(
        None,
        ge=0,
        le=MAX_DELAY_S,
        description="delay the buffers are sized for; default: gps delay + jitter",
    )


class PlanarConfig(ConfigModel):
    """Everything the planar experiment needs; the defaults are thesis 000's parameters."""

    name: str = "planar"
    experiments: list[ExperimentName] = Field(
        default_factory=lambda: list(EXPERIMENTS), min_length=1
    )
    duration_s: float = Field(10.0, gt=0, le=MAX_DURATION_S)
    dt_s: float = Field(0.01, gt=0, description="simulation and IMU step")
    seed: int = Field(0, ge=0, description="first seed; Monte Carlo runs use seed, seed+1, ...")
    seeds: int = Field(1, ge=1, le=10000, description="number of Monte Carlo runs")
    vehicle: VehicleSection = VehicleSection()
    controller: ControllerSection = ControllerSection()
    imu: ImuSection = ImuSection()
    gps: GpsSection = GpsSection()
    estimator: EstimatorSection = EstimatorSection()

    @model_validator(mode="after")
    def _timing(self) -> Self:
        if self.duration_s < self.dt_s:
            raise ValueError(f"duration_s ({self.duration_s}) is shorter than dt_s ({self.dt_s})")
        if self.gps.period_s < self.dt_s:
            raise ValueError(
                f"gps.period_s ({self.gps.period_s}) is shorter than dt_s ({self.dt_s}): "
                "a sensor cannot run faster than the simulation step"
            )
        if s_to_ns(self.dt_s) < 1000:
            raise ValueError("dt_s must be at least 1 microsecond")
        if self.duration_s / self.dt_s > MAX_SIM_STEPS:
            raise ValueError(
                f"duration_s / dt_s is {self.duration_s / self.dt_s:.3g} steps, more than "
                f"{MAX_SIM_STEPS:g}: raise dt_s or shorten duration_s"
            )
        if self.buffer_delay_s >= self.duration_s:
            what = "gps.delay_s + gps.jitter_s"
            if self.estimator.max_delay_s is not None:
                what = "estimator.max_delay_s"
            raise ValueError(
                f"the delayed horizon runs {what} = {self.buffer_delay_s:g} s behind: "
                f"duration_s ({self.duration_s:g} s) must be longer"
            )
        return self

    @property
    def buffer_delay_s(self) -> float:
        if self.estimator.max_delay_s is not None:
            return self.estimator.max_delay_s
        return self.gps.delay_s + self.gps.jitter_s


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanarRun:
    """One experiment with one seed. Row ``i`` of the per-step arrays is IMU step ``i``
    (row 0: the initial state at ``t0``). Delayed-horizon quantities are valid at ``t_delayed_ns``.
    """

    experiment: ExperimentName
    seed: int
    t_ns: IntArray
    truth_p: FloatArray
    truth_v: FloatArray
    truth_theta: FloatArray
    output_p: FloatArray
    output_v: FloatArray
    output_theta: FloatArray
    t_delayed_ns: IntArray
    delayed_x: FloatArray
    delayed_P: FloatArray
    floor_p: FloatArray
    floor_v: FloatArray
    floor_theta: FloatArray
    gps_t_valid_ns: IntArray
    gps_t_arrival_ns: IntArray
    gps_p: FloatArray
    fusion_t_obs_ns: IntArray
    fusion_t_fused_ns: IntArray
    fusion_innovation: FloatArray
    fusion_nis: FloatArray
    fusion_test_ratio: FloatArray
    fusion_accepted: NDArray[np.bool_]
    gps_received: int
    gps_fused: int
    gps_rejected_gate: int
    gps_rejected_too_old: int
    gps_pending: int
    buffer_length: int

    @property
    def delayed_index(self) -> IntArray:
        """Row of the truth arrays at each step's delayed horizon."""
        dt_ns = int(self.t_ns[1] - self.t_ns[0])
        return np.asarray((self.t_delayed_ns - self.t_ns[0]) // dt_ns, dtype=np.int64)


@dataclass(slots=True)
class _Loop:
    """The wired parts of one run: the vehicle and its controller, the sensors, the estimator."""

    sim: PlanarQuadrotor
    controller: ThesisPlanarController
    imu: ImuSensor
    gps: PositionSensor
    gps_line: DelayLine[PositionSample]
    ekf: PlanarEkf
    est: DelayedHorizonEstimator


class _Recorder:
    """Per-step arrays of one run (row ``i``: IMU step ``i``) and the GPS fixes as they arrive."""

    def __init__(self, n: int, dt_s: float) -> None:
        self.truth_p, self.out_p = np.zeros((n, 2)), np.zeros((n, 2))
        self.truth_v, self.out_v = np.zeros((n, 2)), np.zeros((n, 2))
        self.truth_theta, self.out_theta = np.zeros(n), np.zeros(n)
        self.t_d = np.zeros(n, dtype=np.int64)
        self.x_d = np.zeros((n, 5))
        self.P_d = np.zeros((n, 5, 5))
        self.gyro = np.zeros((n, 3))
        self.accel = np.zeros((n, 3))
        self.imu_dt = np.full(n, dt_s)
        self.gps_valid: list[int] = []
        self.gps_arrival: list[int] = []
        self.gps_p: list[FloatArray] = []

    def record(self, i: int, loop: _Loop) -> None:
        s = loop.sim.state
        self.truth_p[i], self.truth_v[i], self.truth_theta[i] = s.p_xz, s.v_xz, s.theta_rad
        o = loop.est.output_nav()
        self.out_p[i], self.out_v[i], self.out_theta[i] = o.pos, o.vel, o.att[0]
        self.t_d[i] = loop.est.t_delayed_ns
        self.x_d[i] = loop.ekf.x
        self.P_d[i] = loop.ekf.P

    def gps_arrived(self, arrival_ns: int, sample: PositionSample) -> None:
        self.gps_valid.append(sample.t_ns)
        self.gps_arrival.append(arrival_ns)
        self.gps_p.append(sample.p_W_B[[0, 2]])


def _vehicle(config: PlanarConfig, dt_ns: int) -> tuple[PlanarQuadrotor, ThesisPlanarController]:
    v, c = config.vehicle, config.controller
    sim = PlanarQuadrotor(
        PlanarParams(mass_kg=v.mass_kg, gravity_m_s2=v.gravity_m_s2, inertia_kg_m2=v.inertia_kg_m2),
        dt_ns=dt_ns,
        t0_ns=T0_NS,
    )
    controller = ThesisPlanarController(
        mass_kg=v.mass_kg,
        gravity_m_s2=v.gravity_m_s2,
        k_climb=c.k_climb,
        k_tilt=c.k_tilt,
        kd_tilt=c.kd_tilt,
        profile=PlanarSetpointProfile(
            climb_rate_m_s=c.climb_rate_m_s,
            climb_end_s=c.climb_end_s,
            tilt_rad=math.radians(c.tilt_deg),
            tilt_start_s=c.tilt_start_s,
            tilt_switch_s=c.tilt_switch_s,
        ),
        t0_ns=T0_NS,
    )
    return sim, controller


def _estimator(
    config: PlanarConfig,
    experiment: ExperimentName,
    x_true0: FloatArray,
    rng_init: np.random.Generator,
    dt_ns: int,
) -> tuple[PlanarEkf, DelayedHorizonEstimator]:
    """The planar EKF started one sigma-draw off the truth, and its delayed horizon (none but
    for ``handled``: the other two fuse each fix on arrival)."""
    e = config.estimator
    sig0 = np.array(
        [e.init_sigma_pos_m] * 2 + [e.init_sigma_vel_m_s] * 2 + [e.init_sigma_theta_rad]
    )
    ekf = PlanarEkf(
        PlanarEkfConfig(
            accel_sigma_m_s2=config.imu.accel_sigma_m_s2,
            gyro_sigma_rad_s=config.imu.gyro_sigma_rad_s,
            gravity_m_s2=config.vehicle.gravity_m_s2,
            accel_model=config.imu.accel_model,
            gate_probability=None if experiment == "naive" else e.gate_probability,
        ),
        x0=x_true0 + sig0 * rng_init.standard_normal(5),
        P0=np.diag(sig0**2),
    )
    max_delay_s = config.buffer_delay_s if experiment == "handled" else 0.0
    est = DelayedHorizonEstimator(
        ekf,
        HorizonConfig(
            imu_period_ns=dt_ns,
            max_delay_ns=s_to_ns(max_delay_s),
            tau_vel_s=e.tau_vel_s,
            tau_pos_s=e.tau_pos_s,
            propagate_velocity_correction=e.propagate_velocity_correction,
        ),
        t0_ns=T0_NS,
    )
    return ekf, est


Rngs = tuple[np.random.Generator, np.random.Generator]


def _build(
    config: PlanarConfig, experiment: ExperimentName, seed: int, dt_ns: int
) -> tuple[_Loop, Rngs]:
    """The loop of one run and its IMU and GPS generators.

    Independent streams: the same seed gives the same sensor noise in every experiment."""
    ss_imu, ss_gps, ss_init = np.random.SeedSequence(seed).spawn(3)
    rng_imu, rng_gps, rng_init = (np.random.default_rng(s) for s in (ss_imu, ss_gps, ss_init))
    sim, controller = _vehicle(config, dt_ns)
    s0 = sim.state
    x_true0 = np.array([*s0.p_xz, *s0.v_xz, s0.theta_rad])
    ekf, est = _estimator(config, experiment, x_true0, rng_init, dt_ns)
    loop = _Loop(
        sim=sim,
        controller=controller,
        imu=ImuSensor(
            accel_sigma_m_s2=config.imu.accel_sigma_m_s2,
            gyro_sigma_rad_s=config.imu.gyro_sigma_rad_s,
            gravity_m_s2=config.vehicle.gravity_m_s2,
            accel_model=config.imu.accel_model,
        ),
        gps=PositionSensor(
            sigma_m=config.gps.sigma_m, period_ns=s_to_ns(config.gps.period_s), t0_ns=T0_NS
        ),
        gps_line=DelayLine(
            delay_ns=s_to_ns(config.gps.delay_s), jitter_ns=s_to_ns(config.gps.jitter_s)
        ),
        ekf=ekf,
        est=est,
    )
    return loop, (rng_imu, rng_gps)


def _simulate(
    loop: _Loop,
    rec: _Recorder,
    t_ns: IntArray,
    rngs: Rngs,
    experiment: ExperimentName,
) -> None:
    """Fly, sense and estimate every step; raises SimError when the vehicle diverges."""
    rng_imu, rng_gps = rngs
    rec.record(0, loop)
    truth = loop.sim.state.to_vehicle_state()
    for i in range(1, len(t_ns)):
        t = int(t_ns[i])
        cmd = loop.controller(t, truth_estimate(truth), loop.controller.setpoint(t))
        truth = loop.sim.step(cmd.thrust_n, float(cmd.torque()[1])).to_vehicle_state()
        imu = loop.imu.sample(truth, t, rng_imu)
        rec.gyro[i], rec.accel[i] = imu.gyro_rad_s, imu.accel_m_s2
        fix = loop.gps.sample(truth, t, rng_gps)
        if fix is not None:
            loop.gps_line.push(fix, rng_gps)
        # Observations that arrived by now go in before the IMU sample that advances time.
        for arrival, sample in loop.gps_line.pop_arrived(t):
            rec.gps_arrived(arrival, sample)
            if experiment == "no_update":
                continue
            if experiment == "naive":
                sample = PositionSample(
                    t_ns=arrival, p_W_B=sample.p_W_B, sigma_m=sample.sigma_m, source=sample.source
                )
            loop.est.push(sample)
        loop.est.push(imu)
        rec.record(i, loop)


def run_planar(config: PlanarConfig, experiment: ExperimentName, seed: int) -> PlanarRun:
    """Simulate, estimate and record one experiment with one seed."""
    if experiment not in EXPERIMENTS:
        raise ExperimentError(
            f"unknown planar experiment {experiment!r}; choose from {EXPERIMENTS}"
        )
    dt_ns = s_to_ns(config.dt_s)
    n = round(config.duration_s / config.dt_s) + 1
    t_ns = T0_NS + dt_ns * np.arange(n, dtype=np.int64)
    loop, rngs = _build(config, experiment, seed, dt_ns)
    rec = _Recorder(n, config.dt_s)
    try:
        _simulate(loop, rec, t_ns, rngs, experiment)
    except SimError as exc:
        raise ExperimentError(
            f"experiment {experiment}, seed {seed}: {exc}; the vehicle.* and controller.* settings "
            f"do not hold it at dt_s = {config.dt_s:g} s"
        ) from None
    return _planar_run(experiment, seed, t_ns, rec, loop)


def _planar_run(
    experiment: ExperimentName, seed: int, t_ns: IntArray, rec: _Recorder, loop: _Loop
) -> PlanarRun:
    """The run's arrays, with the floor: the delayed estimate re-integrated through the IMU
    samples buffered since, at every step."""
    dt_ns = int(t_ns[1] - t_ns[0])
    floor_p, floor_v, floor_att = reintegration_floor(
        loop.ekf.kinematics,
        pos_d=rec.x_d[:, 0:2],
        vel_d=rec.x_d[:, 2:4],
        att_d=rec.x_d[:, 4:5],
        start_idx=(rec.t_d - T0_NS) // dt_ns,
        end_idx=np.arange(len(t_ns), dtype=np.int64),
        gyro=rec.gyro,
        accel=rec.accel,
        dt_s=rec.imu_dt,
    )
    est = loop.est
    log = est.fusion_log
    stats = est.stats("gps")
    return PlanarRun(
        experiment=experiment,
        seed=seed,
        t_ns=t_ns,
        truth_p=rec.truth_p,
        truth_v=rec.truth_v,
        truth_theta=rec.truth_theta,
        output_p=rec.out_p,
        output_v=rec.out_v,
        output_theta=rec.out_theta,
        t_delayed_ns=rec.t_d,
        delayed_x=rec.x_d,
        delayed_P=rec.P_d,
        floor_p=floor_p,
        floor_v=floor_v,
        floor_theta=floor_att[:, 0],
        gps_t_valid_ns=np.array(rec.gps_valid, dtype=np.int64),
        gps_t_arrival_ns=np.array(rec.gps_arrival, dtype=np.int64),
        gps_p=np.array(rec.gps_p).reshape(-1, 2),
        fusion_t_obs_ns=np.array([r.t_obs_ns for r in log], dtype=np.int64),
        fusion_t_fused_ns=np.array([r.t_fused_ns for r in log], dtype=np.int64),
        fusion_innovation=np.array([r.result.innovation for r in log]).reshape(-1, 2),
        fusion_nis=np.array([r.result.nis for r in log]),
        fusion_test_ratio=np.array([r.result.test_ratio for r in log]),
        fusion_accepted=np.array([r.result.accepted for r in log], dtype=bool),
        gps_received=stats.received,
        gps_fused=stats.fused,
        gps_rejected_gate=stats.rejected_gate,
        gps_rejected_too_old=stats.rejected_too_old,
        gps_pending=est.pending("gps"),
        buffer_length=est.buffer_length,
    )
