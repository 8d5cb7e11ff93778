"""Thesis 003's flight controllers (sections 6.3 and 6.5, codes 8.3 and 8.4), which publish
velocity commands (``/cmd_vel``) at 10 Hz to a vehicle whose own loops track them.

Each is a :class:`~quadnav.control.base.SetpointSource`: they turn an estimate into a
velocity setpoint. :class:`OuterLoopController` runs one at its rate (sample and hold) over an
inner :class:`~quadnav.control.base.Controller` (the cascaded PID's velocity mode, as
hector_quadrotor's own controller tracks ``/cmd_vel``), which makes the pair a ``Controller``.

* :class:`TakeoffForward` (section 6.3, code 8.3): ``vz = kp (z_ref - z)`` until the height is
  within ``stop_m``, then ``vx = kp (x_ref - x)`` until x is within ``stop_m``; the target is the
  setpoint's position. Then it holds where it stopped (the thesis's node ends; the vehicle
  hovers). Unlike code 8.3, which leaves the last climb command in the message during the
  forward leg, the height is held with the same P while moving forward.
* :class:`ObstacleAwareWaypointFollower` (section 6.5, code 8.4): a discrete PID per axis on
  the position error and one on the heading towards the waypoint, each tick:
  ``v = kp e + kd (e - e_prev) + ki sum(e)`` (``kd`` and ``ki`` per tick, as the thesis's code
  has them), the yaw-rate command integrated into the yaw setpoint. A waypoint is reached within
  ``reach_radius_m`` (3-D). A laser ray within ``+-sector_half_angle`` of the heading that sees
  something between ``obstacle_min_m`` and ``obstacle_max_m`` marks the route unsafe: the vehicle
  goes back to the last waypoint it reached (the first one if none yet; the thesis goes to
  its origin then) by position control (the thesis calls
  hector_quadrotor's pose action) and stays there. The thesis checks for an obstacle at its
  10 Hz tick; :class:`OuterLoopController` can run the follower as soon as a scan shows one. After the last waypoint it holds position.
  Code 8.4 integrates ``|e|`` and applies the current sign; we integrate the signed error, the
  same while an axis approaches from one side, and the heading error is wrapped to +-pi.

The setpoint source's ``ref`` is the scenario's plan: the take-off's target; the waypoint
follower has its own list and ignores it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from quadnav.control.base import (
    Command,
    Controller,
    Setpoint,
    SetpointSource,
    euler_rpy_from_quat_xyzw,
)
from quadnav.errors import ControlError
from quadnav.messages import RangeScan, StateEstimate
from quadnav.units import s_to_ns

__all__ = [
    "FollowerStatus",
    "ObstacleAwareWaypointFollower",
    "OuterLoopController",
    "TakeoffForward",
    "Thesis003Gains",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class Thesis003Gains:
    """Thesis 003's gains and limits (sections 6.3 and 6.5; codes 8.3 and 8.4)."""

    rate_hz: float = 10.0
    takeoff_kp: float = 0.2  # (m/s) per m
    takeoff_stop_m: float = 0.8
    kp_lin: float = 0.2  # (m/s) per m
    kd_lin: float = 0.01  # (m/s) per m of change over one tick
    ki_lin: float = 0.004  # (m/s) per m summed over the ticks
    kp_ang: float = 3.4  # (rad/s) per rad
    kd_ang: float = 0.2
    ki_ang: float = 0.02
    reach_radius_m: float = 0.5
    obstacle_min_m: float = 0.1
    obstacle_max_m: float = 1.0
    sector_half_angle_rad: float = math.pi / 4

    def __post_init__(self) -> None:
        positive = ("rate_hz", "takeoff_kp", "takeoff_stop_m", "kp_lin", "kp_ang", "reach_radius_m")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ControlError(f"{name} must be > 0")
        for name in ("kd_lin", "ki_lin", "kd_ang", "ki_ang", "obstacle_min_m"):
            if getattr(self, name) < 0:
                raise ControlError(f"{name} must be >= 0")
        if not self.obstacle_min_m < self.obstacle_max_m:
            raise ControlError("obstacle_min_m must be below obstacle_max_m")
        if not 0 < self.sector_half_angle_rad <= math.pi:
            raise ControlError("sector_half_angle must lie in (0, 180] degrees")


