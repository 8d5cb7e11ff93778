"""Closed-loop flights on the true state: the thesis-002 Euler-Lagrange model with its PD or
nested-saturation controller, or the rigid-body model with the cascaded PID fed by a
trajectory, thesis 003's take-off controller or its obstacle-aware waypoint follower.

Every controller is a :class:`~quadnav.control.base.Controller`: the loop hands it the true
state as a perfect :class:`~quadnav.messages.StateEstimate` (:func:`truth_estimate`) and the
trajectory's setpoint, and applies the :class:`~quadnav.control.base.Command`.

:class:`FlightConfig` is the YAML scenario (every field has a default); :data:`BUILTIN`
holds the built-in scenarios; :func:`run_flight` returns arrays.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Literal, Self

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, model_validator
from scipy.spatial.transform import Rotation

from quadnav.config_model import MAX_DURATION_S, MAX_RATE_HZ, MAX_SIM_STEPS, ConfigModel
from quadnav.control.base import (
    Command,
    Controller,
    Setpoint,
    body_rates_from_euler_rates,
    quat_xyzw_from_euler_rpy,
    truth_estimate,
)
from quadnav.control.cascaded_pid import CascadedPid, CascadedPidGains
from quadnav.control.thesis002 import PD_GAIN_SETS, NestedSaturationController, PdController
from quadnav.control.thesis003 import (
    FollowerStatus,
    ObstacleAwareWaypointFollower,
    OuterLoopController,
    TakeoffForward,
    Thesis003Gains,
)
from quadnav.control.trajectories import (
    Circle,
    Hover,
    Reference,
    Sigmoid,
    TrajectoryGenerator,
    Waypoints,
)
from quadnav.errors import ControlError, ExperimentError, IoError, SimError
from quadnav.experiments.slam_flight import SerialLinkSection, SerialPositionLoop, SerialRecord
from quadnav.geometry.rotations import Pose
from quadnav.messages import StateEstimate
from quadnav.sim.euler_lagrange import EulerLagrangeParams, EulerLagrangeQuadrotor
from quadnav.sim.rigid_body import RigidBodyQuadrotor, Wind
from quadnav.sim.world import Box, LaserScanner, World
from quadnav.units import s_to_ns
from quadnav.vehicle import RigidBodyParams

__all__ = [
    "BUILTIN",
    "BUILTIN_DESCRIPTIONS",
    "FlightConfig",
    "FlightEvents",
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


class PdGainsSection(ConfigModel):
    """Overrides of the PD controller's gains (left out: the ``el_pd_gains`` set's value)."""

    kp_z: float | None = None
    kd_z: float | None = None
    kp_xy: float | None = None
    kd_xy: float | None = None
    kp_att: float | None = None
    kd_att: float | None = None
    kp_yaw: float | None = None
    kd_yaw: float | None = None
    max_tilt_rad: float | None = None


class NestedGainsSection(ConfigModel):
    """Overrides of the nested-saturation controller's gains and levels."""

    kp_z: float | None = None
    kd_z: float | None = None
    kp_yaw: float | None = None
    kd_yaw: float | None = None
    levels_rad_s2: tuple[float, float, float, float] | None = None


class PidGainsSection(ConfigModel):
    """Overrides of the cascaded PID's gains and limits."""

    kp_pos: Vec3 | None = None
    kp_vel: Vec3 | None = None
    ki_vel: Vec3 | None = None
    kd_vel: Vec3 | None = None
    kp_att: Vec3 | None = None
    kp_rate: Vec3 | None = None
    ki_rate: Vec3 | None = None
    kd_rate: Vec3 | None = None
    max_vel_m_s: float | None = None
    max_tilt_rad: float | None = None
    max_rate_rad_s: float | None = None
    vel_integral_limit_m_s2: float | None = None
    rate_integral_limit: float | None = None
    min_thrust_fraction: float | None = None
    max_thrust_fraction: float | None = None


_T003 = Thesis003Gains()  # the thesis's values


