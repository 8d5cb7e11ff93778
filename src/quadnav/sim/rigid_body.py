"""A full rigid-body quadrotor: quaternion attitude, four rotors with lag and limits, drag, wind.

State (17): position ``p_W_B`` and velocity ``v_W_B`` in the world (ENU), attitude
``q_W_B_xyzw`` (FLU body), body rates ``w_B``, and the four rotor speeds (rad/s). Rotor i
makes thrust ``k_thrust w_i^2`` along body +z at ``(x_i, y_i)`` and a reaction torque
``-spin_i k_torque w_i^2`` about body z (``spin = +1`` for a rotor turning counter-clockwise
seen from above). Rotor speeds follow their commands through a first-order lag and are
limited to ``[omega_min, omega_max]``: a rotor cannot push down. Drag is linear in the
airspeed, expressed in the body frame. Integration is RK4 at a fixed step (1 kHz by
default); wind is held over a step. The ground plane z = 0 stops the vehicle: it can rest,
take off and land.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.random import Generator
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import SimError
from quadnav.jit import JIT_ENABLED, njit
from quadnav.messages import VehicleState
from quadnav.units import s_to_ns
from quadnav.vehicle import RigidBodyParams

__all__ = ["RigidBodyQuadrotor", "Wind"]

FloatArray = NDArray[np.float64]


class Wind:
    """Mean wind plus gusts: a first-order Gauss-Markov process per axis, seeded.

    ``gust_sigma_m_s`` is the gusts' standard deviation and ``gust_tau_s`` their correlation
    time (Dryden-like low-pass turbulence).
    """

    def __init__(
        self,
        *,
        mean_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0),
        gust_sigma_m_s: float = 0.0,
        gust_tau_s: float = 2.0,
        rng: Generator | None = None,
    ) -> None:
        if gust_sigma_m_s < 0 or not gust_tau_s > 0:
            raise SimError("wind needs gust_sigma_m_s >= 0 and gust_tau_s > 0")
        if gust_sigma_m_s > 0 and rng is None:
            raise SimError("gusting wind needs an rng")
        self.mean = np.asarray(mean_m_s, dtype=np.float64)
        self.sigma = float(gust_sigma_m_s)
        self.tau = float(gust_tau_s)
        self.rng = rng
        self.gust = (
            self.sigma * rng.standard_normal(3)
            if rng is not None and self.sigma > 0
            else np.zeros(3)
        )
        # Without gusts the wind is the mean, the same (read-only) array every step.
        self._steady = np.asarray(self.mean + self.gust, dtype=np.float64)
        self._steady.flags.writeable = False

    def step(self, dt_s: float) -> FloatArray:
        """Advance the gusts by ``dt_s`` and return the wind velocity (world frame, m/s)."""
        if self.sigma > 0 and self.rng is not None:
            a = math.exp(-dt_s / self.tau)
            self.gust = a * self.gust + self.sigma * math.sqrt(
                1 - a * a
            ) * self.rng.standard_normal(3)
            return np.asarray(self.mean + self.gust, dtype=np.float64)
        return self._steady


class RigidBodyQuadrotor:
    """Steps the rigid-body model with RK4; ``step(omega_cmd)`` takes rotor speed commands."""

    def __init__(
        self,
        params: RigidBodyParams,
        *,
        dt_s: float = 0.001,
        p0: tuple[float, float, float] = (0.0, 0.0, 0.0),
        yaw0_rad: float = 0.0,
        hovering: bool = False,
        wind: Wind | None = None,
        t0_ns: int = 0,
    ) -> None:
        if not dt_s > 0:
            raise SimError(f"the step must be > 0 s, got {dt_s}")
        self.params = params
        self.dt_s = float(dt_s)
        self.dt_ns = s_to_ns(dt_s)
        self.t_ns = int(t0_ns)
        self.wind = wind or Wind()
        self._wind_now = self.wind.mean.copy()
        self._I = np.asarray(params.inertia_kg_m2, dtype=np.float64)
        x, y, spin = params.rotor_geometry()
        self._rx, self._ry, self._spin = x, y, spin
        self._consts = _model_constants(params)
        s = np.zeros(17)
        s[0:3] = p0
        s[6:10] = Rotation.from_euler("z", yaw0_rad).as_quat()
        if hovering:
            s[13:17] = params.hover_omega_rad_s
        self.s = s
        self.last_accel_W = np.zeros(3)

    # -- the model ---------------------------------------------------------------------
    def derivative(self, s: FloatArray, omega_cmd: FloatArray, wind_W: FloatArray) -> FloatArray:
        """``s'`` for rotor commands and wind (the kernel :func:`_derivative` the step uses)."""
        out = np.empty(17)
        _derivative(
            np.asarray(s, dtype=np.float64), np.asarray(omega_cmd, dtype=np.float64),
            np.asarray(wind_W, dtype=np.float64), self._consts, out,
        )  # fmt: skip
        return out

    def step(self, omega_cmd: FloatArray) -> FloatArray:
        """Advance one step with rotor speed commands (clipped to the rotor limits)."""
        cmd = np.asarray(omega_cmd, dtype=np.float64)
        if cmd.shape != (4,):
            raise SimError(f"rotor commands must be 4 finite speeds, got {cmd}")
        wind = self.wind.step(self.dt_s)
        self._wind_now = wind
        s, accel = np.empty(17), np.empty(3)
        if JIT_ENABLED:  # (compiled code raises no floating-point warnings)
            status = _step(self.s, cmd, wind, self._consts, self.dt_s, s, accel)
        else:
            with np.errstate(all="ignore"):  # a diverging state is caught below, in one line
                status = _step(self.s, cmd, wind, self._consts, self.dt_s, s, accel)
        if status == _BAD_COMMAND:
            raise SimError(f"rotor commands must be 4 finite speeds, got {cmd}")
        if status == _DIVERGED:
            raise SimError(f"the rigid-body simulation diverged at t = {self.t_ns * 1e-9:.4g} s")
        self.last_accel_W = accel
        self.s = s
        self.t_ns += self.dt_ns
        return s

    # -- views -----------------------------------------------------------------------------
    @property
    def wind_W(self) -> FloatArray:
        return self._wind_now

    def state(self) -> VehicleState:
        # (finite and its quaternion a unit one: step() and __init__ see to it). No copies: each
        # step makes a new state array and acceleration and never writes into them again; they
        # become read-only here (the first 13 entries the state's, its fields views of them)
        return VehicleState.from_vector(self.t_ns, self.s, self.last_accel_W)

    def energy_rot_j(self) -> float:
        w = self.s[10:13]
        return float(0.5 * np.sum(self._I * w * w))