class OuterLoopController:
    """A :class:`SetpointSource` at ``rate_hz`` (its setpoint held between ticks) over an inner
    :class:`Controller`; the due times accumulate, so 10 Hz stays 10 Hz on any step."""

    def __init__(self, outer: SetpointSource, inner: Controller, *, rate_hz: float) -> None:
        if not rate_hz > 0:
            raise ControlError(f"the outer loop's rate must be > 0 Hz, got {rate_hz}")
        self.outer = outer
        self.inner = inner
        self.period_ns = s_to_ns(1.0 / rate_hz)
        self.ticks = 0
        self._next_ns: int | None = None
        self._sp = Setpoint(v=np.zeros(3))
        self._interrupted = False

    def interrupt(self) -> None:
        """Run the outer loop at the next call, off its schedule (an obstacle was seen)."""
        self._interrupted = True

    def __call__(self, t_ns: int, est: StateEstimate, ref: Setpoint) -> Command:
        if self._interrupted:
            self._interrupted = False
            self._sp = self.outer(t_ns, est, ref)
        if self._next_ns is None or t_ns >= self._next_ns:
            self._sp = self.outer(t_ns, est, ref)
            self._next_ns = (t_ns if self._next_ns is None else self._next_ns) + self.period_ns
            self.ticks += 1
        return self.inner(t_ns, est, self._sp)


def _yaw(est: StateEstimate) -> float:
    return euler_rpy_from_quat_xyzw(est.q_W_B_xyzw)[2]


def _hold(p: FloatArray, yaw_rad: float) -> Setpoint:
    return Setpoint(p=p.copy(), v=np.zeros(3), yaw_rad=yaw_rad)


@dataclass(slots=True)
class TakeoffForward:
    """Climb to the setpoint's height, then move to its x, each until within ``stop_m``."""

    gains: Thesis003Gains = field(default_factory=Thesis003Gains)
    phase: Literal["climb", "forward", "done"] = "climb"
    _hold_sp: Setpoint | None = None

    def __call__(self, t_ns: int, est: StateEstimate, ref: Setpoint) -> Setpoint:
        if ref.p is None:
            raise ControlError("the take-off controller needs a target position in its setpoint")
        kp, stop = self.gains.takeoff_kp, self.gains.takeoff_stop_m
        p = est.p_W_B
        if self.phase == "climb" and abs(ref.p[2] - p[2]) < stop:
            self.phase = "forward"
        if self.phase == "forward" and abs(ref.p[0] - p[0]) < stop:
            self.phase = "done"
            self._hold_sp = _hold(p, ref.yaw_rad)
        if self._hold_sp is not None:
            return self._hold_sp
        v = np.zeros(3)
        v[2] = kp * (ref.p[2] - p[2])
        if self.phase == "forward":
            v[0] = kp * (ref.p[0] - p[0])
        return Setpoint(v=v, yaw_rad=ref.yaw_rad)


@dataclass(slots=True)
class FollowerStatus:
    target_index: int = 0
    last_reached: int = -1
    retreating: bool = False
    route_unsafe: bool = False
    detected_at_ns: int | None = None
    done: bool = False
    reached_at_ns: list[int] = field(default_factory=list)


