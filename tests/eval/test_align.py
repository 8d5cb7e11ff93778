from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import EvalError
from quadnav.eval import align
from quadnav.eval.align import AlignMethod, GravityAxis
from quadnav.geometry import Trajectory, geodesic_angle_rad


def random_walk(rng: np.random.Generator, n: int = 400) -> Trajectory:
    p = np.cumsum(rng.normal(0, 1.0, (n, 3)), axis=0)
    return Trajectory(
        t_ns=np.arange(n) * 10_000_000,
        p_W_B=p,
        q_W_B_xyzw=Rotation.random(n, random_state=3).as_quat(),
    )


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("method", ["se3", "sim3", "4dof"])
def test_alignment_recovers_a_known_transform(method: AlignMethod, seed: int) -> None:
    rng = np.random.default_rng(seed)
    ref = random_walk(rng)
    if method == "4dof":
        R_true = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi))
    else:
        R_true = Rotation.random(random_state=seed)
    t_true = rng.normal(0, 20, 3)
    s_true = rng.uniform(0.5, 2.0) if method == "sim3" else 1.0
    # est = inverse similarity of ref, plus 1 cm noise: aligning it must give back (R, t, s).
    p_est = R_true.inv().apply(ref.p_W_B - t_true) / s_true + rng.normal(0, 0.01, ref.p_W_B.shape)
    est = Trajectory(t_ns=ref.t_ns, p_W_B=p_est, q_W_B_xyzw=(R_true.inv() * ref.R_W_B).as_quat())
    aligned, a = align(ref, est, method)
    assert float(geodesic_angle_rad(a.R, R_true)) < 1e-3
    np.testing.assert_allclose(a.t, t_true, atol=0.05 * s_true)
    assert a.s == pytest.approx(s_true, rel=1e-3)
    assert np.sqrt(np.mean(np.sum((aligned.p_W_B - ref.p_W_B) ** 2, axis=1))) < 0.05
    # The attitudes carry the estimated rotation, good to the 1e-3 rad set by 1 cm position noise.
    assert np.all(geodesic_angle_rad(aligned.R_W_B, ref.R_W_B) < 1e-3)


def test_4dof_does_not_absorb_roll_or_pitch() -> None:
    rng = np.random.default_rng(0)
    ref = random_walk(rng)
    tilt = Rotation.from_euler("x", 0.3)
    est = ref.transformed(tilt, np.zeros(3))
    _, a = align(ref, est, "4dof")
    assert abs(a.R.as_euler("xyz")[0]) < 1e-12 and abs(a.R.as_euler("xyz")[1]) < 1e-12


def test_alignment_on_the_first_poses_only() -> None:
    rng = np.random.default_rng(1)
    ref = random_walk(rng)
    shift = np.array([5.0, 0.0, 0.0])
    p = ref.p_W_B.copy()
    p[200:] += 100.0  # the second half is badly off
    est = Trajectory(t_ns=ref.t_ns, p_W_B=p - shift, q_W_B_xyzw=ref.q_W_B_xyzw)
    _, a = align(ref, est, "se3", first_n=100)
    np.testing.assert_allclose(a.t, shift, atol=1e-9)
    assert a.n_used == 100


def test_degenerate_inputs() -> None:
    line = Trajectory(
        t_ns=np.arange(10),
        p_W_B=np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)]),
        q_W_B_xyzw=np.tile([0, 0, 0, 1.0], (10, 1)),
    )
    with pytest.raises(EvalError, match="collinear"):
        align(line, line, "se3")
    with pytest.raises(EvalError, match="at least 3"):
        align(line.select(slice(0, 2)), line.select(slice(0, 2)), "sim3")


@pytest.mark.parametrize("axis", ["x", "y", "z"])
def test_4dof_rotates_about_the_gravity_axis(axis: GravityAxis) -> None:
    rng = np.random.default_rng(4)
    ref = random_walk(rng)
    R_true = Rotation.from_euler(axis, 0.7)
    t_true = np.array([3.0, -2.0, 1.0])
    est = ref.transformed(R_true.inv(), -R_true.inv().apply(t_true))
    aligned, a = align(ref, est, "4dof", gravity_axis=axis)
    assert float(geodesic_angle_rad(a.R, R_true)) < 1e-9
    np.testing.assert_allclose(aligned.p_W_B, ref.p_W_B, atol=1e-9)
    if axis != "z":  # about z (the old behaviour) the yaw of a KITTI-like y-vertical is lost
        bad, _ = align(ref, est, "4dof", gravity_axis="z")
        assert np.sqrt(np.mean(np.sum((bad.p_W_B - ref.p_W_B) ** 2, axis=1))) > 1.0
