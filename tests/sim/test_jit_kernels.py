"""The compiled hot paths (``quadnav.jit``): each kernel compiled by numba against the same
kernel run as Python, a seeded closed-loop flight (simulator, controller, IMU) on the compiled
path against the slow path, and the rigid body against an independent Newton-Euler model."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.control import cascaded_pid
from quadnav.control.base import Setpoint, truth_estimate
from quadnav.estimation import nav_ekf
from quadnav.geometry.rotations import so3_exp
from quadnav.jit import JIT_ENABLED
from quadnav.sim import rigid_body, sensors
from quadnav.vehicle import RigidBodyParams

pytestmark = pytest.mark.skipif(
    not JIT_ENABLED, reason="QUADNAV_JIT=0 in the environment: nothing is compiled to compare"
)

KERNELS = [
    (rigid_body, "_derivative"),
    (rigid_body, "_rk4_step"),
    (rigid_body, "_step"),
    (rigid_body, "_all_finite"),
    (cascaded_pid, "_pid_step"),
    (cascaded_pid, "_clip"),
    (cascaded_pid, "_thrust_vector"),
    (sensors, "_accumulate"),
    (nav_ekf, "_propagate"),
    (nav_ekf, "_matmul"),
]


def _random_state(rng: np.random.Generator, p: RigidBodyParams) -> np.ndarray:
    s = np.empty(17)
    s[0:3] = rng.normal(0.0, 2.0, 3)
    s[3:6] = rng.normal(0.0, 1.5, 3)
    s[6:10] = Rotation.random(random_state=rng).as_quat()
    s[10:13] = rng.normal(0.0, 2.0, 3)
    s[13:17] = p.hover_omega_rad_s * rng.uniform(0.5, 1.4, 4)
    return s


def test_the_rigid_body_kernel_is_newton_euler_written_independently() -> None:
    """The derivative against the model written with SciPy and numpy: thrust and drag in the
    body, Euler's equations, the quaternion's kinematics, the rotors' lag."""
    p = RigidBodyParams()
    body = rigid_body.RigidBodyQuadrotor(p)
    rng = np.random.default_rng(3)
    x, y, spin = p.rotor_geometry()
    inertia = np.asarray(p.inertia_kg_m2)
    for _ in range(50):
        s = _random_state(rng, p)
        cmd, wind = p.hover_omega_rad_s * rng.uniform(0.5, 1.4, 4), rng.normal(0, 3, 3)
        R = Rotation.from_quat(s[6:10])
        om, w = s[13:17], s[10:13]
        f = p.k_thrust_n_s2 * om**2
        torque = np.array([y @ f, -x @ f, -spin @ (p.k_torque_nm_s2 * om**2)])
        force_B = np.array([0, 0, f.sum()]) - np.asarray(p.drag_n_s_m) * R.inv().apply(
            s[3:6] - wind
        )
        acc = R.apply(force_B) / p.mass_kg - [0, 0, p.gravity_m_s2]
        w_dot = (torque - np.cross(w, inertia * w)) / inertia
        q = s[6:10]  # q' = 1/2 q (x) (w, 0), scalar last
        q_dot = 0.5 * np.array(
            [
                q[3] * w[0] + q[1] * w[2] - q[2] * w[1],
                q[3] * w[1] + q[2] * w[0] - q[0] * w[2],
                q[3] * w[2] + q[0] * w[1] - q[1] * w[0],
                -q[0:3] @ w,
            ]
        )
        expected = np.concatenate([s[3:6], acc, q_dot, w_dot, (cmd - om) / p.motor_tau_s])
        np.testing.assert_allclose(body.derivative(s, cmd, wind), expected, rtol=1e-10, atol=1e-9)