class Thesis003Section(ConfigModel):
    """Thesis 003's gains and limits (sections 6.3 and 6.5): the defaults are the thesis's.
    ``kd_*`` act on the change of the error over one tick, ``ki_*`` on its sum over the ticks."""

    rate_hz: float = Field(_T003.rate_hz, gt=0, le=1000.0, description="the /cmd_vel rate")
    takeoff_kp: float = Field(_T003.takeoff_kp, gt=0, description="take-off P: (m/s) per m")
    takeoff_stop_m: float = Field(
        _T003.takeoff_stop_m, gt=0, description="take-off: a leg ends within this"
    )
    kp_lin: float = Field(_T003.kp_lin, gt=0)
    kd_lin: float = Field(_T003.kd_lin, ge=0)
    ki_lin: float = Field(_T003.ki_lin, ge=0)
    kp_ang: float = Field(_T003.kp_ang, gt=0)
    kd_ang: float = Field(_T003.kd_ang, ge=0)
    ki_ang: float = Field(_T003.ki_ang, ge=0)
    reach_radius_m: float = Field(
        _T003.reach_radius_m, gt=0, description="a waypoint is reached within this"
    )
    obstacle_min_m: float = Field(
        _T003.obstacle_min_m, ge=0, description="laser hits nearer are ignored"
    )
    obstacle_max_m: float = Field(
        _T003.obstacle_max_m, gt=0, description="an obstacle is nearer than this"
    )
    sector_half_angle_deg: float = Field(math.degrees(_T003.sector_half_angle_rad), gt=0, le=180.0)

    def gains(self) -> Thesis003Gains:
        values = self.model_dump()
        half = math.radians(values.pop("sector_half_angle_deg"))
        return Thesis003Gains(**values, sector_half_angle_rad=half)


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
    el_pd_gains: Literal["default", "table_5_1"] = Field(
        "default", description="PD gain set: table_5_1 is thesis 002's attitude gains"
    )
    el_pd: PdGainsSection = PdGainsSection()
    el_nested: NestedGainsSection = NestedGainsSection()
    pid_gains: PidGainsSection = PidGainsSection()
    thesis003: Thesis003Section = Thesis003Section()
    position_source: Literal["truth", "serial_truth", "slam"] = Field(
        "truth",
        description="euler_lagrange: the position the controller flies on, the true state's or "
        "thesis 002's X<cm>Y<cm>Z<cm>F frames over a serial link (a pseudo-terminal pair) "
        "carrying the true position or the stereo SLAM's",
    )
    link: SerialLinkSection = SerialLinkSection()

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
        if self.position_source != "truth" and self.vehicle != "euler_lagrange":
            raise ValueError(
                f"position_source {self.position_source}: only the euler_lagrange vehicle flies "
                "on the serial frames"
            )
        if self.duration_s / self.dt_s > MAX_SIM_STEPS:
            raise ValueError(
                f"duration_s / dt_s is {self.duration_s / self.dt_s:.3g} steps, more than "
                f"{MAX_SIM_STEPS:g}: raise dt_s or shorten duration_s"
            )
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
        key = {"pd": "el_pd", "nested_saturation": "el_nested"}.get(self.controller, "pid_gains")
        try:
            if self.vehicle == "euler_lagrange":
                _el_controller(self)
            else:
                _pid_gains(self)
            if self.controller in ("takeoff_forward", "waypoint_follower"):
                key = "thesis003"
                self.thesis003.gains()
        except (ControlError, TypeError, ValueError) as exc:
            return f"{key}: {exc}"
        return None


def _el_controller(config: FlightConfig) -> PdController | NestedSaturationController:
    """The configured controller of the Euler-Lagrange model."""
    if config.controller == "pd":
        overrides = config.el_pd.model_dump(exclude_none=True)
        gains = {**PD_GAIN_SETS[config.el_pd_gains], **overrides}
        return PdController(**gains, mass_kg=config.mass_kg)
    return NestedSaturationController(
        **config.el_nested.model_dump(exclude_none=True), mass_kg=config.mass_kg
    )


def _pid_gains(config: FlightConfig) -> CascadedPidGains:
    return CascadedPidGains(**config.pid_gains.model_dump(exclude_none=True))