# -- the compiled kernels (quadnav.jit: numba, or plain Python with QUADNAV_JIT=0) -------------
@njit
def _all_finite(a: FloatArray) -> bool:
    """Whether every entry is finite (a loop: it stops at the first that is not)."""
    for x in a:  # noqa: SIM110
        if not math.isfinite(x):
            return False
    return True


# The model's constants, one float array: k_thrust, k_torque, mass, gravity, Ix, Iy, Iz, the
# body drag (x, y, z), the rotor lag, the rotor limits, then the rotors' x, y and spin (4 each).
_N_CONSTS = 13 + 12


def _model_constants(p: RigidBodyParams) -> FloatArray:
    x, y, spin = p.rotor_geometry()
    if len(x) != 4:
        raise SimError(f"the rigid body has 4 rotors, got {len(x)}")
    c = np.array(
        [p.k_thrust_n_s2, p.k_torque_nm_s2, p.mass_kg, p.gravity_m_s2, *p.inertia_kg_m2,
         *p.drag_n_s_m, p.motor_tau_s, p.omega_min_rad_s, p.omega_max_rad_s, *x, *y, *spin],
        dtype=np.float64,
    )  # fmt: skip
    assert c.shape == (_N_CONSTS,)
    return c


@njit
def _derivative(
    s: FloatArray, cmd: FloatArray, wind: FloatArray, c: FloatArray, out: FloatArray
) -> None:
    """``s'`` into ``out``, written in scalars (it runs four times a simulator step)."""
    k_thrust, k_torque, m, grav = c[0], c[1], c[2], c[3]
    Ix, Iy, Iz, dx, dy, dz, motor_tau = c[4], c[5], c[6], c[7], c[8], c[9], c[10]
    vx, vy, vz = s[3], s[4], s[5]
    qx, qy, qz, qw = s[6], s[7], s[8], s[9]
    wx, wy, wz = s[10], s[11], s[12]
    thrust = 0.0
    tau_x = 0.0
    tau_y = 0.0
    tau_z = 0.0
    for i in range(4):
        om = s[13 + i]
        f = k_thrust * om * om
        thrust += f
        tau_x += c[17 + i] * f
        tau_y -= c[13 + i] * f
        tau_z -= c[21 + i] * (k_torque * om * om)
    # R_W_B from the quaternion (columns: body axes in the world)
    xx, yy, zz = qx * qx, qy * qy, qz * qz
    xy, xz, yz, wx_, wy_, wz_ = qx * qy, qx * qz, qy * qz, qw * qx, qw * qy, qw * qz
    r00, r01, r02 = 1 - 2 * (yy + zz), 2 * (xy - wz_), 2 * (xz + wy_)
    r10, r11, r12 = 2 * (xy + wz_), 1 - 2 * (xx + zz), 2 * (yz - wx_)
    r20, r21, r22 = 2 * (xz - wy_), 2 * (yz + wx_), 1 - 2 * (xx + yy)
    ax, ay, az = vx - wind[0], vy - wind[1], vz - wind[2]
    # Body-frame force: thrust along z minus linear drag on the body-frame airspeed.
    fbx = -dx * (r00 * ax + r10 * ay + r20 * az)
    fby = -dy * (r01 * ax + r11 * ay + r21 * az)
    fbz = thrust - dz * (r02 * ax + r12 * ay + r22 * az)
    out[0], out[1], out[2] = vx, vy, vz
    out[3] = (r00 * fbx + r01 * fby + r02 * fbz) / m
    out[4] = (r10 * fbx + r11 * fby + r12 * fbz) / m
    out[5] = (r20 * fbx + r21 * fby + r22 * fbz) / m - grav
    # q' = 1/2 q (x) (w, 0)
    out[6] = 0.5 * (qw * wx + qy * wz - qz * wy)
    out[7] = 0.5 * (qw * wy + qz * wx - qx * wz)
    out[8] = 0.5 * (qw * wz + qx * wy - qy * wx)
    out[9] = -0.5 * (qx * wx + qy * wy + qz * wz)
    # Euler's equations: I w' = tau - w x I w
    out[10] = (tau_x - (wy * Iz * wz - wz * Iy * wy)) / Ix
    out[11] = (tau_y - (wz * Ix * wx - wx * Iz * wz)) / Iy
    out[12] = (tau_z - (wx * Iy * wy - wy * Ix * wx)) / Iz
    for i in range(4):
        out[13 + i] = (cmd[i] - s[13 + i]) / motor_tau


