"""The controller interface: a state estimate and a setpoint in, a command out.

Every controller of quadnav is a :class:`Controller`::

    command = controller(t_ns, est, ref)

* ``est`` is a :class:`~quadnav.messages.StateEstimate` in its common 3-D form (``p_W_B``,
  ``v_W_B``, ``q_W_B_xyzw`` and ``w_B``, the bias-corrected body rate). A controller reads
  nothing else, so the same controller flies on an estimator's output or, through
  :func:`truth_estimate`, on the simulator's true state. A controller that needs the body
  rate refuses an estimate without one (``w_B`` None) with a :class:`~quadnav.errors.ControlError`.
* ``ref`` is a :class:`Setpoint`: position, velocity, acceleration (and the jerk and snap a
  flat trajectory gives, which the nested saturations use), yaw, and an optional attitude
  setpoint (the planar controller's tilt reference). Each controller documents which fields it
  reads; ``p`` None means velocity control.
* The :class:`Command` says what to apply: the collective thrust and either a body torque
  (N m) or the normalised torque ``tau~`` (rad/s^2) of thesis 002's Euler-Lagrange model, and,
  for a vehicle with rotors, the rotor speeds the mixer made of them. ``kind`` names which.

World ENU, body FLU, as everywhere; Euler angles are ZYX (yaw, pitch, roll), given as
``(roll, pitch, yaw)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import ControlError
from quadnav.messages import StateEstimate, VehicleState, slot_setters

__all__ = [
    "TRUTH_STATE_NAMES",
    "Command",
    "Controller",
    "Setpoint",
    "SetpointSource",
    "body_rates_from_euler_rates",
    "euler_rates_from_body_rates",
    "euler_rpy_from_quat_xyzw",
    "quat_xyzw_from_euler_rpy",
    "require_rate",
    "truth_estimate",
]

FloatArray = NDArray[np.float64]

#: The state layout of :func:`truth_estimate`.
TRUTH_STATE_NAMES = (
    *(f"p_{a}" for a in "xyz"),
    *(f"v_{a}" for a in "xyz"),
    *(f"q_{a}" for a in "xyzw"),
    *(f"w_{a}" for a in "xyz"),
)


@dataclass(frozen=True, slots=True, kw_only=True)
class Setpoint:
    """What the vehicle should do now. ``p`` None means velocity control; ``j`` and ``snap``
    are the trajectory's higher derivatives; ``q_W_B_xyzw`` an attitude setpoint."""

    p: FloatArray | None = None
    v: FloatArray | None = None
    a: FloatArray | None = None
    j: FloatArray | None = None
    snap: FloatArray | None = None
    yaw_rad: float = 0.0
    q_W_B_xyzw: FloatArray | None = None


CommandKind = Literal["rotor_speeds", "thrust_torque", "thrust_tau"]


@dataclass(frozen=True, slots=True, kw_only=True)
class Command:
    """A controller's output.

    ``thrust_n`` is the collective thrust along body z. Exactly one of ``torque_B_nm`` (body
    torque, N m) and ``tau_B_rad_s2`` (thesis 002's ``tau~ = J^-1 (tau - C eta')``, which the
    Euler-Lagrange model takes) is given. ``rotor_rad_s`` are the rotor speed commands when
    the controller mixes for a vehicle with rotors; ``saturated`` says a limit cut the demand.
    """

    thrust_n: float
    torque_B_nm: FloatArray | None = None
    tau_B_rad_s2: FloatArray | None = None
    rotor_rad_s: FloatArray | None = None
    saturated: bool = False

    def __post_init__(self) -> None:
        if (self.torque_B_nm is None) == (self.tau_B_rad_s2 is None):
            raise ControlError("a Command gives exactly one of torque_B_nm and tau_B_rad_s2")

    @classmethod
    def of_rotors(
        cls, thrust_n: float, torque_B_nm: FloatArray, rotor_rad_s: FloatArray, saturated: bool
    ) -> Command:
        """A ``rotor_speeds`` command with its torque (valid by construction: no check), for a
        controller called every simulator step."""
        out = object.__new__(cls)
        set_thrust, set_torque, set_tau, set_rotor, set_saturated = _COMMAND_SLOTS
        set_thrust(out, thrust_n)
        set_torque(out, torque_B_nm)
        set_tau(out, None)
        set_rotor(out, rotor_rad_s)
        set_saturated(out, saturated)
        return out

    @property
    def kind(self) -> CommandKind:
        if self.rotor_rad_s is not None:
            return "rotor_speeds"
        return "thrust_torque" if self.torque_B_nm is not None else "thrust_tau"

    def rotors(self) -> FloatArray:
        """The rotor speed commands (rad/s); a ``ControlError`` if the controller gave none."""
        if self.rotor_rad_s is None:
            raise ControlError(f"a {self.kind} command has no rotor speeds to apply")
        return self.rotor_rad_s

    def torque(self) -> FloatArray:
        """The torque given, whichever its kind (N m or rad/s^2)."""
        out = self.torque_B_nm if self.torque_B_nm is not None else self.tau_B_rad_s2
        assert out is not None  # __post_init__ guarantees one
        return out