def _ring(kind: str, **kw: object) -> dict[str, object]:
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
_SQUARE = [(0.0, 0.0, 1.2), (1.2, 0.0, 1.2), (1.2, 1.2, 1.2), (0.0, 1.2, 1.2), (0.0, 0.0, 1.2)]
#: Thesis 002's flights on its SLAM (sections 5.7-5.10), on the stereo SLAM's position sent as
#: serial frames at 10 Hz: the hover at 1.2 m (switched on 0.4 m low, 0.28 m off sideways and a
#: little tilted; its error taken after 6 s), the 1 m sigmoids in x and y, the 1.2 m x 1.2 m
#: square at 1.2 m (0.5 m/s legs). Short flights: the SLAM on rendered images runs at a few
#: frames a second.
_SLAM_FLIGHTS: dict[str, dict[str, object]] = {
    "hover": {
        "trajectory": _ring("hover", position_m=(0.0, 0.0, 1.2)),
        "initial": {"position_m": (0.2, -0.2, 0.8), "euler_rad": (0.03, -0.03, 0.0)},
        "duration_s": 12.0,
        "tracking_start_s": 6.0,
    },
    "sigmoid": {
        "trajectory": _ring(
            "sigmoid",
            position_m=(0.0, 0.0, 1.2),
            amplitude_m=(1.0, 1.0, 0.0),
            t_mid_s=7.0,
            duration_s=6.0,
        ),
        "duration_s": 14.0,
    },
    "square": {
        "trajectory": _ring("waypoints", points_m=_SQUARE, speed_m_s=0.5, hold_s=0.5),
        "duration_s": 15.0,
    },
}
_SLAM_CONTROLLERS = {"pd": {"controller": "pd", "el_pd_gains": "table_5_1"},
                     "nested": {"controller": "nested_saturation"}}  # fmt: skip
_THESIS002_SLAM = {
    f"thesis002_slam_{flight}_{c}": {
        "vehicle": "euler_lagrange",
        "initial": {"position_m": (0.0, 0.0, 1.2)},  # (the hover's own start replaces it)
        "position_source": "slam",
        **spec,
        **ctrl,
    }
    for flight, spec in _SLAM_FLIGHTS.items()
    for c, ctrl in _SLAM_CONTROLLERS.items()
}
#: Built-in scenarios: thesis 002's four simulations and its six flights on the SLAM, the circle
#: with and without gusts, and thesis 003's take-off and obstacle experiments.
BUILTIN: dict[str, dict[str, object]] = {
    "thesis002_pd_stabilization": {**_THESIS002_STAB, "controller": "pd"},
    "thesis002_nested_stabilization": {**_THESIS002_STAB, "controller": "nested_saturation"},
    "thesis002_pd_tracking": {**_THESIS002_TRACK, "controller": "pd"},
    "thesis002_nested_tracking": {**_THESIS002_TRACK, "controller": "nested_saturation"},
    **_THESIS002_SLAM,
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
    "thesis003_waypoints": {
        "controller": "waypoint_follower",
        "initial": {"position_m": (0.0, 0.0, 0.0)},
        "trajectory": _ring(
            "waypoints", points_m=[(0.0, 0.0, 3.0), (2.0, 2.0, 3.0), (4.0, 5.0, 3.0)]
        ),
        "duration_s": 40.0,
    },
}

