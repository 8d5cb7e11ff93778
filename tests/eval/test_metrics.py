from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import EvalError
from quadnav.eval import align, ape, associate, error_stats, nees, position_nees, rpe, rpe_pairs
from quadnav.geometry import Trajectory
from quadnav.io import read_trajectory

EVO = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "evo"
needs_kitti = pytest.mark.skipif(
    not (EVO / "KITTI_00_gt.txt").exists(), reason=f"shared data not at {EVO}"
)


@needs_kitti
def test_kitti_00_reproduces_evos_published_results() -> None:
    """evo's stored results for ORB-SLAM on KITTI 00 (shared/data/README.md)."""
    ref = read_trajectory(EVO / "KITTI_00_gt.txt")
    est = read_trajectory(EVO / "KITTI_00_ORB.txt")
    r, e = associate(ref, est)
    aligned, _ = align(r, e, "se3")
    stats = error_stats(ape(r, aligned))
    assert stats["rmse"] == pytest.approx(1.3034497145650266, abs=1e-6)
    assert stats["mean"] == pytest.approx(1.1569971285389768, abs=1e-6)
    assert stats["median"] == pytest.approx(1.065624769555848, abs=1e-6)
    assert stats["max"] == pytest.approx(3.587949120678954, abs=1e-6)
    # The README's RPE (0.22626 m) is from an older evo that left out the first 10 m segment;
    # evo 1.38.1 includes it (evo_rpe kitti KITTI_00_gt.txt KITTI_00_ORB.txt --delta 10
    # --delta_unit m; see test_evo_parity.py).
    errors, _ = rpe(r, e, delta=10.0, unit="metres")
    assert error_stats(errors)["rmse"] == pytest.approx(0.23676346946465107, rel=1e-6)


def straight(n: int, step: float = 1.0, dt_ns: int = 100_000_000) -> Trajectory:
    p = np.column_stack([np.arange(n) * step, np.zeros(n), np.zeros(n)])
    return Trajectory(
        t_ns=np.arange(n) * dt_ns, p_W_B=p, q_W_B_xyzw=np.tile([0, 0, 0, 1.0], (n, 1))
    )


def test_rpe_pairs_in_frames_seconds_and_metres() -> None:
    tr = straight(11, step=0.5)
    i, j = rpe_pairs(tr, 2, "frames")
    assert list(zip(i, j, strict=True)) == [(0, 2), (2, 4), (4, 6), (6, 8), (8, 10)]
    i, j = rpe_pairs(tr, 2, "frames", all_pairs=True)
    assert len(i) == 9 and np.all(j - i == 2)
    i, j = rpe_pairs(tr, 0.3, "seconds")  # 0.1 s per pose: every third pose, from the first
    assert list(zip(i, j, strict=True)) == [(0, 3), (3, 6), (6, 9)]
    i, j = rpe_pairs(tr, 1.0, "metres")  # 0.5 m per pose: every second pose, from the first
    assert list(zip(i, j, strict=True)) == [(0, 2), (2, 4), (4, 6), (6, 8), (8, 10)]
    i, j = rpe_pairs(tr, 1.0, "metres", all_pairs=True)
    assert list(zip(i, j, strict=True))[:2] == [(0, 2), (1, 3)]
    with pytest.raises(EvalError):
        rpe_pairs(tr, 1.5, "frames")


def test_all_pairs_in_metres_take_the_first_of_tied_ends() -> None:
    # Standing still at poses 2-4 (x = 1 m): a 1 m step from pose 0 ties over 2, 3, 4; evo's
    # argmin takes the first. Equal misses go to the earlier pose.
    x = [0.0, 0.5, 1.0, 1.0, 1.0, 1.5, 2.0, 3.0]
    tr = Trajectory(
        t_ns=np.arange(len(x)),
        p_W_B=np.column_stack([x, np.zeros(len(x)), np.zeros(len(x))]),
        q_W_B_xyzw=np.tile([0, 0, 0, 1.0], (len(x), 1)),
    )
    i, j = rpe_pairs(tr, 1.0, "metres", all_pairs=True)
    pairs = dict(zip(i.tolist(), j.tolist(), strict=True))
    assert pairs[0] == 2  # not 3 or 4
    assert pairs[1] == 5  # 1.0 m from 0.5 m: pose 5 at 1.5 m
    assert pairs[2] == 6 and pairs[3] == 6 and pairs[4] == 6
    assert 5 not in pairs  # 2.0 m and 3.0 m are both 0.5 m off, beyond the 10 % tolerance
    i, j = rpe_pairs(tr, 1.0, "metres", all_pairs=True, rel_tol=0.5)
    assert dict(zip(i.tolist(), j.tolist(), strict=True))[5] == 6  # the tie goes to the earlier


def test_ape_and_rpe_of_known_errors() -> None:
    ref = straight(20)
    # A constant 0.1 rad yaw error and a 0.2 m offset in y.
    est = Trajectory(
        t_ns=ref.t_ns,
        p_W_B=ref.p_W_B + [0.0, 0.2, 0.0],
        q_W_B_xyzw=(Rotation.from_euler("z", 0.1) * ref.R_W_B).as_quat(),
    )
    np.testing.assert_allclose(ape(ref, est, "trans"), 0.2)
    np.testing.assert_allclose(ape(ref, est, "rot"), 0.1, atol=1e-12)
    # Relative motion: the estimate moves 1 m along its own yawed x each step, the reference along x.
    err, ends = rpe(ref, est, delta=1, unit="frames", relation="trans")
    np.testing.assert_allclose(err, 2 * np.sin(0.05), atol=1e-12)  # |R(-0.1) e_x - e_x|
    assert list(ends[:3]) == [1, 2, 3]
    assert error_stats(np.array([3.0, 4.0]))["rmse"] == pytest.approx(np.sqrt(12.5))


def test_nees_of_consistent_gaussian_errors_is_the_dimension() -> None:
    rng = np.random.default_rng(0)
    n = 20000
    A = rng.normal(size=(n, 3, 3))
    P = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(3)
    e = np.einsum("nij,nj->ni", np.linalg.cholesky(P), rng.normal(size=(n, 3)))
    assert nees(e, P).mean() == pytest.approx(3.0, rel=0.03)


def test_position_nees_uses_the_axes_with_variance() -> None:
    ref = straight(5)
    cov = np.zeros((5, 3, 3))
    cov[:, 0, 0] = cov[:, 2, 2] = 0.04
    est = Trajectory(
        t_ns=ref.t_ns, p_W_B=ref.p_W_B + [0.2, 5.0, 0.0], q_W_B_xyzw=ref.q_W_B_xyzw, cov_p=cov
    )
    np.testing.assert_allclose(position_nees(ref, est), 1.0)  # y has no variance: left out
    with pytest.raises(EvalError, match="no covariance"):
        position_nees(ref, ref)
