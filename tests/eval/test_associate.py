from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import EvalError
from quadnav.eval import associate
from quadnav.geometry import Trajectory


def traj(t_ns, *, timed: bool = True, name: str = "") -> Trajectory:
    t = np.asarray(t_ns, dtype=np.int64)
    x = t * 1e-9  # position x equals time in seconds: easy to check pairing
    return Trajectory(
        t_ns=t,
        p_W_B=np.column_stack([x, np.zeros_like(x), np.zeros_like(x)]),
        q_W_B_xyzw=np.tile([0, 0, 0, 1.0], (len(t), 1)),
        timed=timed,
        name=name,
    )


def test_nearest_neighbour_within_max_diff_and_one_to_one() -> None:
    ref = traj(np.arange(0, 10) * 100_000_000)  # 10 Hz
    est = traj([5_000_000, 98_000_000, 103_000_000, 450_000_000, 2_000_000_000])
    r, e = associate(ref, est, t_max_diff_s=0.01)
    # 98 ms and 103 ms both claim the 100 ms pose: the closer (98 ms) keeps it; 450 ms is too far.
    assert list(e.t_ns) == [5_000_000, 98_000_000]
    assert list(r.t_ns) == [0, 100_000_000]


def test_offset_shifts_the_estimate() -> None:
    ref = traj(np.arange(0, 10) * 100_000_000)
    est = traj(np.arange(0, 10) * 100_000_000 + 1_000_000_000)
    with pytest.raises(EvalError, match="no overlapping time"):
        associate(ref, est)
    r, e = associate(ref, est, t_offset_s=-1.0)
    assert len(r) == 10
    np.testing.assert_array_equal(r.t_ns, e.t_ns)


def test_interpolation_evaluates_the_reference_at_estimate_times() -> None:
    ref = traj(np.arange(0, 11) * 100_000_000)
    est = traj([50_000_000, 125_000_000, 990_000_000, 1_200_000_000])
    r, e = associate(ref, est, t_max_diff_s=0.06, interpolate=True)
    assert list(e.t_ns) == [50_000_000, 125_000_000, 990_000_000]  # 1.2 s is outside the reference
    np.testing.assert_allclose(r.p_W_B[:, 0], [0.05, 0.125, 0.99], atol=1e-12)
    np.testing.assert_array_equal(r.t_ns, e.t_ns)


def test_untimed_trajectories_pair_by_index() -> None:
    a, b = traj(np.arange(5), timed=False), traj(np.arange(5), timed=False)
    r, e = associate(a, b)
    assert len(r) == len(e) == 5
    with pytest.raises(EvalError, match="pair by index"):
        associate(a, traj(np.arange(4), timed=False))
    with pytest.raises(EvalError, match="one trajectory has timestamps"):
        associate(a, traj(np.arange(5)))


def test_rotation_is_slerped() -> None:
    ref = Trajectory(
        t_ns=np.array([0, 1_000_000_000]),
        p_W_B=np.zeros((2, 3)),
        q_W_B_xyzw=Rotation.from_euler("z", [[0.0], [1.0]]).as_quat(),
    )
    r, _ = associate(ref, traj([250_000_000]), t_max_diff_s=1.0, interpolate=True)
    assert r.R_W_B[0].as_euler("xyz")[2] == pytest.approx(0.25)