def test_each_kernel_compiled_gives_what_it_gives_as_python() -> None:
    p = RigidBodyParams()
    rng = np.random.default_rng(7)
    consts = rigid_body._model_constants(p)
    pid = cascaded_pid.CascadedPid(p, dt_s=0.002)
    for k in range(30):
        s, cmd, wind = (
            _random_state(rng, p),
            p.hover_omega_rad_s * rng.uniform(0, 2, 4),
            rng.normal(size=3),
        )
        outs = [np.empty(17), np.empty(17)]
        for fn, out in zip(
            (rigid_body._derivative, rigid_body._derivative.py_func), outs, strict=True
        ):
            fn(s, cmd, wind, consts, out)
        np.testing.assert_allclose(outs[0], outs[1], rtol=1e-13, atol=1e-12)
        steps = [np.empty(17), np.empty(17)]
        for fn, out in zip(
            (rigid_body._rk4_step, rigid_body._rk4_step.py_func), steps, strict=True
        ):
            fn(s, cmd, wind, consts, 0.002, out)
        np.testing.assert_allclose(steps[0], steps[1], rtol=1e-13, atol=1e-12)
        args = (s[0:3], s[3:6], s[6:10], s[10:13], rng.normal(0, 3, 3), k % 2 == 0,
                rng.normal(size=3), rng.normal(size=3), float(rng.uniform(-3, 3)), pid._gains, pid._consts)  # fmt: skip
        st0 = rng.normal(0, 0.5, 14)
        states = [st0.copy(), st0.copy()]
        states[0][12:] = states[1][12:] = k % 3 > 0  # with and without previous errors
        pid_outs = [np.empty(9), np.empty(9)]
        for fn, st, out in zip(
            (cascaded_pid._pid_step, cascaded_pid._pid_step.py_func), states, pid_outs, strict=True
        ):
            fn(*args, st, out)
        np.testing.assert_allclose(pid_outs[0], pid_outs[1], rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(states[0], states[1], rtol=1e-12, atol=1e-12)
        sums = [np.zeros(3) for _ in range(4)]
        for fn, sf, sw in (
            (sensors._accumulate, sums[0], sums[1]),
            (sensors._accumulate.py_func, sums[2], sums[3]),
        ):
            fn(s[3:6], s[6:10], s[10:13], 0.002, 9.81, sf, sw)
        np.testing.assert_allclose(sums[0], sums[2], rtol=1e-13)
        np.testing.assert_allclose(sums[1], sums[3], rtol=1e-13)
        np.testing.assert_allclose(  # the specific force is R^T (a + g z)
            sums[0] / 0.002,
            Rotation.from_quat(s[6:10]).inv().apply(s[3:6] + [0, 0, 9.81]),
            rtol=1e-10,
            atol=1e-12,
        )


def _fly(seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """The simulator, the cascaded PID on the truth and the integrating IMU (500 Hz steps,
    a 200 Hz IMU with noise and biases), from the ground to a point 1.5 m up and turned."""
    p = RigidBodyParams()
    body = rigid_body.RigidBodyQuadrotor(p, dt_s=0.002)
    pid = cascaded_pid.CascadedPid(p, dt_s=0.002)
    imu = sensors.IntegratingImu(
        period_ns=5_000_000, gyro_sigma_rad_s=0.003, accel_sigma_m_s2=0.05,
        gyro_bias_rw_rad_s_sqrt_s=1e-4, accel_bias_rw_m_s2_sqrt_s=1e-3,
        gyro_bias0_rad_s=(0.01, -0.02, 0.005), accel_bias0_m_s2=(0.1, 0.0, -0.1),
    )  # fmt: skip
    rng = np.random.default_rng(11)
    ref = Setpoint(p=np.array([1.0, 0.5, 1.5]), yaw_rad=0.5)
    states, imu_out = [], []
    for _ in range(int(seconds / 0.002)):
        truth = body.state()
        sample = imu.sample(truth, truth.t_ns, rng)
        if sample is not None:
            imu_out.append(np.concatenate([sample.gyro_rad_s, sample.accel_m_s2]))
        body.step(pid(truth.t_ns, truth_estimate(truth), ref).rotors())
        states.append(body.s.copy())
    return np.array(states), np.array(imu_out)


def test_a_seeded_flight_is_the_same_on_the_compiled_and_the_slow_path(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fast, fast_imu = _fly(3.0)
    for module, name in KERNELS:
        monkeypatch.setattr(module, name, getattr(module, name).py_func)
    slow, slow_imu = _fly(3.0)
    assert fast[0, 2] == 0.0 and np.linalg.norm(fast[-1, 0:3] - [1.0, 0.5, 1.5]) < 0.1
    assert len(fast_imu) == len(slow_imu) == 599  # 200 Hz over 3 s, the first poll starting it
    np.testing.assert_allclose(fast, slow, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(fast_imu, slow_imu, rtol=1e-9, atol=1e-9)


def test_the_navigation_prediction_kernel_is_the_textbook_one() -> None:
    """``_propagate`` (compiled and as Python) against the mean integrated in numpy and the
    covariance ``F P F^T + G diag(q) G^T`` of :func:`nav_jacobians` built whole."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        R, dt = Rotation.random(random_state=rng).as_matrix(), float(rng.uniform(0.001, 0.02))
        v, p, gyro, accel = (rng.normal(0, s, 3) for s in (2.0, 5.0, 1.5, 9.0))
        bg, ba = rng.normal(0, 0.01, 3), rng.normal(0, 0.1, 3)
        w, f = gyro - bg, accel - ba
        g_W, q = np.array([0.0, 0.0, -9.80665]), rng.uniform(1e-8, 1e-2, 12)
        L = rng.normal(size=(15, 15))
        P = L @ L.T * 1e-3
        F_ref, G_ref = nav_ekf.nav_jacobians(R @ so3_exp(w * dt), f, w, dt)
        F0, G0 = nav_ekf.nav_jacobians(np.eye(3), np.zeros(3), np.zeros(3), dt)
        for fn in (nav_ekf._propagate, nav_ekf._propagate.py_func):
            F, G = F0.copy(), G0.copy()
            out = (np.empty(3), np.empty(3), np.empty((3, 3)), np.empty(3), np.empty(3))
            P1 = np.full((15, 15), np.nan)
            fn(R, v, p, gyro, accel, bg, ba, dt, g_W, F, G, q, P, True, (*out, P1))
            w1, f1, R1, v1, p1 = out
            np.testing.assert_array_equal(w1, w)
            np.testing.assert_array_equal(f1, f)
            np.testing.assert_allclose(R1, R @ so3_exp(w * dt), atol=1e-14)
            np.testing.assert_allclose(v1, v + dt * (R1 @ f + g_W), atol=1e-12)
            np.testing.assert_allclose(p1, p + dt * v1, atol=1e-12)
            np.testing.assert_allclose(F, F_ref, atol=1e-13)
            np.testing.assert_allclose(G, G_ref, atol=1e-13)
            expected = F_ref @ P @ F_ref.T + (G_ref * q) @ G_ref.T
            np.testing.assert_allclose(P1, expected, rtol=1e-11, atol=1e-16)
            untouched = np.full((15, 15), np.nan)
            fn(R, v, p, gyro, accel, bg, ba, dt, g_W, F, G, q, P, False, (*out, untouched))
            np.testing.assert_allclose(R1, R @ so3_exp(w * dt), atol=1e-14)
            assert np.isnan(untouched).all()  # (no covariance: P' is not written)


def test_the_rigid_body_step_kernel_is_rk4_the_ground_and_the_acceleration() -> None:
    """``_step`` against its parts in numpy: the RK4 step, the ground plane (a state below it
    put on it, and stopped when sinking, its attitude kept), the acceleration over the step; a
    command or a state that is not finite refused, and said which."""
    p = RigidBodyParams()
    consts = rigid_body._model_constants(p)
    rng = np.random.default_rng(12)
    for k in range(30):
        s = _random_state(rng, p)
        s[2] = rng.uniform(-0.01, 0.005) if k % 2 else s[2]  # half of them at the ground
        cmd, wind = p.hover_omega_rad_s * rng.uniform(0, 2, 4), rng.normal(size=3)
        want = np.empty(17)
        rigid_body._rk4_step(s, cmd, wind, consts, 0.002, want)
        if want[2] <= 0.0:
            want[2] = 0.0
            if want[5] < 0.0:
                want[[3, 4, 5, 10, 11, 12]] = 0.0
                want[6:10] = s[6:10]
        out, accel = np.full(17, np.nan), np.full(3, np.nan)
        assert rigid_body._step(s, cmd, wind, consts, 0.002, out, accel) == rigid_body._OK
        np.testing.assert_array_equal(out, want)
        np.testing.assert_allclose(accel, (want[3:6] - s[3:6]) / 0.002, rtol=1e-15)
    bad = cmd.copy()
    bad[1] = np.nan
    out = np.full(17, 7.0)
    assert rigid_body._step(s, bad, wind, consts, 0.002, out, accel) == rigid_body._BAD_COMMAND
    assert (out == 7.0).all()
    s[0] = np.inf
    assert rigid_body._step(s, cmd, wind, consts, 0.002, out, accel) == rigid_body._DIVERGED