#: What each built-in scenario shows (``quadnav sim --list`` and ``--help``).
BUILTIN_DESCRIPTIONS: dict[str, str] = {
    "thesis002_pd_stabilization": "thesis 002's PD laws on its Euler-Lagrange model: settle on "
    "(0, 0, 5) from (1, 2, 2, psi 0.5)",
    "thesis002_nested_stabilization": "the same with thesis 002's nested saturations",
    "thesis002_pd_tracking": "thesis 002's PD laws on its 20 m sigmoids",
    "thesis002_nested_tracking": "nested saturations on the sigmoids",
    **{
        f"thesis002_slam_{f}_{c}": f"thesis 002's {what} with {law}, on the stereo SLAM's "
        "position sent as X<cm>Y<cm>Z<cm>F frames at 10 Hz over a pseudo-terminal (ZED in a room)"
        for f, what in (
            ("hover", "hover at 1.2 m (5.9)"),
            ("sigmoid", "1 m sigmoids (5.10)"),
            ("square", "1.2 m x 1.2 m square (5.7)"),
        )
        for c, law in (("pd", "the PD laws (Table 5.1 gains)"), ("nested", "nested saturations"))
    },
    "circle": "rigid body with the cascaded PID, 2 m radius at 1 m/s",
    "circle_gusts": "the circle in 2 m/s gusts",
    "thesis003_takeoff": "thesis 003's take-off P controller, then forward to (5, 0, 5)",
    "thesis003_obstacle": "thesis 003's PID waypoint follower with a laser scan: sees the house, "
    "retreats (figures 6.23-6.24)",
    "thesis003_waypoints": "thesis 003's PID waypoint follower in free flight through (0, 0, 3), "
    "(2, 2, 3), (4, 5, 3) (figure 6.22)",
}


def builtin_config(name: str) -> dict[str, object]:
    if name not in BUILTIN:
        raise ExperimentError(f"no built-in scenario {name!r}; choose from {', '.join(BUILTIN)}")
    return {"name": name, **BUILTIN[name]}


@dataclass(frozen=True, slots=True, kw_only=True)
class FlightEvents:
    """What thesis 003's controllers did (None where the controller has no such event).
    Waypoints are numbered from 1, as the thesis does."""

    takeoff_phase: str | None = None
    route_unsafe: bool | None = None
    obstacle_detected_at_s: float | None = None
    retreated_to_waypoint: int | None = None
    last_waypoint_reached: int | None = None
    waypoints_reached_at_s: tuple[float, ...] = ()
    finished: bool | None = None

    @classmethod
    def of_follower(cls, st: FollowerStatus) -> FlightEvents:
        return cls(
            route_unsafe=st.route_unsafe,
            obstacle_detected_at_s=None if st.detected_at_ns is None else st.detected_at_ns * 1e-9,
            retreated_to_waypoint=st.target_index + 1 if st.retreating else None,
            last_waypoint_reached=st.last_reached + 1,
            waypoints_reached_at_s=tuple(t * 1e-9 for t in st.reached_at_ns),
            finished=st.done,
        )

    def items(self) -> list[tuple[str, object]]:
        """The events that happened, by name (for tables, reports and metrics.json)."""
        return [
            (name, getattr(self, name))
            for name in self.__dataclass_fields__
            if getattr(self, name) not in (None, ())
        ]


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
    events: FlightEvents
    wall_time_s: float
    #: with position_source other than truth: what went over the serial link
    link: SerialRecord | None = None


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


class _FlightLog:
    """The rows of one flight, every ``every``-th step."""

    def __init__(self, n_steps: int, every: int) -> None:
        self.rows = list(range(0, n_steps + 1, every))
        n = len(self.rows)
        self.p, self.v, self.euler, self.rates, self.torque = (
            np.full((n, 3), np.nan) for _ in range(5)
        )
        self.thrust = np.full(n, np.nan)
        self.rotors = np.full((n, 4), np.nan)
        self.sat = np.zeros(n, dtype=bool)
        self._r = 0

    def due(self, i: int) -> bool:
        return self._r < len(self.rows) and self.rows[self._r] == i

    def record(
        self,
        s: FloatArray,
        euler: FloatArray,
        cmd: Command,
        *,
        saturated: bool,
        rotor_rad_s: FloatArray | None = None,
    ) -> None:
        """``s`` holds position, velocity and rates at 0:3, 3:6 and 6:9; the rotors' speeds."""
        r = self._r
        self.p[r], self.v[r], self.rates[r], self.euler[r] = s[0:3], s[3:6], s[6:9], euler
        self.thrust[r], self.torque[r] = cmd.thrust_n, cmd.torque()
        if rotor_rad_s is not None:
            self.rotors[r] = rotor_rad_s
        self.sat[r] = saturated
        self._r += 1


