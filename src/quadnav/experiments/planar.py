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
            what = "estimator.max_delay_s" if self.estimator.max_delay_s is not None else "gps.delay_s + gps.jitter_s"  # fmt: skip
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


def run_planar(config: PlanarConfig, experiment: ExperimentName, seed: int) -> PlanarRun:
    """Simulate, estimate and record one experiment with one seed."""
    if experiment not in EXPERIMENTS:
        raise ExperimentError(
            f"unknown planar experiment {experiment!r}; choose from {EXPERIMENTS}"
        )
    dt_ns = s_to_ns(config.dt_s)
    n_steps = round(config.duration_s / config.dt_s)
    t0_ns = 0
    # Independent streams: the same seed gives the same sensor noise in every experiment.
    ss_imu, ss_gps, ss_init = np.random.SeedSequence(seed).spawn(3)
    rng_imu, rng_gps, rng_init = (np.random.default_rng(s) for s in (ss_imu, ss_gps, ss_init))

    v = config.vehicle
    sim = PlanarQuadrotor(
        PlanarParams(mass_kg=v.mass_kg, gravity_m_s2=v.gravity_m_s2, inertia_kg_m2=v.inertia_kg_m2),
        dt_ns=dt_ns,
        t0_ns=t0_ns,
    )
    c = config.controller
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
        t0_ns=t0_ns,
    )
    imu_sensor = ImuSensor(
        accel_sigma_m_s2=config.imu.accel_sigma_m_s2,
        gyro_sigma_rad_s=config.imu.gyro_sigma_rad_s,
        gravity_m_s2=v.gravity_m_s2,
        accel_model=config.imu.accel_model,
    )
    gps_sensor = PositionSensor(
        sigma_m=config.gps.sigma_m, period_ns=s_to_ns(config.gps.period_s), t0_ns=t0_ns
    )
    gps_line: DelayLine[PositionSample] = DelayLine(
        delay_ns=s_to_ns(config.gps.delay_s), jitter_ns=s_to_ns(config.gps.jitter_s)
    )

    e = config.estimator
    sig0 = np.array(
        [e.init_sigma_pos_m] * 2 + [e.init_sigma_vel_m_s] * 2 + [e.init_sigma_theta_rad]
    )
    s0 = sim.state
    x_true0 = np.array([*s0.p_xz, *s0.v_xz, s0.theta_rad])
    ekf = PlanarEkf(
        PlanarEkfConfig(
            accel_sigma_m_s2=config.imu.accel_sigma_m_s2,
            gyro_sigma_rad_s=config.imu.gyro_sigma_rad_s,
            gravity_m_s2=v.gravity_m_s2,
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
        t0_ns=t0_ns,
    )

    N = n_steps + 1
    t_ns = t0_ns + dt_ns * np.arange(N, dtype=np.int64)
    truth_p = np.zeros((N, 2))
    truth_v = np.zeros((N, 2))
    truth_theta = np.zeros(N)
    out_p = np.zeros((N, 2))
    out_v = np.zeros((N, 2))
    out_theta = np.zeros(N)
    t_d = np.zeros(N, dtype=np.int64)
    x_d = np.zeros((N, 5))
    P_d = np.zeros((N, 5, 5))
    gyro = np.zeros((N, 3))
    accel = np.zeros((N, 3))
    imu_dt = np.full(N, config.dt_s)
    gps_valid: list[int] = []
    gps_arrival: list[int] = []
    gps_p: list[FloatArray] = []

    def record(i: int) -> None:
        s = sim.state
        truth_p[i], truth_v[i], truth_theta[i] = s.p_xz, s.v_xz, s.theta_rad
        o = est.output_nav()
        out_p[i], out_v[i], out_theta[i] = o.pos, o.vel, o.att[0]
        t_d[i] = est.t_delayed_ns
        x_d[i] = ekf.x
        P_d[i] = ekf.P

    record(0)
    truth = sim.state.to_vehicle_state()
    for i in range(1, N):
        thrust, torque = controller(int(t_ns[i]), truth)
        try:
            truth = sim.step(thrust, torque).to_vehicle_state()
        except SimError as exc:
            raise ExperimentError(
                f"experiment {experiment}, seed {seed}: {exc}; the vehicle.* and controller.* settings "
                f"do not hold it at dt_s = {config.dt_s:g} s"
            ) from None
        imu = imu_sensor.sample(truth, int(t_ns[i]), rng_imu)
        gyro[i], accel[i] = imu.gyro_rad_s, imu.accel_m_s2
        fix = gps_sensor.sample(truth, int(t_ns[i]), rng_gps)
        if fix is not None:
            gps_line.push(fix, rng_gps)
        # Observations that arrived by now go in before the IMU sample that advances time.
        for arrival, sample in gps_line.pop_arrived(int(t_ns[i])):
            gps_valid.append(sample.t_ns)
            gps_arrival.append(arrival)
            gps_p.append(sample.p_W_B[[0, 2]])
            if experiment == "no_update":
                continue
            if experiment == "naive":
                sample = PositionSample(
                    t_ns=arrival, p_W_B=sample.p_W_B, sigma_m=sample.sigma_m, source=sample.source
                )
            est.push(sample)
        est.push(imu)
        record(i)

    # The floor: the delayed estimate re-integrated through the IMU samples buffered since.
    start = (t_d - t0_ns) // dt_ns
    floor_p, floor_v, floor_att = reintegration_floor(
        ekf.kinematics,
        pos_d=x_d[:, 0:2],
        vel_d=x_d[:, 2:4],
        att_d=x_d[:, 4:5],
        start_idx=start,
        end_idx=np.arange(N, dtype=np.int64),
        gyro=gyro,
        accel=accel,
        dt_s=imu_dt,
    )
    log = est.fusion_log
    stats = est.stats("gps")
    return PlanarRun(
        experiment=experiment,
        seed=seed,
        t_ns=t_ns,
        truth_p=truth_p,
        truth_v=truth_v,
        truth_theta=truth_theta,
        output_p=out_p,
        output_v=out_v,
        output_theta=out_theta,
        t_delayed_ns=t_d,
        delayed_x=x_d,
        delayed_P=P_d,
        floor_p=floor_p,
        floor_v=floor_v,
        floor_theta=floor_att[:, 0],
        gps_t_valid_ns=np.array(gps_valid, dtype=np.int64),
        gps_t_arrival_ns=np.array(gps_arrival, dtype=np.int64),
        gps_p=np.array(gps_p).reshape(-1, 2),
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