@dataclass(slots=True)
class ObstacleAwareWaypointFollower:
    """Thesis 003's decoupled PID (x, y, z, yaw) to each waypoint; retreat on an obstacle."""

    waypoints_m: list[tuple[float, float, float]]
    gains: Thesis003Gains = field(default_factory=Thesis003Gains)
    status: FollowerStatus = field(default_factory=FollowerStatus)
    _seen_ns: int | None = None  # an obstacle seen since the last tick
    _integ: FloatArray = field(default_factory=lambda: np.zeros(3))
    _prev_err: FloatArray | None = None
    _yaw_integ: float = 0.0
    _prev_yaw_err: float | None = None
    _yaw_sp: float | None = None
    _hold_sp: Setpoint | None = None

    def __post_init__(self) -> None:
        if len(self.waypoints_m) < 1:
            raise ControlError("the waypoint follower needs at least one waypoint")

    def obstacle_ahead(self, scan: RangeScan) -> bool:
        """A ray within the sector around the heading (body +x) in the obstacle band."""
        g = self.gains
        ang = np.angle(np.exp(1j * scan.angles_rad))
        r = scan.ranges_m[np.abs(ang) < g.sector_half_angle_rad]
        return bool(np.any((r > g.obstacle_min_m) & (r < g.obstacle_max_m)))

    def observe(self, scan: RangeScan) -> bool:
        """A laser scan (at the scanner's rate); True when it shows an obstacle on a route not
        yet known unsafe (the caller may then run the follower at once: see
        :meth:`OuterLoopController.interrupt`)."""
        st = self.status
        if self._seen_ns is None and not (st.retreating or st.done) and self.obstacle_ahead(scan):
            self._seen_ns = scan.t_ns
            return True
        return False

    def __call__(self, t_ns: int, est: StateEstimate, ref: Setpoint) -> Setpoint:
        st = self.status
        if self._seen_ns is not None and not (st.retreating or st.done):
            st.retreating = st.route_unsafe = True
            st.detected_at_ns = self._seen_ns
            st.target_index = max(st.last_reached, 0)
            self._hold_sp = _hold(
                self._target(), _yaw(est) if self._yaw_sp is None else self._yaw_sp
            )
        self._seen_ns = None
        if self._hold_sp is not None:
            if st.retreating and not st.done and self._near(self._target(), est):
                st.done = True  # back at the last safe waypoint
            return self._hold_sp
        if self._near(self._target(), est):
            st.last_reached = st.target_index
            st.reached_at_ns.append(t_ns)
            if st.target_index == len(self.waypoints_m) - 1:
                st.done = True
                self._hold_sp = _hold(est.p_W_B, _yaw(est))
                return self._hold_sp
            st.target_index += 1
            self._integ[:] = 0.0
            self._prev_err = None
            self._yaw_integ, self._prev_yaw_err = 0.0, None
        return self._pid(est)

    def _near(self, target: FloatArray, est: StateEstimate) -> bool:
        return bool(np.linalg.norm(target - est.p_W_B) < self.gains.reach_radius_m)

    def _target(self) -> FloatArray:
        return np.asarray(self.waypoints_m[self.status.target_index], dtype=np.float64)

    def _pid(self, est: StateEstimate) -> Setpoint:
        g = self.gains
        err = self._target() - est.p_W_B
        d_err = np.zeros(3) if self._prev_err is None else err - self._prev_err
        self._prev_err = err
        self._integ = self._integ + err
        v = g.kp_lin * err + g.kd_lin * d_err + g.ki_lin * self._integ
        yaw = _yaw(est)
        if self._yaw_sp is None:
            self._yaw_sp = yaw
        # Face the waypoint (the laser looks where we go); straight above or below it, the
        # bearing is noise: hold the heading.
        if math.hypot(err[0], err[1]) > 0.3:
            e = math.remainder(math.atan2(err[1], err[0]) - yaw, math.tau)
            de = 0.0 if self._prev_yaw_err is None else e - self._prev_yaw_err
            self._prev_yaw_err = e
            self._yaw_integ += e
            rate = g.kp_ang * e + g.kd_ang * de + g.ki_ang * self._yaw_integ
            self._yaw_sp = math.remainder(self._yaw_sp + rate / g.rate_hz, math.tau)
        return Setpoint(v=v, yaw_rad=self._yaw_sp)
