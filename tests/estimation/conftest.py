"""A short closed-loop flight of the planar vehicle, as sample streams for estimator tests."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from quadnav.control import PlanarSetpointProfile, ThesisPlanarController, truth_estimate
from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig, PlanarEkf, PlanarEkfConfig
from quadnav.messages import ImuSample, PositionSample
from quadnav.sim import ImuSensor, PlanarParams, PlanarQuadrotor, PlanarState

DT_NS = 10_000_000


@dataclass
class Flight:
    states: list[PlanarState]  # states[i] at t = i * DT_NS
    imu: list[ImuSample]  # imu[i - 1] ends the step to states[i]

    def truth_x(self, i: int) -> np.ndarray:
        s = self.states[i]
        return np.array([*s.p_xz, *s.v_xz, s.theta_rad])

    def fix(self, i: int, *, sigma: float = 1e-3, offset: float = 0.0) -> PositionSample:
        s = self.states[i]
        return PositionSample(
            t_ns=s.t_ns, p_W_B=np.array([s.p_xz[0] + offset, 0.0, s.p_xz[1]]), sigma_m=sigma
        )


def fly(
    n_steps: int, *, accel_sigma: float = 0.0, gyro_sigma: float = 0.0, seed: int = 0
) -> Flight:
    """Climb, then tilt early so every state moves within a few seconds."""
    sim = PlanarQuadrotor(PlanarParams(), dt_ns=DT_NS)
    ctrl = ThesisPlanarController(
        profile=PlanarSetpointProfile(climb_end_s=1.0, tilt_start_s=1.5, tilt_switch_s=2.5)
    )
    imu_sensor = ImuSensor(accel_sigma_m_s2=accel_sigma, gyro_sigma_rad_s=gyro_sigma)
    rng = np.random.default_rng(seed)
    states = [sim.state]
    imu = []
    truth = sim.state.to_vehicle_state()
    for i in range(1, n_steps + 1):
        cmd = ctrl(i * DT_NS, truth_estimate(truth), ctrl.setpoint(i * DT_NS))
        states.append(sim.step(cmd.thrust_n, float(cmd.torque()[1])))
        truth = states[-1].to_vehicle_state()
        imu.append(imu_sensor.sample(truth, i * DT_NS, rng))
    return Flight(states, imu)


@pytest.fixture(scope="session")
def clean_flight() -> Flight:
    return fly(400)


def make_estimator(
    flight: Flight,
    *,
    max_delay_ns: int,
    x0_offset: np.ndarray | None = None,
    P0_sigma: float = 1e-3,
    output_correction: bool = True,
    gate_probability: float | None = 0.9999,
    max_observations_per_source: int = 1024,
) -> DelayedHorizonEstimator:
    x0 = flight.truth_x(0) + (np.zeros(5) if x0_offset is None else x0_offset)
    ekf = PlanarEkf(
        PlanarEkfConfig(
            accel_sigma_m_s2=1e-3, gyro_sigma_rad_s=1e-4, gate_probability=gate_probability
        ),
        x0=x0,
        P0=np.eye(5) * P0_sigma**2,
    )
    return DelayedHorizonEstimator(
        ekf,
        HorizonConfig(
            imu_period_ns=DT_NS,
            max_delay_ns=max_delay_ns,
            output_correction=output_correction,
            max_observations_per_source=max_observations_per_source,
        ),
        t0_ns=0,
    )
