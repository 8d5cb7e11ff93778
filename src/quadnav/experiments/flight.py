"""Closed-loop flights on the true state: the thesis-002 Euler-Lagrange model with its PD or
nested-saturation controller, or the rigid-body model with the cascaded PID fed by a
trajectory, thesis 003's take-off controller or its obstacle-aware waypoint follower.

:class:`FlightConfig` is the YAML scenario (every field has a default); :data:`BUILTIN`
holds the built-in scenarios; :func:`run_flight` returns arrays.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Literal, Self

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, model_validator
from scipy.spatial.transform import Rotation

from quadnav.config_model import (
    MAX_DURATION_S,
    MAX_RATE_HZ,
    MAX_SIM_STEPS,
    ConfigModel,
    check_finite_mapping,
)
from quadnav.control.cascaded_pid import CascadedPid, CascadedPidGains, Setpoint
from quadnav.control.thesis002 import NestedSaturationController, PdController, RefRow
from quadnav.control.thesis003 import ObstacleAwareWaypointFollower, TakeoffForward
from quadnav.control.trajectories import (
    Circle,
    Hover,
    Reference,
    Sigmoid,
    TrajectoryGenerator,
    Waypoints,
)
from quadnav.errors import ControlError, ExperimentError, SimError
from quadnav.sim.euler_lagrange import EulerLagrangeParams, EulerLagrangeQuadrotor
from quadnav.sim.rigid_body import RigidBodyQuadrotor, Wind
from quadnav.sim.world import Box, LaserScanner, World
from quadnav.vehicle import RigidBodyParams

__all__ = [
    "BUILTIN",
    "BUILTIN_DESCRIPTIONS",
    "FlightConfig",
    "FlightRun",
    "builtin_config",
    "run_flight",
]

FloatArray = NDArray[np.float64]
Vec3 = tuple[float, float, float]


class TrajectorySection(ConfigModel):
    """``position_m`` is the hover point, the sigmoid's start, or the circle's first point."""

    kind: Literal["hover", "sigmoid", "circle", "waypoints"] = "hover"
    position_m: Vec3 = (0.0, 0.0, 1.5)
    amplitude_m: Vec3 = (20.0, 20.0, 0.0)
    t_mid_s: float = 15.0
    duration_s: float = Field(10.0, gt=0, le=MAX_DURATION_S)
    radius_m: float = Field(2.0, gt=0)
    speed_m_s: float = Field(1.0, gt=0)
    points_m: list[Vec3] = Field(default_factory=lambda: [(0.0, 0.0, 1.5)], min_length=1)
    hold_s: float = Field(2.0, ge=0, le=MAX_DURATION_S)


class InitialSection(ConfigModel):
    position_m: Vec3 = (0.0, 0.0, 0.0)
    euler_rad: Vec3 = Field((0.0, 0.0, 0.0), description="roll, pitch, yaw")
    hovering: bool = Field(False, description="rigid body: rotors start at hover speed")


class WindSection(ConfigModel):
    mean_m_s: Vec3 = (0.0, 0.0, 0.0)
    gust_sigma_m_s: float = Field(0.0, ge=0)
    gust_tau_s: float = Field(2.0, gt=0)


class BoxSection(ConfigModel):
    name: str = "box"
    min_m: Vec3
    max_m: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> Self:
        if not all(a < b for a, b in zip(self.min_m, self.max_m, strict=True)):
            raise ValueError(
                f"min_m must be below max_m on every axis, got min_m {list(self.min_m)}, "
                f"max_m {list(self.max_m)}"
            )
        return self


class FlightConfig(ConfigModel):
    """A flight scenario: vehicle, controller, trajectory, world, duration, seed."""

    name: str = "circle"
    vehicle: Literal["euler_lagrange", "rigid_body"] = "rigid_body"
    controller: Literal[
        "pd", "nested_saturation", "cascaded_pid", "takeoff_forward", "waypoint_follower"
    ] = "cascaded_pid"
    trajectory: TrajectorySection = TrajectorySection(kind="circle")
    initial: InitialSection = InitialSection(position_m=(0.0, 0.0, 1.5), hovering=True)
    wind: WindSection = WindSection()
    world: list[BoxSection] = Field(default_factory=list)
    duration_s: float = Field(30.0, gt=0, le=MAX_DURATION_S)
    dt_s: float = Field(0.001, gt=0, le=0.01)
    seed: int = Field(0, ge=0)
    log_rate_hz: float = Field(100.0, gt=0, le=MAX_RATE_HZ)
    settle_band_m: float = Field(0.05, gt=0, description="settling: error stays inside this")
    tracking_start_s: float = Field(
        0.0, ge=0, le=MAX_DURATION_S, description="tracking RMSE window start"
    )
    mass_kg: float = Field(1.5, ge=0.01, description="kg, 10 g at least")
    frame: Literal["x", "+"] = Field("x", description="rigid body: rotor layout")
    el_pd: dict[str, Any] = Field(default_factory=dict, description="PdController overrides")
    el_nested: dict[str, Any] = Field(
        default_factory=dict, description="NestedSaturationController overrides"
    )
    pid_gains: dict[str, Any] = Field(
        default_factory=dict, description="CascadedPidGains overrides"
    )

    @model_validator(mode="after")
    def _fits(self) -> Self:
        el = self.vehicle == "euler_lagrange"
        if el != (self.controller in ("pd", "nested_saturation")):
            raise ValueError(
                "controller: pd and nested_saturation fly the euler_lagrange vehicle; "
                "cascaded_pid, takeoff_forward and waypoint_follower the rigid_body"
            )
        if self.log_rate_hz > 1.0 / self.dt_s:
            raise ValueError(
                f"log_rate_hz ({self.log_rate_hz:g} Hz) is faster than the simulation step "
                f"(dt_s = {self.dt_s:g} s: at most {1.0 / self.dt_s:g} Hz)"
            )
        if self.log_rate_hz * self.duration_s < 2.0:
            raise ValueError(
                f"log_rate_hz ({self.log_rate_hz:g} Hz) logs fewer than 2 rows in duration_s "
                f"({self.duration_s:g} s)"
            )
        if self.duration_s / self.dt_s > MAX_SIM_STEPS:
            raise ValueError(
                f"duration_s / dt_s is {self.duration_s / self.dt_s:.3g} steps, more than "
                f"{MAX_SIM_STEPS:g}: raise dt_s or shorten duration_s"
            )
        for key, target in (
            ("el_pd", PdController),
            ("el_nested", NestedSaturationController),
            ("pid_gains", CascadedPidGains),
        ):
            names = [f.name for f in dataclasses.fields(target) if f.name != "mass_kg"]
            check_finite_mapping(getattr(self, key), key, names)
        if problem := self._vehicle_problem():
            raise ValueError(problem)
        return self

    def _vehicle_problem(self) -> str | None:
        """The vehicle and its controller's gains as run_flight builds them, with what they
        refuse named by this configuration's keys."""
        if self.vehicle == "rigid_body":
            params = RigidBodyParams(config=self.frame)
            lift_kg = params.max_thrust_n / (1.2 * params.gravity_m_s2)
            if self.mass_kg > lift_kg:
                return (
                    f"mass_kg ({self.mass_kg:g}) is more than the rotors can fly: at most "
                    f"{lift_kg:.3g} kg (1.2x the weight in thrust)"
                )
        key, target = {"pd": ("el_pd", PdController), "nested_saturation": ("el_nested", NestedSaturationController),
                       "cascaded_pid": ("pid_gains", CascadedPidGains)}.get(self.controller, ("pid_gains", CascadedPidGains))  # fmt: skip
        gains = dict(getattr(self, key))
        for f in dataclasses.fields(target):
            if (
                f.name in gains
                and isinstance(f.default, tuple)
                and not (
                    isinstance(gains[f.name], list | tuple) and len(gains[f.name]) == len(f.default)
                )
            ):
                return f"{key}.{f.name} must be a list of {len(f.default)} numbers, got {gains[f.name]!r}"  # fmt: skip
        if target is not CascadedPidGains:
            gains["mass_kg"] = self.mass_kg
        try:
            target(**gains)
        except (ControlError, TypeError, ValueError) as exc:
            return f"{key}: {exc}"
        return None