_OK, _BAD_COMMAND, _DIVERGED = 0, 1, 2  # what _step says


@njit
def _step(
    s: FloatArray, omega_cmd: FloatArray, wind: FloatArray, c: FloatArray, dt: float,
    out: FloatArray, accel: FloatArray,
) -> int:  # fmt: skip
    """:meth:`RigidBodyQuadrotor.step`'s kernel: the commands checked (``_BAD_COMMAND`` if one
    is not finite: nothing written), one RK4 step into ``out``, the ground plane (no sinking;
    touching it stops the vehicle where it stands, its attitude kept: legs hold it, so nothing
    turns without the gyro seeing it, and the stop shows in the accelerometer as the landing
    shock), the new state checked (``_DIVERGED``), the acceleration over the step into
    ``accel``."""
    if not _all_finite(omega_cmd):
        return _BAD_COMMAND
    _rk4_step(s, omega_cmd, wind, c, dt, out)
    if out[2] <= 0.0:
        out[2] = 0.0
        if out[5] < 0.0:
            for i in range(3):
                out[3 + i] = 0.0
                out[10 + i] = 0.0
            for i in range(6, 10):  # the turn the step integrated, undone with its rate
                out[i] = s[i]
    if not _all_finite(out):
        return _DIVERGED
    for i in range(3):
        accel[i] = (out[3 + i] - s[3 + i]) / dt
    return _OK


@njit
def _rk4_step(
    s: FloatArray, omega_cmd: FloatArray, wind: FloatArray, c: FloatArray, dt: float,
    out: FloatArray,
) -> None:  # fmt: skip
    """One RK4 step (Simulink's ode4; commands and wind held over it) into ``out``, the
    quaternion renormalised and the rotor speeds clipped to their limits; the commands are
    clipped first."""
    n = s.shape[0]
    om_min, om_max = c[11], c[12]
    cmd = np.empty(4)
    for i in range(4):
        cmd[i] = min(max(omega_cmd[i], om_min), om_max)
    k1, k2, k3, k4 = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    x = np.empty(n)
    _derivative(s, cmd, wind, c, k1)
    for i in range(n):
        x[i] = s[i] + 0.5 * dt * k1[i]
    _derivative(x, cmd, wind, c, k2)
    for i in range(n):
        x[i] = s[i] + 0.5 * dt * k2[i]
    _derivative(x, cmd, wind, c, k3)
    for i in range(n):
        x[i] = s[i] + dt * k3[i]
    _derivative(x, cmd, wind, c, k4)
    for i in range(n):
        out[i] = s[i] + (dt / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    qn = math.sqrt(out[6] * out[6] + out[7] * out[7] + out[8] * out[8] + out[9] * out[9])
    for i in range(6, 10):
        out[i] /= qn
    for i in range(13, 17):
        out[i] = min(max(out[i], om_min), om_max)
