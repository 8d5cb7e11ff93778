"""The Controller interface: one estimate and setpoint in, a Command out, for every controller."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.control import Command, Controller, Setpoint, ThesisPlanarController, truth_estimate
from quadnav.control.base import (
    body_rates_from_euler_rates,
    euler_rates_from_body_rates,
    euler_rpy_from_quat_xyzw,
    quat_xyzw_from_euler_rpy,
)
from quadnav.control.cascaded_pid import CascadedPid
from quadnav.control.thesis002 import NestedSaturationController, PdController
from quadnav.control.thesis003 import (
    ObstacleAwareWaypointFollower,
    OuterLoopController,
    TakeoffForward,
    Thesis003Gains,
)
from quadnav.errors import ControlError
from quadnav.messages import RangeScan, StateEstimate, VehicleState
from quadnav.vehicle import RigidBodyParams


def estimate(*, p: tuple[float, float, float] = (0, 0, 1)) -> StateEstimate:
    """A slightly tilted, turning vehicle, as a perfect estimate."""
    truth = VehicleState(
        t_ns=0,
        p_W_B=np.array(p, dtype=float),
        v_W_B=np.zeros(3),
        a_W_B=np.zeros(3),
        q_W_B_xyzw=Rotation.from_euler("ZYX", [0.3, 0.05, -0.02]).as_quat(),
        w_B=np.array([0.01, -0.02, 0.03]),
    )
    return truth_estimate(truth)


def all_controllers() -> list[tuple[Controller, str]]:
    """The five controllers of the project, typed as the protocol (mypy checks each)."""
    params = RigidBodyParams()
    gains = Thesis003Gains()
    follower = ObstacleAwareWaypointFollower(waypoints_m=[(1.0, 0.0, 1.0)], gains=gains)
    return [
        (CascadedPid(params), "rotor_speeds"),
        (PdController(), "thrust_tau"),
        (NestedSaturationController(), "thrust_tau"),
        (ThesisPlanarController(), "thrust_torque"),
        (
            OuterLoopController(TakeoffForward(gains=gains), CascadedPid(params), rate_hz=10),
            "rotor_speeds",
        ),
        (OuterLoopController(follower, CascadedPid(params), rate_hz=10), "rotor_speeds"),
    ]


@pytest.mark.parametrize("index", range(6))
def test_every_controller_maps_an_estimate_and_a_setpoint_to_a_command(index: int) -> None:
    ctrl, kind = all_controllers()[index]
    cmd = ctrl(0, estimate(), Setpoint(p=np.array([0.0, 0.0, 1.0]), v=np.zeros(3)))
    assert isinstance(cmd, Command) and cmd.kind == kind
    assert math.isfinite(cmd.thrust_n) and cmd.thrust_n > 0
    assert np.isfinite(cmd.torque()).all() and cmd.torque().shape == (3,)


@pytest.mark.parametrize("index", [0, 1, 2, 3])
def test_a_controller_that_needs_the_body_rate_says_so(index: int) -> None:
    ctrl, _ = all_controllers()[index]
    est = estimate()
    no_rate = StateEstimate(t_ns=5, p_W_B=est.p_W_B, v_W_B=est.v_W_B, q_W_B_xyzw=est.q_W_B_xyzw,
                            x=est.x, names=est.names)  # fmt: skip
    with pytest.raises(ControlError, match="needs the body rate"):
        ctrl(5, no_rate, Setpoint(p=np.zeros(3)))


def test_command_carries_one_torque_and_says_when_it_has_no_rotor_speeds() -> None:
    with pytest.raises(ControlError, match="exactly one"):
        Command(thrust_n=1.0, torque_B_nm=np.zeros(3), tau_B_rad_s2=np.zeros(3))
    with pytest.raises(ControlError, match="exactly one"):
        Command(thrust_n=1.0)
    with pytest.raises(ControlError, match="no rotor speeds"):
        Command(thrust_n=1.0, tau_B_rad_s2=np.zeros(3)).rotors()


def test_a_rotor_command_made_without_its_check_is_the_checked_one() -> None:
    torque, rotors = np.array([0.1, -0.2, 0.0]), np.full(4, 400.0)
    fast = Command.of_rotors(9.5, torque, rotors, True)
    slow = Command(thrust_n=9.5, torque_B_nm=torque, rotor_rad_s=rotors, saturated=True)
    assert fast == slow and fast.kind == "rotor_speeds" and fast.rotors() is rotors


def test_euler_and_rate_conversions_agree_with_scipy_and_invert() -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        rpy = rng.uniform([-1.2, -1.2, -3.1], [1.2, 1.2, 3.1])
        q = quat_xyzw_from_euler_rpy(*rpy)
        ref = Rotation.from_euler("ZYX", rpy[::-1]).as_quat()
        assert min(np.abs(q - ref).max(), np.abs(q + ref).max()) < 1e-12
        np.testing.assert_allclose(euler_rpy_from_quat_xyzw(ref), rpy, atol=1e-12)
        w = rng.normal(size=3)
        rates = euler_rates_from_body_rates(rpy[0], rpy[1], w)
        np.testing.assert_allclose(
            body_rates_from_euler_rates(rpy[0], rpy[1], rates), w, atol=1e-12
        )
    # Body rate from Euler rates against a finite difference of the rotation.
    rpy, rates, h = np.array([0.4, -0.3, 1.0]), np.array([0.2, -0.5, 0.7]), 1e-6
    R0 = Rotation.from_euler("ZYX", rpy[::-1])
    R1 = Rotation.from_euler("ZYX", (rpy + h * rates)[::-1])
    w_fd = (R0.inv() * R1).as_rotvec() / h
    np.testing.assert_allclose(body_rates_from_euler_rates(rpy[0], rpy[1], rates), w_fd, atol=1e-5)


def test_the_outer_loop_keeps_its_rate_on_a_step_that_does_not_divide_its_period() -> None:
    """10 Hz on 7 ms steps for 10 s: 100 ticks (+1 at t = 0); restarting the period at each
    tick (due = now + period) would tick every 105 ms, 96 times."""
    pid = CascadedPid(RigidBodyParams(), dt_s=0.007)
    outer = OuterLoopController(TakeoffForward(), pid, rate_hz=10.0)
    est, sp = estimate(), Setpoint(p=np.array([0.0, 0.0, 5.0]))
    for k in range(int(10.0 / 0.007) + 1):
        outer(k * 7_000_000, est, sp)
    assert outer.ticks in (100, 101)


def scan(ranges: dict[float, float]) -> RangeScan:
    """A 360-ray scan with the given (angle in degrees: range) hits, nothing elsewhere."""
    r = np.full(360, np.inf)
    for deg, d in ranges.items():
        r[(round(deg) + 180) % 360] = d
    return RangeScan(t_ns=0, angle_min_rad=-math.pi, angle_increment_rad=math.radians(1),
                     range_max_m=10.0, ranges_m=r)  # fmt: skip


@pytest.mark.parametrize(
    ("hits", "seen"),
    [
        ({40.0: 0.5}, True),  # inside +-45 degrees, between 0.1 and 1 m
        ({-44.0: 0.99}, True),
        ({50.0: 0.5}, False),  # outside the sector
        ({0.0: 0.05}, False),  # nearer than 0.1 m: the thesis ignores it
        ({0.0: 1.2}, False),  # farther than 1 m
        ({180.0: 0.3}, False),  # behind
    ],
)
def test_obstacle_band_and_sector_are_the_thesis_ones(hits: dict[float, float], seen: bool) -> None:
    f = ObstacleAwareWaypointFollower(waypoints_m=[(5.0, 0.0, 1.0)])
    assert f.obstacle_ahead(scan(hits)) is seen


def test_thesis003_defaults_are_the_thesis_values() -> None:
    g = Thesis003Gains()
    assert (g.kp_lin, g.kd_lin, g.ki_lin) == (0.2, 0.01, 0.004)
    assert (g.kp_ang, g.kd_ang, g.ki_ang) == (3.4, 0.2, 0.02)
    assert (g.reach_radius_m, g.obstacle_min_m, g.obstacle_max_m) == (0.5, 0.1, 1.0)
    assert g.sector_half_angle_rad == pytest.approx(math.pi / 4)
    assert (g.takeoff_kp, g.takeoff_stop_m, g.rate_hz) == (0.2, 0.8, 10.0)


def test_waypoint_pid_is_the_thesis_discrete_law() -> None:
    """One tick from rest 2 m short in x: v = kp e (no change yet) + ki e (the sum so far)."""
    f = ObstacleAwareWaypointFollower(waypoints_m=[(2.0, 0.0, 1.0)])
    est = estimate(p=(0.0, 0.0, 1.0))
    sp = f(0, est, Setpoint())
    assert sp.v is not None and sp.p is None  # a velocity command, as /cmd_vel
    np.testing.assert_allclose(sp.v, [0.2 * 2 + 0.004 * 2, 0.0, 0.0], atol=1e-12)
    sp = f(100_000_000, est, Setpoint())  # same place: no change of error, the sum doubled
    assert sp.v is not None
    np.testing.assert_allclose(sp.v, [0.2 * 2 + 0.004 * 4, 0.0, 0.0], atol=1e-12)


def test_no_loop_forges_a_vehicle_state_from_an_estimate() -> None:
    """Only the simulators make a ``VehicleState`` (the truth); loops hand controllers a
    ``StateEstimate``. Before the Controller interface, run_nav and the SITL vehicle built one
    from the EKF's output."""
    import ast
    from pathlib import Path

    import quadnav

    root = Path(quadnav.__file__).parent
    makers = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "VehicleState":
                makers.append(path.relative_to(root).as_posix())
    sims = {"sim/rigid_body.py", "sim/planar.py", "sim/euler_lagrange.py"}
    assert makers and set(makers) <= sims, makers