def _ring(kind: str, **kw: Any) -> dict[str, Any]:
    return {"kind": kind, **kw}


_THESIS002_STAB = {
    "vehicle": "euler_lagrange",
    "trajectory": _ring("hover", position_m=(0.0, 0.0, 5.0)),
    "initial": {"position_m": (1.0, 2.0, 2.0), "euler_rad": (0.0, 0.0, 0.5)},
    "duration_s": 20.0,
}
_THESIS002_TRACK = {
    "vehicle": "euler_lagrange",
    "trajectory": _ring(
        "sigmoid",
        position_m=(0.0, 0.0, 5.0),
        amplitude_m=(20.0, 20.0, 0.0),
        t_mid_s=15.0,
        duration_s=10.0,
    ),
    "initial": {"position_m": (10.0, 10.0, 0.0), "euler_rad": (0.0, 0.0, 0.5)},
    "duration_s": 40.0,
    "tracking_start_s": 10.0,
}
#: Built-in scenarios: thesis 002's four simulations, the circle with and without gusts, and
#: thesis 003's take-off and obstacle experiments.
BUILTIN: dict[str, dict[str, Any]] = {
    "thesis002_pd_stabilization": {**_THESIS002_STAB, "controller": "pd"},
    "thesis002_nested_stabilization": {**_THESIS002_STAB, "controller": "nested_saturation"},
    "thesis002_pd_tracking": {**_THESIS002_TRACK, "controller": "pd"},
    "thesis002_nested_tracking": {**_THESIS002_TRACK, "controller": "nested_saturation"},
    "circle": {"duration_s": 30.0, "tracking_start_s": 8.0},
    "circle_gusts": {
        "duration_s": 30.0,
        "tracking_start_s": 8.0,
        "wind": {"gust_sigma_m_s": 2.0, "gust_tau_s": 2.0},
    },
    "thesis003_takeoff": {
        "controller": "takeoff_forward",
        "initial": {"position_m": (0.0, 0.0, 0.0)},
        "trajectory": _ring("hover", position_m=(5.0, 0.0, 5.0)),
        "duration_s": 25.0,
    },
    "thesis003_obstacle": {
        "controller": "waypoint_follower",
        "initial": {"position_m": (0.0, 0.0, 0.0)},
        "trajectory": _ring(
            "waypoints", points_m=[(0.0, 0.0, 2.0), (2.0, 0.0, 2.0), (6.0, 0.0, 2.0)]
        ),
        "world": [{"name": "house", "min_m": (3.5, -2.0, 0.0), "max_m": (5.5, 2.0, 3.0)}],
        "duration_s": 30.0,
    },
}

