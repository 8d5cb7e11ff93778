"""The navigation flight's compiled kernels (``quadnav.jit``, issue 26): the rotations, the
output predictor's step and correction, the EKF's update, the IMU's reading. Each compiled
kernel against itself run as Python, against an independent reference (SciPy, the batched
numpy path, the textbook update), and a seeded ``indoor_vision_pose`` flight with the kernels
compiled against the same flight with them as Python."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.estimation import horizon, nav_ekf
from quadnav.experiments import nav
from quadnav.experiments.nav import run_nav
from quadnav.experiments.scenarios import nav_builtin
from quadnav.geometry import rotations
from quadnav.messages import ImuSample
from quadnav.sim import rigid_body, sensors
from tests.sim import test_jit_kernels

pytestmark = test_jit_kernels.pytestmark  # (skipped where QUADNAV_JIT=0: nothing compiled)

# (module, name) of every kernel a module calls by that name: patched together for the slow path
SLOW_PATH = [
    (rotations, "so3_exp_one"),
    (rotations, "so3_log_one"),
    (rotations, "quat_xyzw_one"),
    (nav_ekf, "so3_exp_one"),
    (nav_ekf, "so3_log_one"),
    (nav_ekf, "_strapdown_one"),
    (nav_ekf, "_strapdown_ring"),
    (nav_ekf, "_strapdown_into"),
    (nav_ekf, "_state_row"),
    (nav_ekf, "_estimate_parts"),
    (nav_ekf, "_output_parts"),
    (nav_ekf, "quat_xyzw_one"),
    (nav, "_log_row"),
    (nav_ekf, "_rotation_error"),
    (nav_ekf, "_kalman_update"),
    (horizon, "_pi_correct"),
    (nav_ekf, "_pi_correct"),
    (nav_ekf, "_correct_ring"),
    (nav_ekf, "_inject"),
    (sensors, "_reading"),
    (sensors, "_draw_one"),
    (sensors, "_draw_reading"),
    (sensors, "_vision_pose"),
    (rigid_body, "_all_finite"),
]


def _rotations(rng: np.random.Generator) -> list[np.ndarray]:
    """Random rotations, and rotations near a half turn about each axis (Shepperd's other
    three branches), and near the identity (Rodrigues' small-angle branch)."""
    out = list(Rotation.random(20, random_state=rng).as_matrix())
    for axis in np.eye(3):
        out.append(Rotation.from_rotvec(axis * 3.0).as_matrix())
    out.append(Rotation.from_rotvec([1e-8, -2e-8, 3e-9]).as_matrix())
    return out


def test_the_rotation_kernels_are_scipys_and_their_python() -> None:
    rng = np.random.default_rng(1)
    for R in _rotations(rng):
        q = rotations.quat_xyzw_from_matrix(R)
        ref = Rotation.from_matrix(R).as_quat()
        np.testing.assert_allclose(q, ref if ref[3] >= 0 else -ref, atol=1e-12)
        assert q[3] >= 0
        np.testing.assert_array_equal(q, rotations.quat_xyzw_one.py_func(R))
        rv = Rotation.from_matrix(R).as_rotvec()
        if np.linalg.norm(rv) < 3.1:  # (so3_log is for angles below pi)
            np.testing.assert_allclose(rotations.so3_log(R), rv, atol=1e-9)
        np.testing.assert_allclose(
            rotations.so3_log(R), rotations.so3_log_one.py_func(R), rtol=1e-14, atol=1e-15
        )
    for rv in [*rng.normal(0, 1.0, (20, 3)), np.array([1e-9, 0.0, -2e-9])]:
        E = rotations.so3_exp(rv)
        np.testing.assert_allclose(E, Rotation.from_rotvec(rv).as_matrix(), atol=1e-13)
        np.testing.assert_allclose(E, rotations.so3_exp_one.py_func(rv), rtol=1e-14, atol=1e-15)


def test_the_output_predictor_step_is_the_batched_strapdown() -> None:
    """One state's compiled step against the batched numpy path of the same integration (a
    batch of one), with and without the delta-angle correction."""
    kin = nav_ekf.NavKinematics()
    rng = np.random.default_rng(2)
    for k in range(20):
        pos, vel = rng.normal(0, 5, 3), rng.normal(0, 2, 3)
        att = Rotation.random(random_state=rng).as_matrix().ravel()
        gyro, accel = rng.normal(0, 1, 3), rng.normal(0, 5, 3) + [0, 0, 9.8]
        corr = rng.normal(0, 1e-3, 3) if k % 2 else None
        one = kin.integrate(pos, vel, att, gyro, accel, 0.004, corr)
        batch = kin.integrate(
            pos[None], vel[None], att[None], gyro[None], accel[None], np.array([0.004]),
            None if corr is None else corr[None],
        )  # fmt: skip
        for a, b in zip(one, batch, strict=True):
            np.testing.assert_allclose(a, b[0], rtol=1e-12, atol=1e-13)
        c = np.zeros(3) if corr is None else corr
        py = nav_ekf._strapdown_one.py_func(pos, vel, att, gyro, accel, 0.004, c, kin.gravity_m_s2)
        for a, b in zip(one, py, strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-15)
        R_a, R_b = att, Rotation.random(random_state=rng).as_matrix().ravel()
        expected = Rotation.from_matrix(R_b.reshape(3, 3).T @ R_a.reshape(3, 3)).as_rotvec()
        np.testing.assert_allclose(kin.attitude_error(R_a, R_b), expected, atol=1e-9)


def test_the_output_predictors_ring_step_is_the_batched_strapdown() -> None:
    """The ring's compiled step (row to row, the biases removed in the kernel) against the
    batched numpy path of the same integration; the other rows untouched."""
    kin = nav_ekf.NavKinematics()
    rng = np.random.default_rng(6)
    for k in range(20):
        L, src = 5, k % 5
        dst = (src + 1) % L
        ring = (rng.normal(0, 5, (L, 3)), rng.normal(0, 2, (L, 3)), rng.normal(size=(L, 9)))
        ring[2][src] = Rotation.random(random_state=rng).as_matrix().ravel()
        gyro, accel = rng.normal(0, 1, 3), rng.normal(0, 5, 3) + [0, 0, 9.8]
        imu = ImuSample(t_ns=1, gyro_rad_s=gyro, accel_m_s2=accel)
        biases = (rng.normal(0, 0.01, 3), rng.normal(0, 0.1, 3))
        corr = rng.normal(0, 1e-3, 3)
        before = [a.copy() for a in ring]
        want = kin.integrate(
            ring[0][src][None], ring[1][src][None], ring[2][src][None],
            (gyro - biases[0])[None], (accel - biases[1])[None], np.array([0.004]), corr[None],
        )  # fmt: skip
        kin.integrate_ring(ring, src, dst, imu, biases, 0.004, corr)
        for got, was, w in zip(ring, before, want, strict=True):
            np.testing.assert_allclose(got[dst], w[0], rtol=1e-12, atol=1e-13)
            others = np.arange(L) != dst
            np.testing.assert_array_equal(got[others], was[others])
        slow = tuple(a.copy() for a in before)
        horizon.integrate_ring(kin, slow, src, dst, imu, biases, 0.004, corr)  # (numpy's)
        for got, w in zip(ring, slow, strict=True):
            np.testing.assert_allclose(got, w, rtol=1e-14, atol=1e-15)


def test_the_logged_state_row_is_the_estimates() -> None:
    """The EKF's row for the log (position, velocity, SciPy's quaternion, biases) and its 15
    states' covariance, with and without the odometry drift's states beside them."""
    rng = np.random.default_rng(7)
    for mode in ("absolute", "relative"):
        config = nav_ekf.NavEkfConfig(odometry_mode=mode)
        q0 = Rotation.random(random_state=rng).as_quat()
        ekf = nav_ekf.NavEkf(
            config, p0=rng.normal(size=3), v0=rng.normal(size=3), q0_xyzw=q0,
            P0=np.diag(rng.uniform(0.01, 1.0, 15)), bg0=rng.normal(0, 0.01, 3),
            ba0=rng.normal(0, 0.1, 3),
        )  # fmt: skip
        ekf._P = ekf._P + rng.normal(0, 1e-3, ekf._P.shape)
        row, P = np.full(16, np.nan), np.full((15, 15), np.nan)
        ekf.state_row(row, P)
        q = Rotation.from_matrix(ekf.R).as_quat()
        want = np.concatenate([ekf.p, ekf.v, q if q[3] >= 0 else -q, ekf.bg, ekf.ba])
        np.testing.assert_allclose(row, want, atol=1e-12)
        np.testing.assert_array_equal(P, ekf.P)
        nav_state = ekf.nav(0)
        est = nav_ekf.NavKinematics().to_estimate(nav_state, ekf.x, ekf.names, ekf.P)
        np.testing.assert_array_equal(row[6:10], est.q_W_B_xyzw)
        np.testing.assert_array_equal(est.p_W_B, ekf.p)
        np.testing.assert_array_equal(est.v_W_B, ekf.v)
        assert est.p_W_B is not nav_state.pos and est.v_W_B is not nav_state.vel  # (copies)


def test_the_output_estimate_is_the_rings_state_in_numpy() -> None:
    """The output predictor's estimate from its kernel: copies of the ring's row, SciPy's
    quaternion, ``x`` the concatenated row, the names and the body rate (the gyro less its bias)."""
    rng = np.random.default_rng(11)
    kin = nav_ekf.NavKinematics()
    for R in _rotations(rng):
        pos, vel, att = rng.normal(size=3), rng.normal(size=3), R.ravel().copy()
        gyro, bg = rng.normal(size=3), rng.normal(size=3) * 0.1
        est = kin.output_estimate(horizon.NavState(7, pos, vel, att), gyro, bg)
        want = kin.to_estimate(
            horizon.NavState(7, pos, vel, att), np.concatenate((pos, vel, att)),
            kin.output_names, None, gyro - bg,
        )  # fmt: skip
        for name in ("p_W_B", "v_W_B", "q_W_B_xyzw", "x", "w_B"):
            np.testing.assert_array_equal(getattr(est, name), getattr(want, name), err_msg=name)
        assert est.t_ns == 7 and est.names == kin.output_names and est.P is None
        # without a gyro reading, or with a bias of another shape, there is no body rate
        for no_rate in ((None, bg), (gyro, np.zeros(1))):
            est = kin.output_estimate(horizon.NavState(7, pos, vel, att), *no_rate)
            assert est.w_B is None
            np.testing.assert_array_equal(est.p_W_B, pos)
        assert not np.shares_memory(est.p_W_B, pos) and not np.shares_memory(est.x, att)


def test_the_log_row_kernel_puts_each_part_in_its_columns() -> None:
    rng = np.random.default_rng(8)
    parts = [rng.normal(size=w) for w in (3, 3, 4, 3, 3, 3, 4, 3, 3)]
    row = np.full(nav._WIDTH, np.nan)
    nav._log_row(row, *parts)
    names = ("truth_p", "truth_v", "truth_q", "ref_p", "output_p", "output_v", "output_q")
    for name, part in zip(names, parts, strict=False):
        a, b = nav._COLUMNS[name]
        np.testing.assert_array_equal(row[a:b], part)
    a, b = nav._COLUMNS["true_bias"]
    np.testing.assert_array_equal(row[a:b], np.concatenate(parts[7:]))
    assert np.isnan(row[nav._DELAYED]).all()  # (the estimator writes those)


def test_the_output_correction_is_the_proportional_integral_one() -> None:
    """The ring's correction against the formula written out in numpy: errors at the oldest
    entry, their integrals, the gains; every entry moved, later ones also by their age."""
    rng = np.random.default_rng(3)
    for propagate in (True, False):
        L, oldest = 7, 3
        ob_t = 1_000_000_000 + 4_000_000 * ((np.arange(L) - oldest) % L)
        ob_pos, ob_vel = rng.normal(size=(L, 3)), rng.normal(size=(L, 3))
        pos, vel, ip, iv = (rng.normal(size=3) for _ in range(4))
        exp_pos, exp_vel, exp_ip, exp_iv = ob_pos.copy(), ob_vel.copy(), ip.copy(), iv.copy()
        vg, pg = 0.02, 0.01
        ve, pe = vel - exp_vel[oldest], pos - exp_pos[oldest]
        exp_iv += ve
        exp_ip += pe
        vc = ve * vg + exp_iv * (vg**2 * 0.1)
        pc = pe * pg + exp_ip * (pg**2 * 0.1)
        exp_vel += vc
        age = (ob_t - ob_t[oldest]) * 1e-9
        exp_pos += pc + age[:, None] * vc if propagate else pc
        horizon._pi_correct(ob_t, ob_pos, ob_vel, oldest, pos, vel, ip, iv, pg, vg, propagate)
        for got, want in ((ob_pos, exp_pos), (ob_vel, exp_vel), (ip, exp_ip), (iv, exp_iv)):
            np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-15)