_COMMAND_SLOTS = slot_setters(
    Command, "thrust_n", "torque_B_nm", "tau_B_rad_s2", "rotor_rad_s", "saturated"
)


class Controller(Protocol):
    """A state estimate and a setpoint in, a command out (stateful: integrators, phases)."""

    def __call__(self, t_ns: int, est: StateEstimate, ref: Setpoint) -> Command: ...


class SetpointSource(Protocol):
    """An outer loop that makes the setpoint an inner :class:`Controller` tracks (thesis 003's
    take-off and waypoint followers, which command velocities)."""

    def __call__(self, t_ns: int, est: StateEstimate, ref: Setpoint) -> Setpoint: ...


def truth_estimate(truth: VehicleState) -> StateEstimate:
    """The true state as a perfect estimate (no covariance): for flights on the true state."""
    x = np.concatenate([truth.p_W_B, truth.v_W_B, truth.q_W_B_xyzw, truth.w_B])
    return StateEstimate(
        t_ns=truth.t_ns,
        p_W_B=truth.p_W_B,
        v_W_B=truth.v_W_B,
        q_W_B_xyzw=truth.q_W_B_xyzw,
        x=x,
        names=TRUTH_STATE_NAMES,
        w_B=truth.w_B,
    )


def require_rate(est: StateEstimate, who: str) -> FloatArray:
    """The estimate's body rate, or a :class:`ControlError` naming the controller."""
    if est.w_B is None:
        raise ControlError(f"{who} needs the body rate: the estimate at t_ns {est.t_ns} has none")
    return est.w_B


def euler_rpy_from_quat_xyzw(q: FloatArray) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw) of a unit quaternion, in rad."""
    x, y, z, w = np.asarray(q, dtype=np.float64).tolist()
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def quat_xyzw_from_euler_rpy(roll: float, pitch: float, yaw: float) -> FloatArray:
    """The unit quaternion of ZYX Euler angles (roll, pitch, yaw) in rad."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return np.array(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ]
    )


def euler_rates_from_body_rates(
    roll: float, pitch: float, w_B: FloatArray
) -> tuple[float, float, float]:
    """ZYX Euler angle rates (roll', pitch', yaw') from the body rate (rad/s)."""
    p, q, r = np.asarray(w_B, dtype=np.float64).tolist()
    sf, cf = math.sin(roll), math.cos(roll)
    ct = math.cos(pitch)
    if abs(ct) < 1e-9:
        raise ControlError(f"Euler rates are undefined at pitch {math.degrees(pitch):.1f} deg")
    tt = math.sin(pitch) / ct
    return (p + (sf * q + cf * r) * tt, cf * q - sf * r, (sf * q + cf * r) / ct)


def body_rates_from_euler_rates(
    roll: float, pitch: float, rates: FloatArray
) -> tuple[float, float, float]:
    """The body rate (rad/s) from ZYX Euler angle rates (roll', pitch', yaw')."""
    dphi, dtheta, dpsi = np.asarray(rates, dtype=np.float64).tolist()
    sf, cf = math.sin(roll), math.cos(roll)
    st, ct = math.sin(pitch), math.cos(pitch)
    return (dphi - st * dpsi, cf * dtheta + sf * ct * dpsi, -sf * dtheta + cf * ct * dpsi)