#: What each built-in scenario shows (``quadnav sim --list`` and ``--help``).
BUILTIN_DESCRIPTIONS: dict[str, str] = {
    "thesis002_pd_stabilization": "thesis 002's PD laws on its Euler-Lagrange model: settle on "
    "(0, 0, 5) from (1, 2, 2, psi 0.5)",
    "thesis002_nested_stabilization": "the same with thesis 002's nested saturations",
    "thesis002_pd_tracking": "thesis 002's PD laws on its 20 m sigmoids",
    "thesis002_nested_tracking": "nested saturations on the sigmoids",
    "circle": "rigid body with the cascaded PID, 2 m radius at 1 m/s",
    "circle_gusts": "the circle in 2 m/s gusts",
    "thesis003_takeoff": "thesis 003's take-off P controller, then forward to (5, 0, 5)",
    "thesis003_obstacle": "thesis 003's PID waypoint follower with a laser scan: sees the house, "
    "retreats",
}


def builtin_config(name: str) -> dict[str, Any]:
    if name not in BUILTIN:
        raise ExperimentError(f"no built-in scenario {name!r}; choose from {', '.join(BUILTIN)}")
    return {"name": name, **BUILTIN[name]}


@dataclass(frozen=True, slots=True, kw_only=True)
class FlightRun:
    """Logged flight (rows at ``log_rate_hz``): state, reference, controls, events."""

    config: FlightConfig
    t_s: FloatArray
    p: FloatArray
    v: FloatArray
    euler_rpy: FloatArray  # roll, pitch, yaw (rad)
    rates: FloatArray
    ref_p: FloatArray
    thrust_n: FloatArray
    torque: FloatArray  # tau~ (rad/s^2) for the Euler-Lagrange model, N m for the rigid body
    rotor_rad_s: FloatArray  # (N, 4); NaN for the Euler-Lagrange model
    saturated: NDArray[np.bool_]
    obstacle_distance_m: FloatArray
    events: dict[str, Any]
    wall_time_s: float