def test_the_ring_correction_in_one_kernel_is_the_attitude_error_and_the_pi_one() -> None:
    """:meth:`NavKinematics.correct_ring` (one kernel) against the generic
    :func:`horizon.correct_ring` (the attitude error, then :func:`_pi_correct`): the same ring
    and integrals, bit for bit; the delta angle is SciPy's rotation error times the gain."""
    rng = np.random.default_rng(12)
    kin = nav_ekf.NavKinematics()
    for propagate in (True, False):
        L, oldest = 7, 2
        ring_t = 1_000_000_000 + 4_000_000 * ((np.arange(L) - oldest) % L)
        att = np.stack([R.ravel() for R in Rotation.random(L, random_state=rng).as_matrix()])
        ring = (rng.normal(size=(L, 3)), rng.normal(size=(L, 3)), att)
        R_nav = Rotation.random(random_state=rng).as_matrix()
        nav_state = horizon.NavState(0, rng.normal(size=3), rng.normal(size=3), R_nav.ravel())
        integ = (rng.normal(size=3), rng.normal(size=3))
        gains = (0.05, 0.01, 0.02)
        same = tuple(a.copy() for a in ring), tuple(a.copy() for a in integ)
        got = kin.correct_ring(ring, ring_t, oldest, nav_state, integ, gains, propagate)
        want = horizon.correct_ring(kin, *same[:1], ring_t, oldest, nav_state, same[1], gains,
                                    propagate)  # fmt: skip
        np.testing.assert_array_equal(got, want)
        for a, b in zip((*ring, *integ), (*same[0], *same[1]), strict=True):
            np.testing.assert_array_equal(a, b)
        turn = Rotation.from_matrix(att[oldest].reshape(3, 3).T @ R_nav).as_rotvec()
        np.testing.assert_allclose(got, turn * gains[0], rtol=1e-9, atol=1e-15)


