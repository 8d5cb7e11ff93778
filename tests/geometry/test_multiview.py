"""The shared multi-view geometry: each function against a scene whose answer is known by
construction (random cameras and points), with noise and outliers where the function is meant to
survive them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import GeometryError
from quadnav.geometry import Pose, geodesic_angle_rad
from quadnav.geometry.multiview import (
    essential_pose,
    kabsch,
    nearest_rotation,
    pnp,
    projection,
    reprojection_errors,
    triangulate,
    triangulate_track,
)


def _scene(rng: np.random.Generator, n: int = 80) -> tuple[Pose, Pose, np.ndarray]:
    """Two cameras 0.4 m apart looking at points 3-8 m ahead of the first (world = camera a)."""
    T_W_Ca = Pose.identity()
    T_W_Cb = Pose(
        Rotation.from_rotvec(rng.normal(0, 0.1, 3)),
        np.array([0.4, 0.05, 0.1]) + rng.normal(0, 0.02, 3),
    )
    pts = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(3, 8, n)])
    return T_W_Ca, T_W_Cb, pts


def _see(T_W_C: Pose, pts: np.ndarray) -> np.ndarray:
    c = T_W_C.inverse() @ pts
    return np.asarray(c[:, :2] / c[:, 2:3])


def test_nearest_rotation_projects_onto_so3() -> None:
    rng = np.random.default_rng(1)
    R = Rotation.from_rotvec([0.3, -0.4, 1.1]).as_matrix()
    got = nearest_rotation(R + rng.normal(0, 1e-4, (3, 3)))
    assert np.allclose(got @ got.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(got) == pytest.approx(1.0, abs=1e-12)
    assert np.abs(got - R).max() < 5e-4
    # a reflection is not returned: the determinant stays +1
    assert np.linalg.det(nearest_rotation(np.diag([1.0, 1.0, -1.0]))) == pytest.approx(1.0)
    with pytest.raises(GeometryError, match="finite 3x3"):
        nearest_rotation(np.full((3, 3), np.nan))


def test_kabsch_recovers_rotations_batched_and_refuses_reflections() -> None:
    rng = np.random.default_rng(2)
    Rs = Rotation.random(4, random_state=3)
    src = rng.normal(size=(4, 30, 3))
    dst = np.einsum("mij,mnj->mni", Rs.as_matrix(), src) + rng.normal(0, 1e-3, (4, 30, 3))
    got, sv = kabsch(src, dst)
    for m in range(4):
        assert geodesic_angle_rad(Rotation.from_matrix(got[m]), Rs[m]) < 1e-3
    assert sv.shape == (4, 3) and np.all(sv[:, 2] > 0)
    # points mirrored through a plane: the best proper rotation, not the reflection
    flat = rng.normal(size=(20, 3)) * [1.0, 1.0, 0.0]
    mirrored = flat * [1.0, 1.0, -1.0]
    R, _ = kabsch(flat, mirrored)
    assert np.linalg.det(R) == pytest.approx(1.0)
    assert np.allclose(flat @ R.T, mirrored, atol=1e-9)  # a plane's mirror is a rotation of it


@pytest.mark.parametrize("seed", range(5))
def test_essential_pose_survives_noise_and_outliers(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T_W_Ca, T_W_Cb, pts = _scene(rng)
    xa, xb = _see(T_W_Ca, pts), _see(T_W_Cb, pts)
    f = 460.0
    xa += rng.normal(0, 0.5 / f, xa.shape)
    xb += rng.normal(0, 0.5 / f, xb.shape)
    bad = rng.choice(len(xb), 16, replace=False)  # 20 % of gross mismatches
    xb[bad] += rng.uniform(-0.2, 0.2, (16, 2))
    two = essential_pose(xa, xb, threshold=1.5 / f)
    assert two is not None
    T_true = T_W_Ca.inverse() @ T_W_Cb
    assert geodesic_angle_rad(two.T_Ca_Cb.R_A_B, T_true.R_A_B) < np.radians(0.5)
    dir_true = T_true.p_A_B / np.linalg.norm(T_true.p_A_B)
    assert np.linalg.norm(two.T_Ca_Cb.p_A_B) == pytest.approx(1.0)
    assert float(two.T_Ca_Cb.p_A_B @ dir_true) > np.cos(np.radians(3.0))
    assert not two.inliers[bad].any() or two.inliers[bad].mean() < 0.2
    # the same input and seed give the same answer
    again = essential_pose(xa, xb, threshold=1.5 / f)
    assert again is not None and np.array_equal(again.inliers, two.inliers)


def test_essential_pose_wants_enough_points() -> None:
    rng = np.random.default_rng(0)
    T_W_Ca, T_W_Cb, pts = _scene(rng, n=8)
    assert essential_pose(_see(T_W_Ca, pts), _see(T_W_Cb, pts), threshold=1e-3) is None
    with pytest.raises(GeometryError, match="finite"):
        essential_pose(np.full((20, 2), np.nan), np.zeros((20, 2)), threshold=1e-3)


def test_triangulate_many_views_and_depths() -> None:
    rng = np.random.default_rng(4)
    T_W_Ca, T_W_Cb, pts = _scene(rng, n=50)
    T_W_Cc = Pose(Rotation.from_rotvec([0.0, 0.05, 0.0]), np.array([-0.3, 0.2, 0.0]))
    views = [T_W_Ca, T_W_Cb, T_W_Cc]
    xy = np.stack([_see(T, pts) for T in views], axis=1)
    got, z = triangulate(xy, np.array([projection(T) for T in views]))
    assert np.allclose(got, pts, atol=1e-8)
    assert np.allclose(z[:, 0], pts[:, 2], atol=1e-8)
    assert np.all(z > 0)
    one = triangulate_track(
        {7: xy[3, 0], 9: xy[3, 1]}, {7: projection(T_W_Ca), 9: projection(T_W_Cb)}
    )
    assert one is not None and np.allclose(one, pts[3], atol=1e-8)
    assert triangulate_track({7: xy[3, 0]}, {7: projection(T_W_Ca)}) is None


def test_triangulate_refuses_a_single_view() -> None:
    P = projection(Pose.identity())
    with pytest.raises(GeometryError, match="N, V >= 2"):
        triangulate(np.zeros((3, 1, 2)), np.array([P]))


def test_reprojection_errors_mark_points_behind_the_camera() -> None:
    P = projection(Pose.identity())
    X = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, -2.0], [0.2, 0.0, 1.0]])
    err, z = reprojection_errors(P, X, np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]))
    assert err[0] == 0.0 and np.isinf(err[1]) and err[2] == pytest.approx(0.2)
    assert np.allclose(z, [2.0, -2.0, 1.0])


@pytest.mark.parametrize("seed", range(3))
def test_pnp_from_a_guess_and_by_ransac(seed: int) -> None:
    rng = np.random.default_rng(seed)
    _, T_W_Cb, pts = _scene(rng)
    xy = _see(T_W_Cb, pts) + rng.normal(0, 0.5 / 460.0, (len(pts), 2))
    guess = Pose(T_W_Cb.R_A_B * Rotation.from_rotvec([0.02, -0.02, 0.01]), T_W_Cb.p_A_B + 0.05)
    res = pnp(pts, xy, guess=guess)
    assert res is not None
    assert np.linalg.norm(res.T_W_C.p_A_B - T_W_Cb.p_A_B) < 0.02
    assert geodesic_angle_rad(res.T_W_C.R_A_B, T_W_Cb.R_A_B) < np.radians(0.2)
    bad = rng.choice(len(xy), 24, replace=False)  # 30 % outliers
    xy[bad] += rng.uniform(-0.3, 0.3, (24, 2))
    rr = pnp(pts, xy, ransac_threshold=2.0 / 460.0)
    assert rr is not None
    assert np.linalg.norm(rr.T_W_C.p_A_B - T_W_Cb.p_A_B) < 0.03
    assert rr.inliers[bad].mean() < 0.2 and rr.inliers.sum() >= 0.6 * len(xy)
    with pytest.raises(GeometryError, match="ransac_threshold"):
        pnp(pts, xy)
    assert pnp(pts[:5], xy[:5], guess=guess) is None


def test_gtsam_pose_round_trip() -> None:
    from quadnav.geometry.gtsam_bridge import pose3, to_pose

    P = Pose(Rotation.from_rotvec([0.3, -1.2, 2.0]), np.array([1.0, 2.0, 3.0]))
    back = to_pose(pose3(P))
    assert np.allclose(back.matrix(), P.matrix(), atol=1e-12)
    back.inverse()  # a writable position: SciPy's apply refuses read-only buffers


def test_the_pnp_covariance_matches_the_spread_of_poses_over_noise_draws() -> None:
    """Monte Carlo: poses fitted to 40 points under 1 px of noise scatter as the covariance says."""
    from quadnav.geometry.multiview import pnp, pnp_covariance

    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(-2, 2, 40), rng.uniform(-1.5, 1.5, 40), rng.uniform(3, 7, 40)])
    T = Pose(Rotation.from_rotvec([0.05, -0.1, 0.02]), np.array([0.1, -0.2, 0.3]))
    c = (X - T.p_A_B) @ T.R_A_B.as_matrix()
    clean = c[:, :2] / c[:, 2:]
    sigma = 1.0 / 460.0
    errs, covs = [], []
    for _ in range(200):
        xy = clean + rng.normal(0, sigma, clean.shape)
        fit = pnp(X, xy, guess=T)
        assert fit is not None
        d = fit.T_W_C
        errs.append(np.r_[(d.R_A_B * T.R_A_B.inv()).as_rotvec(), d.p_A_B - T.p_A_B])
        covs.append(pnp_covariance(d, X, xy))
    E = np.array(errs)
    nees = np.mean([e @ np.linalg.solve(C, e) for e, C in zip(E, covs, strict=True)]) / 6
    assert 0.7 < nees < 1.4, nees
    spread = np.sqrt(np.diag(np.cov(E.T)))
    said = np.sqrt(np.diag(np.mean(covs, axis=0)))
    assert np.all(np.abs(spread / said - 1) < 0.3), (spread, said)


def test_parallax_is_the_widest_angle_between_the_rays() -> None:
    from quadnav.geometry.multiview import parallax_rad

    p = np.array([0.0, 0.0, 10.0])
    two = np.array([[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0]])
    assert parallax_rad(p, two) == pytest.approx(2 * np.arctan(0.5 / 10.0), rel=1e-12)
    three = np.vstack([two, [[0.1, 0.0, 0.0]]])  # a middle view widens nothing
    assert parallax_rad(p, three) == pytest.approx(parallax_rad(p, two), rel=1e-12)
    assert parallax_rad(p, two[:1]) == 0.0  # one view: no parallax
    assert parallax_rad(p, np.vstack([two, [p]])) == 0.0  # a camera at the point: none either
