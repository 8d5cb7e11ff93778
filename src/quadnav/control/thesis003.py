"""Thesis 003's flight controllers, which command velocities (``/cmd_vel``) to a vehicle
whose own loops track them (here the cascaded PID's velocity mode).

* :class:`TakeoffForward` (section 6.3): proportional climb to a height, then a proportional
  move forward along x.
* :class:`ObstacleAwareWaypointFollower` (section 6.5): a decoupled PID per axis towards each
  waypoint in turn; when a laser ray within +-45 degrees of the heading sees something closer
  than 1 m, it goes back to the last waypoint it reached and reports the route as unsafe.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from quadnav.control.cascaded_pid import Setpoint
from quadnav.errors import ControlError
from quadnav.messages import RangeScan, VehicleState

__all__ = ["FollowerStatus", "ObstacleAwareWaypointFollower", "TakeoffForward"]

FloatArray = NDArray[np.float64]


@dataclass(slots=True)
class TakeoffForward:
    """Climb to ``height_m`` with ``vz = kp (z_ref - z)``, then move ``forward_m`` along x."""

    height_m: float = 5.0
    forward_m: float = 5.0
    kp: float = 0.8
    tolerance_m: float = 0.05
    max_speed_m_s: float = 1.0
    phase: Literal["climb", "forward", "done"] = "climb"
    x_ref_m: float = 0.0

    def __post_init__(self) -> None:
        if not (self.kp > 0 and self.tolerance_m > 0 and self.max_speed_m_s > 0):
            raise ControlError("TakeoffForward needs kp, tolerance_m and max_speed_m_s > 0")

    def __call__(self, state: VehicleState) -> Setpoint:
        p = state.p_W_B
        v = np.zeros(3)
        if self.phase == "climb":
            v[2] = self.kp * (self.height_m - p[2])
            if abs(self.height_m - p[2]) < self.tolerance_m:
                self.phase = "forward"
                self.x_ref_m = float(p[0]) + self.forward_m
        if self.phase in ("forward", "done"):
            v[0] = self.kp * (self.x_ref_m - p[0])
            v[2] = self.kp * (self.height_m - p[2])
            if abs(self.x_ref_m - p[0]) < self.tolerance_m:
                self.phase = "done"
        return Setpoint(v=np.clip(v, -self.max_speed_m_s, self.max_speed_m_s), yaw_rad=0.0)


@dataclass(slots=True)
class FollowerStatus:
    target_index: int = 0
    last_reached: int = -1
    retreating: bool = False
    route_unsafe: bool = False
    detected_at_ns: int | None = None
    done: bool = False


@dataclass(slots=True)
class ObstacleAwareWaypointFollower:
    """Decoupled PID (x, y, z, yaw) to each waypoint; retreat on an obstacle ahead."""

    waypoints_m: list[tuple[float, float, float]]
    kp: tuple[float, float, float] = (0.8, 0.8, 1.0)
    ki: tuple[float, float, float] = (0.05, 0.05, 0.05)
    kd: tuple[float, float, float] = (0.1, 0.1, 0.1)
    kp_yaw: float = 1.5
    max_speed_m_s: float = 0.8
    reach_radius_m: float = 0.15
    obstacle_range_m: float = 1.0
    sector_half_angle_rad: float = math.pi / 4
    dt_s: float = 0.001
    status: FollowerStatus = field(default_factory=FollowerStatus)
    _integ: FloatArray = field(default_factory=lambda: np.zeros(3))
    _prev_err: FloatArray | None = None
    _yaw_sp: float = 0.0

    def __post_init__(self) -> None:
        if len(self.waypoints_m) < 1:
            raise ControlError("the waypoint follower needs at least one waypoint")
        if any(k < 0 for k in (*self.kp, *self.ki, *self.kd)) or not all(k > 0 for k in self.kp):
            raise ControlError("waypoint follower gains must be >= 0 (kp > 0)")

    def obstacle_ahead(self, scan: RangeScan) -> bool:
        """A ray within the sector around the heading (body +x) closer than the threshold."""
        ang = np.angle(np.exp(1j * scan.angles_rad))
        ahead = np.abs(ang) <= self.sector_half_angle_rad
        return bool(np.any(scan.ranges_m[ahead] < self.obstacle_range_m))

    def __call__(self, state: VehicleState, scan: RangeScan | None) -> Setpoint:
        st = self.status
        p = state.p_W_B
        if scan is not None and not st.retreating and not st.done and self.obstacle_ahead(scan):
            # Unsafe route: go back to the last waypoint reached (or the first one).
            st.retreating = True
            st.route_unsafe = True
            st.detected_at_ns = state.t_ns
            st.target_index = max(st.last_reached, 0)
            self._integ[:] = 0.0
            self._prev_err = None
        target = np.asarray(self.waypoints_m[st.target_index], dtype=np.float64)
        err = target - p
        if np.linalg.norm(err) < self.reach_radius_m:
            if st.retreating:
                st.done = True
            else:
                st.last_reached = st.target_index
                if st.target_index < len(self.waypoints_m) - 1:
                    st.target_index += 1
                    self._integ[:] = 0.0
                    self._prev_err = None
                else:
                    st.done = True
            target = np.asarray(self.waypoints_m[st.target_index], dtype=np.float64)
            err = target - p
        d_err = np.zeros(3) if self._prev_err is None else (err - self._prev_err) / self.dt_s
        self._prev_err = err
        self._integ = np.clip(self._integ + err * self.dt_s, -2.0, 2.0)
        v = (
            np.asarray(self.kp) * err
            + np.asarray(self.ki) * self._integ
            + np.asarray(self.kd) * d_err
        )
        speed = float(np.linalg.norm(v))
        if speed > self.max_speed_m_s:
            v *= self.max_speed_m_s / speed
        # Face the direction of travel on horizontal legs (the laser looks where we go); hold
        # the heading while climbing, descending or retreating.
        if not st.retreating and math.hypot(err[0], err[1]) > 0.3:
            self._yaw_sp = math.atan2(err[1], err[0])
        return Setpoint(v=v, yaw_rad=self._yaw_sp)