def test_the_injection_kernel_adds_the_correction() -> None:
    """An update's correction into new arrays: the velocity, position and biases plus their
    parts of ``dx``, as numpy adds them; the attitude turned by SciPy's rotation of its part."""
    rng = np.random.default_rng(13)
    dx, v, p, bg, ba = rng.normal(size=15) * 0.1, *(rng.normal(size=3) for _ in range(4))
    R = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    out = tuple(np.full(3, np.nan) for _ in range(4)) + (np.full((3, 3), np.nan),)
    nav_ekf._inject(dx, R, v, p, bg, ba, out)
    for got, want in zip(out[:4], (v + dx[3:6], p + dx[6:9], bg + dx[9:12], ba + dx[12:15]),
                         strict=True):  # fmt: skip
        np.testing.assert_array_equal(got, want)
    want_R = R @ Rotation.from_rotvec(dx[0:3]).as_matrix()
    np.testing.assert_allclose(out[4], want_R, atol=1e-15)
    assert not np.allclose(out[4], R, atol=1e-3)  # (the turn is there, not the old attitude)


def _textbook_update(
    P: np.ndarray, H: np.ndarray, Rn: np.ndarray, r: np.ndarray
) -> tuple[float, np.ndarray, np.ndarray]:
    S = H @ P @ H.T + Rn
    K = P @ H.T @ np.linalg.inv(S)
    dx = K @ r
    P1 = (np.eye(len(P)) - K @ H) @ P
    B = np.eye(len(P))
    B[0:3, 0:3] = np.eye(3) - 0.5 * rotations.skew(dx[0:3])
    P1 = B @ P1 @ B.T
    return float(r @ np.linalg.solve(S, r)), dx, 0.5 * (P1 + P1.T)