def _trajectory(t: TrajectorySection) -> TrajectoryGenerator:
    if t.kind == "hover":
        return Hover(position_m=t.position_m)
    if t.kind == "sigmoid":
        return Sigmoid(
            start_m=t.position_m,
            amplitude_m=t.amplitude_m,
            t_mid_s=t.t_mid_s,
            duration_s=t.duration_s,
        )
    if t.kind == "circle":
        return Circle(
            center_m=(t.position_m[0] - t.radius_m, t.position_m[1], t.position_m[2]),
            radius_m=t.radius_m,
            speed_m_s=t.speed_m_s,
        )
    return Waypoints(points_m=list(t.points_m), speed_m_s=t.speed_m_s, hold_s=t.hold_s)


def run_flight(config: FlightConfig) -> FlightRun:
    """Fly the scenario on the true state and log it."""
    import time

    dt = config.dt_s
    n = round(config.duration_s / dt)
    every = max(1, round(1.0 / (config.log_rate_hz * dt)))
    t_all = np.arange(n + 1) * dt
    traj = _trajectory(config.trajectory)
    ref: Reference = traj.reference(t_all)
    world = World(boxes=tuple(Box(name=b.name, min_m=b.min_m, max_m=b.max_m) for b in config.world))
    rng = np.random.default_rng(config.seed)
    rows = list(range(0, n + 1, every))
    N = len(rows)
    log = {k: np.full((N, 3), np.nan) for k in ("p", "v", "euler", "rates", "torque")}
    thrust = np.full(N, np.nan)
    rotors = np.full((N, 4), np.nan)
    sat = np.zeros(N, dtype=bool)
    events: dict[str, Any] = {}
    ic = config.initial
    wall0 = time.perf_counter()
    try:
        if config.vehicle == "euler_lagrange":
            s0 = np.zeros(12)
            s0[0:3] = ic.position_m
            s0[3:6] = ic.euler_rad
            el = EulerLagrangeQuadrotor(EulerLagrangeParams(mass_kg=config.mass_kg), s0=s0, dt_s=dt)
            ctrl: PdController | NestedSaturationController
            if config.controller == "pd":
                ctrl = PdController(mass_kg=config.mass_kg, **config.el_pd)
                level = math.inf
            else:
                ctrl = NestedSaturationController(mass_kg=config.mass_kg, **config.el_nested)
                level = ctrl.levels_rad_s2[0]
            r = 0
            for i in range(n + 1):
                row = RefRow(
                    ref.p[i],
                    ref.v[i],
                    ref.a[i],
                    ref.j[i],
                    float(ref.yaw[i]),
                    None if ref.snap is None else ref.snap[i],
                )
                u, tau = ctrl(el.s, row)
                if r < N and rows[r] == i:
                    s = el.s
                    log["p"][r], log["v"][r], log["rates"][r] = s[0:3], s[6:9], s[9:12]
                    log["euler"][r] = s[3:6]
                    thrust[r], log["torque"][r] = u, tau
                    sat[r] = bool(np.any(np.abs(tau[0:2]) >= level - 1e-9))
                    r += 1
                if i < n:
                    el.step(u, tau)
        else:
            params = RigidBodyParams(mass_kg=config.mass_kg, config=config.frame)
            wind = Wind(
                mean_m_s=config.wind.mean_m_s,
                gust_sigma_m_s=config.wind.gust_sigma_m_s,
                gust_tau_s=config.wind.gust_tau_s,
                rng=rng,
            )
            rb = RigidBodyQuadrotor(
                params,
                dt_s=dt,
                p0=ic.position_m,
                yaw0_rad=ic.euler_rad[2],
                hovering=ic.hovering,
                wind=wind,
            )
            pid = CascadedPid(params, CascadedPidGains(**config.pid_gains), dt_s=dt)
            scanner = LaserScanner()
            takeoff = (
                TakeoffForward(height_m=ref.p[0, 2], forward_m=float(ref.p[0, 0]))
                if config.controller == "takeoff_forward"
                else None
            )
            follower = (
                ObstacleAwareWaypointFollower(waypoints_m=list(config.trajectory.points_m), dt_s=dt)
                if config.controller == "waypoint_follower"
                else None
            )
            scan = None
            scan_every = max(1, round(0.025 / dt))  # 40 Hz laser
            r = 0
            for i in range(n + 1):
                state = rb.state()
                if follower is not None:
                    if i % scan_every == 0:
                        yaw = float(Rotation.from_quat(state.q_W_B_xyzw).as_euler("ZYX")[0])
                        scan = scanner.scan(world, state.p_W_B, yaw, state.t_ns, rng)
                    sp = follower(state, scan)
                elif takeoff is not None:
                    sp = takeoff(state)
                else:
                    sp = Setpoint(p=ref.p[i], v=ref.v[i], a=ref.a[i], yaw_rad=float(ref.yaw[i]))
                cmd = pid(state, sp)
                if r < N and rows[r] == i:
                    s = rb.s
                    log["p"][r], log["v"][r], log["rates"][r] = s[0:3], s[3:6], s[10:13]
                    log["euler"][r] = Rotation.from_quat(s[6:10]).as_euler("ZYX")[::-1]
                    thrust[r], log["torque"][r] = pid.last_thrust_n, pid.last_torque_nm
                    rotors[r] = s[13:17]
                    sat[r] = pid.saturated or bool(np.any(cmd >= params.omega_max_rad_s - 1e-9))
                    r += 1
                if i < n:
                    rb.step(cmd)
            if follower is not None:
                st = follower.status
                events = {
                    "route_unsafe": st.route_unsafe,
                    "obstacle_detected_at_s": None
                    if st.detected_at_ns is None
                    else st.detected_at_ns * 1e-9,
                    "retreated_to_waypoint": st.target_index + 1 if st.retreating else None,
                    "last_waypoint_reached": st.last_reached + 1,
                    "finished": st.done,
                }
            if takeoff is not None:
                events = {"phase": takeoff.phase}
    except (SimError, ControlError) as exc:
        raise ExperimentError(f"scenario {config.name!r}: {exc}") from None
    wall = time.perf_counter() - wall0
    ref_rows = ref.p[rows]
    if config.controller in ("takeoff_forward", "waypoint_follower"):
        ref_rows = np.full_like(ref_rows, np.nan)  # these controllers have no time reference
    return FlightRun(
        config=config,
        t_s=np.asarray(t_all[rows], dtype=np.float64),
        p=log["p"],
        v=log["v"],
        euler_rpy=log["euler"],
        rates=log["rates"],
        ref_p=ref_rows,
        thrust_n=thrust,
        torque=log["torque"],
        rotor_rad_s=rotors,
        saturated=sat,
        obstacle_distance_m=world.min_distance_m(log["p"]),
        events=events,
        wall_time_s=wall,
    )