def _setpoint(ref: Reference, i: int) -> Setpoint:
    return Setpoint(
        p=ref.p[i],
        v=ref.v[i],
        a=ref.a[i],
        j=ref.j[i],
        snap=None if ref.snap is None else ref.snap[i],
        yaw_rad=float(ref.yaw[i]),
    )


def _el_estimate(t_ns: int, s: FloatArray) -> StateEstimate:
    """The Euler-Lagrange model's state as a perfect estimate (attitude and body rate from
    its Euler angles and their rates)."""
    roll, pitch, yaw = s[3:6].tolist()
    w_B = np.array(body_rates_from_euler_rates(roll, pitch, s[9:12]))
    q = quat_xyzw_from_euler_rpy(roll, pitch, yaw)
    return StateEstimate(
        t_ns=t_ns, p_W_B=s[0:3], v_W_B=s[6:9], q_W_B_xyzw=q, x=s, names=EL_STATE_NAMES, w_B=w_B
    )


#: The Euler-Lagrange model's state layout.
EL_STATE_NAMES = ("x", "y", "z", "phi", "theta", "psi", "vx", "vy", "vz", "dphi", "dtheta", "dpsi")


def _serial_loop(config: FlightConfig, ref: Reference) -> SerialPositionLoop | None:
    """The companion computer and the serial link the position comes over, if it does."""
    src = config.position_source
    if src == "truth":
        return None
    ic = config.initial
    start = Pose.from_quat_xyzw(quat_xyzw_from_euler_rpy(*ic.euler_rad), ic.position_m)
    path = np.concatenate([np.asarray([ic.position_m]), ref.p[:: max(1, len(ref.p) // 200)]])
    try:
        return SerialPositionLoop(config.link, src, start=start, path_W=path, seed=config.seed)
    except (OSError, IoError) as exc:
        raise ExperimentError(f"position_source {src}: the serial link: {exc}") from None


def _fly_euler_lagrange(
    config: FlightConfig, ref: Reference, log: _FlightLog
) -> tuple[FlightEvents, SerialRecord | None]:
    ic, dt, n = config.initial, config.dt_s, len(ref.p) - 1
    s0 = np.zeros(12)
    s0[0:3] = ic.position_m
    s0[3:6] = ic.euler_rad
    el = EulerLagrangeQuadrotor(EulerLagrangeParams(mass_kg=config.mass_kg), s0=s0, dt_s=dt)
    ctrl = _el_controller(config)
    level = ctrl.levels_rad_s2[0] if isinstance(ctrl, NestedSaturationController) else math.inf
    dt_ns = s_to_ns(dt)
    serial = _serial_loop(config, ref)
    try:
        for i in range(n + 1):
            est = _el_estimate(i * dt_ns, el.s)
            if serial is not None:
                assert est.w_B is not None
                est = serial.estimate(est, el.vehicle_state(i * dt_ns, est.q_W_B_xyzw, est.w_B))
            cmd = ctrl(i * dt_ns, est, _setpoint(ref, i))
            if log.due(i):
                s = el.s
                tau = cmd.torque()
                sat = bool(np.any(np.abs(tau[0:2]) >= level - 1e-9))
                log.record(np.concatenate([s[0:3], s[6:9], s[9:12]]), s[3:6], cmd, saturated=sat)
            if i < n:
                el.step(cmd.thrust_n, cmd.torque())
    finally:
        record = None if serial is None else serial.close()
    return FlightEvents(), record


def _rigid_body_controller(
    config: FlightConfig, pid: CascadedPid
) -> tuple[Controller, TakeoffForward | ObstacleAwareWaypointFollower | None]:
    """The controller the rigid body flies, and thesis 003's setpoint source if it is one."""
    gains = config.thesis003.gains()
    outer: TakeoffForward | ObstacleAwareWaypointFollower
    if config.controller == "takeoff_forward":
        outer = TakeoffForward(gains=gains)
    elif config.controller == "waypoint_follower":
        outer = ObstacleAwareWaypointFollower(
            waypoints_m=list(config.trajectory.points_m), gains=gains
        )
    else:
        return pid, None
    return OuterLoopController(outer, pid, rate_hz=gains.rate_hz), outer


def _fly_rigid_body(
    config: FlightConfig, ref: Reference, log: _FlightLog, world: World
) -> FlightEvents:
    ic, dt, n = config.initial, config.dt_s, len(ref.p) - 1
    rng = np.random.default_rng(config.seed)
    params = RigidBodyParams(mass_kg=config.mass_kg, config=config.frame)
    w = config.wind
    wind = Wind(
        mean_m_s=w.mean_m_s, gust_sigma_m_s=w.gust_sigma_m_s, gust_tau_s=w.gust_tau_s, rng=rng
    )
    rb = RigidBodyQuadrotor(
        params, dt_s=dt, p0=ic.position_m, yaw0_rad=ic.euler_rad[2], hovering=ic.hovering, wind=wind
    )
    ctrl, outer = _rigid_body_controller(config, CascadedPid(params, _pid_gains(config), dt_s=dt))
    follower = outer if isinstance(outer, ObstacleAwareWaypointFollower) else None
    scanner, scan_every = LaserScanner(), max(1, round(0.025 / dt))  # 40 Hz laser
    for i in range(n + 1):
        truth = rb.state()
        if follower is not None and i % scan_every == 0:
            yaw = float(Rotation.from_quat(truth.q_W_B_xyzw).as_euler("ZYX")[0])
            seen = follower.observe(scanner.scan(world, truth.p_W_B, yaw, truth.t_ns, rng))
            if seen and isinstance(ctrl, OuterLoopController):
                ctrl.interrupt()  # retreat at once, not at the next 10 Hz tick
        cmd = ctrl(truth.t_ns, truth_estimate(truth), _setpoint(ref, i))
        rotors = cmd.rotors()
        if log.due(i):
            s = rb.s
            euler = Rotation.from_quat(s[6:10]).as_euler("ZYX")[::-1]
            sat = cmd.saturated or bool(np.any(rotors >= params.omega_max_rad_s - 1e-9))
            state = np.concatenate([s[0:3], s[3:6], s[10:13]])
            log.record(state, euler, cmd, saturated=sat, rotor_rad_s=s[13:17])
        if i < n:
            rb.step(rotors)
    if follower is not None:
        return FlightEvents.of_follower(follower.status)
    if isinstance(outer, TakeoffForward):
        return FlightEvents(takeoff_phase=outer.phase)
    return FlightEvents()


def run_flight(config: FlightConfig) -> FlightRun:
    """Fly the scenario on the true state and log it."""
    dt = config.dt_s
    n = round(config.duration_s / dt)
    t_all = np.arange(n + 1) * dt
    ref: Reference = _trajectory(config.trajectory).reference(t_all)
    world = World(boxes=tuple(Box(name=b.name, min_m=b.min_m, max_m=b.max_m) for b in config.world))
    log = _FlightLog(n, max(1, round(1.0 / (config.log_rate_hz * dt))))
    wall0 = time.perf_counter()
    try:
        link = None
        if config.vehicle == "euler_lagrange":
            events, link = _fly_euler_lagrange(config, ref, log)
        else:
            events = _fly_rigid_body(config, ref, log, world)
    except (SimError, ControlError) as exc:
        raise ExperimentError(f"scenario {config.name!r}: {exc}") from None
    wall = time.perf_counter() - wall0
    ref_rows = ref.p[log.rows]
    if config.controller in ("takeoff_forward", "waypoint_follower"):
        ref_rows = np.full_like(ref_rows, np.nan)  # these controllers have no time reference
    return FlightRun(
        config=config,
        t_s=np.asarray(t_all[log.rows], dtype=np.float64),
        p=log.p,
        v=log.v,
        euler_rpy=log.euler,
        rates=log.rates,
        ref_p=ref_rows,
        thrust_n=log.thrust,
        torque=log.torque,
        rotor_rad_s=log.rotors,
        saturated=log.sat,
        obstacle_distance_m=world.min_distance_m(log.p),
        events=events,
        wall_time_s=wall,
        link=link,
    )
