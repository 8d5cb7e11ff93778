from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import GeometryError
from quadnav.geometry import Trajectory, geodesic_angle_rad


def line(n: int = 5) -> Trajectory:
    t = np.arange(n, dtype=np.int64) * 1_000_000_000
    p = np.column_stack([np.arange(n), np.zeros(n), np.zeros(n)]).astype(float)
    q = Rotation.from_euler("z", np.linspace(0, 0.4 * (n - 1), n)[:, None]).as_quat()
    return Trajectory(t_ns=t, p_W_B=p, q_W_B_xyzw=q, name="line")


def test_interpolation_is_linear_in_position_and_slerp_in_attitude() -> None:
    tr = line()
    mid = tr.interpolate(np.array([500_000_000, 2_250_000_000]))
    np.testing.assert_allclose(mid.p_W_B[:, 0], [0.5, 2.25], atol=1e-12)
    expected = Rotation.from_euler("z", [[0.2], [0.9]])
    assert np.all(geodesic_angle_rad(mid.R_W_B, expected) < 1e-12)
    with pytest.raises(GeometryError, match="outside"):
        tr.interpolate(np.array([5_000_000_000]))


def test_validation() -> None:
    tr = line()
    with pytest.raises(GeometryError, match="increase"):
        Trajectory(t_ns=tr.t_ns[::-1].copy(), p_W_B=tr.p_W_B, q_W_B_xyzw=tr.q_W_B_xyzw)
    with pytest.raises(GeometryError, match="finite"):
        Trajectory(t_ns=tr.t_ns, p_W_B=np.full((5, 3), np.nan), q_W_B_xyzw=tr.q_W_B_xyzw)
    with pytest.raises(GeometryError, match="integer"):
        Trajectory(t_ns=tr.t_ns * 1.0, p_W_B=tr.p_W_B, q_W_B_xyzw=tr.q_W_B_xyzw)
    with pytest.raises(GeometryError, match="zero"):
        Trajectory(t_ns=tr.t_ns, p_W_B=tr.p_W_B, q_W_B_xyzw=np.zeros((5, 4)))
    # Quaternions are normalised on the way in.
    t2 = Trajectory(t_ns=tr.t_ns, p_W_B=tr.p_W_B, q_W_B_xyzw=2 * tr.q_W_B_xyzw)
    np.testing.assert_allclose(np.linalg.norm(t2.q_W_B_xyzw, axis=1), 1.0)


def test_transformed_applies_a_similarity_and_round_trips_matrices() -> None:
    tr = line()
    R = Rotation.from_euler("xyz", [0.1, -0.2, 0.3])
    out = tr.transformed(R, np.array([1.0, 2.0, 3.0]), 2.0)
    np.testing.assert_allclose(out.p_W_B, 2.0 * R.apply(tr.p_W_B) + [1.0, 2.0, 3.0], atol=1e-12)
    assert np.all(geodesic_angle_rad(out.R_W_B, R * tr.R_W_B) < 1e-12)
    back = Trajectory.from_matrices(tr.t_ns, tr.matrices())
    np.testing.assert_allclose(back.p_W_B, tr.p_W_B)
    assert np.all(geodesic_angle_rad(back.R_W_B, tr.R_W_B) < 1e-12)
    assert tr.path_length_m() == pytest.approx(4.0)