@pytest.mark.parametrize("m", [1, 4])
def test_the_update_kernel_is_the_textbook_update(m: int) -> None:
    rng = np.random.default_rng(4 + m)
    for n in (15, 20):  # the 15 states, and with the odometry frame's drift
        A = rng.normal(size=(n, n))
        P = A @ A.T * 0.01 + np.eye(n) * 1e-3
        H = rng.normal(size=(m, n))
        Rn = np.diag(rng.uniform(0.01, 0.1, m))
        r = rng.normal(0, 0.1, m)
        nis, dx, P1 = nav_ekf._kalman_update(P, H, Rn, r, 1e9)
        want_nis, want_dx, want_P = _textbook_update(P, H, Rn, r)
        assert nis == pytest.approx(want_nis, rel=1e-10)
        np.testing.assert_allclose(dx, want_dx, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(P1, want_P, rtol=1e-8, atol=1e-12)
        py = nav_ekf._kalman_update.py_func(P, H, Rn, r, 1e9)
        np.testing.assert_allclose(P1, py[2], rtol=1e-12, atol=1e-15)
        refused = nav_ekf._kalman_update(P, H, Rn, r, want_nis * 0.99)  # just beyond the gate
        assert refused[1].size == 0 and refused[2] is P


def test_the_imu_draw_kernel_is_the_numpy_draw() -> None:
    """One sample's errors (the biases it carries, its noise; the biases after it) against the
    same standard normals in numpy; the biases before the sample are kept as they were."""
    errors = sensors.ImuErrors(
        gyro_sigma_rad_s=0.003, accel_sigma_m_s2=0.05, gyro_bias_rw_rad_s_sqrt_s=1e-4,
        accel_bias_rw_m_s2_sqrt_s=1e-3, gyro_bias0_rad_s=(0.01, -0.02, 0.005),
        accel_bias0_m_s2=(0.1, 0.0, -0.1),
    )  # fmt: skip
    rng, same = np.random.default_rng(9), np.random.default_rng(9)
    for dt in (0.004, 0.005, 0.0021):
        bg0, ba0 = errors.bias_g.copy(), errors.bias_a.copy()
        bg, ba, ng, na = errors.draw_one(dt, rng)
        z = same.standard_normal(12)
        np.testing.assert_array_equal(bg, bg0)
        np.testing.assert_array_equal(ba, ba0)
        np.testing.assert_array_equal(ng, z[0:3] * 0.003)
        np.testing.assert_array_equal(na, z[3:6] * 0.05)
        np.testing.assert_array_equal(errors.bias_g, bg0 + z[6:9] * (1e-4 * np.sqrt(dt)))
        np.testing.assert_array_equal(errors.bias_a, ba0 + z[9:12] * (1e-3 * np.sqrt(dt)))
        assert errors.bias_g is not bg and errors.bias_a is not ba


def test_the_imu_reading_in_one_kernel_is_the_draw_then_the_reading() -> None:
    """:meth:`ImuErrors.reading_one` against :meth:`ImuErrors.draw_one` and the reading in
    numpy, on the same numbers: the same reading, the same biases after it, the sums zeroed."""
    kw = dict(gyro_sigma_rad_s=0.003, accel_sigma_m_s2=0.05, gyro_bias_rw_rad_s_sqrt_s=1e-4,
              accel_bias_rw_m_s2_sqrt_s=1e-3, gyro_bias0_rad_s=(0.01, -0.02, 0.005),
              accel_bias0_m_s2=(0.1, 0.0, -0.1))  # fmt: skip
    one, two = sensors.ImuErrors(**kw), sensors.ImuErrors(**kw)  # type: ignore[arg-type]
    rng, same = np.random.default_rng(10), np.random.default_rng(10)
    for dt in (0.004, 0.005, 0.0021):
        sums = (rng.normal(size=3) * dt, rng.normal(size=3) * dt)
        same.normal(size=3), same.normal(size=3)
        want_sums = (sums[0].copy(), sums[1].copy())
        bg_before = one.bias_g
        gyro, accel = np.empty(3), np.empty(3)
        assert one.reading_one(sums, dt, rng, gyro, accel)
        bg, ba, ng, na = two.draw_one(dt, same)
        np.testing.assert_array_equal(gyro, want_sums[0] / dt + bg + ng)
        np.testing.assert_array_equal(accel, want_sums[1] / dt + ba + na)
        np.testing.assert_array_equal(one.bias_g, two.bias_g)
        np.testing.assert_array_equal(one.bias_a, two.bias_a)
        assert not sums[0].any() and not sums[1].any() and one.bias_g is not bg_before
    bad = (np.array([0.0, np.nan, 0.0]), np.zeros(3))
    assert not one.reading_one(bad, 0.004, rng, np.empty(3), np.empty(3))


def test_the_imu_reading_kernel_refuses_what_is_not_finite() -> None:
    sums = [np.array([0.02, -0.01, 0.005]), np.array([0.0, 0.1, 39.2])]
    gyro, accel = np.empty(3), np.empty(3)
    bg, ba, ng, na = (np.full(3, v) for v in (0.01, 0.2, 0.001, 0.02))
    assert sensors._reading(sums[0].copy(), sums[1].copy(), 0.004, bg, ba, ng, na, gyro, accel)
    np.testing.assert_allclose(gyro, sums[0] / 0.004 + 0.011)
    np.testing.assert_allclose(accel, sums[1] / 0.004 + 0.22)
    bad = sums[1].copy()
    bad[2] = np.nan
    sw = sums[0].copy()
    assert not sensors._reading(sw, bad, 0.004, bg, ba, ng, na, gyro, accel)
    assert not sw.any() and not bad.any()  # the sums start again either way
    assert rigid_body._all_finite(np.ones(17)) and not rigid_body._all_finite(
        np.array([1.0, np.inf])
    )


def test_the_vision_pose_kernel_is_the_frames_rotations_in_scipy() -> None:
    """The simulated vision pose from its kernel against SciPy's rotations of the same numbers:
    the position into the vision frame plus its noise, the attitude turned by the frame and
    by the yaw error; its Python the same."""
    rng = np.random.default_rng(17)
    for R in _rotations(rng):
        frame_yaw, yaw_err, sigma = rng.uniform(-3, 3), rng.normal(0, 0.1), 0.05
        R_V_W = Rotation.from_euler("z", -frame_yaw).as_matrix()
        p_W_V, p_W_B, noise = rng.normal(size=3), rng.normal(0, 3, 3), rng.normal(size=3)
        q_W_B = Rotation.from_matrix(R).as_quat()
        p, q = np.full(3, np.nan), np.full(4, np.nan)
        sensors._vision_pose(R_V_W, p_W_V, p_W_B, q_W_B, yaw_err, sigma, noise, p, q)
        np.testing.assert_allclose(p, R_V_W @ (p_W_B - p_W_V) + sigma * noise, atol=1e-12)
        want = (
            Rotation.from_euler("z", -frame_yaw) * Rotation.from_quat(q_W_B)
            * Rotation.from_euler("z", yaw_err)
        )  # fmt: skip
        assert (Rotation.from_quat(q) * want.inv()).magnitude() < 1e-9
        assert q[3] >= 0
        p2, q2 = np.empty(3), np.empty(4)
        sensors._vision_pose.py_func(R_V_W, p_W_V, p_W_B, q_W_B, yaw_err, sigma, noise, p2, q2)
        np.testing.assert_allclose(p2, p, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(q2, q, rtol=1e-14, atol=1e-15)


def test_a_seeded_navigation_flight_is_the_same_with_its_kernels_as_python(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    sc = nav_builtin("indoor_vision_pose", ["plan.kind=takeoff_forward", "plan.duration_s=4"])
    fast = run_nav(sc, 5)
    for module, name in SLOW_PATH:
        monkeypatch.setattr(module, name, getattr(module, name).py_func)
    slow = run_nav(sc, 5)
    assert len(fast.t_ns) > 1500 and np.isfinite(fast.delayed_err[-1]).all()
    assert np.linalg.norm(fast.output_p[-1] - fast.truth_p[-1]) < 0.1  # (it flew, and well)
    for name in ("truth_p", "output_p", "output_q", "delayed_x", "delayed_err", "delayed_P"):
        np.testing.assert_allclose(
            getattr(fast, name), getattr(slow, name), rtol=1e-9, atol=1e-9, err_msg=name
        )
