"""The VIO run's metrics on hand-made cases whose answer is known without the code."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.eval.na import is_na
from quadnav.eval.vio_metrics import (
    ApeSummary,
    NeesSummary,
    RpeSummary,
    RunCounts,
    drift_final_pct,
    gravity_error_deg,
    nees_band,
    pose_nees,
    pose_nees_parts,
    pose_nees_summary,
    vio_metrics,
)
from quadnav.geometry.trajectory import Trajectory

COUNTS = RunCounts(
    frames=100, failures=1, reinitializations=1, rejected_images=0, initialized_after_s=0.5
)


def _loop(n: int = 200, seconds: float = 20.0) -> Trajectory:
    """A body flying a wavy loop (x-y circle of 2 m radius, z going up and down), yawing."""
    t = np.linspace(0.0, seconds, n)
    p = np.column_stack([2 * np.cos(0.3 * t), 2 * np.sin(0.3 * t), 1.0 + 0.3 * np.sin(t)])
    R = Rotation.from_euler("zyx", np.column_stack([0.3 * t, 0.05 * np.sin(t), 0.02 * t]))
    return Trajectory(
        t_ns=(t * 1e9).astype(np.int64), p_W_B=p, q_W_B_xyzw=R.as_quat(), name="truth"
    )


def _moved(tr: Trajectory, yaw_deg: float, shift: tuple[float, float, float]) -> Trajectory:
    return tr.transformed(Rotation.from_euler("z", yaw_deg, degrees=True), np.array(shift))


def test_yawed_and_shifted_copy_has_zero_4dof_ape() -> None:
    truth = _loop()
    est = _moved(truth, 70.0, (3.0, -1.0, 0.5))
    m = vio_metrics(truth, est, COUNTS)
    assert isinstance(m.ape_4dof, ApeSummary) and isinstance(m.ape_sim3, ApeSummary)
    assert m.ape_4dof.rmse_m < 1e-9 and m.ape_4dof.max_m < 1e-9
    assert m.ape_sim3.scale == pytest.approx(1.0, abs=1e-9)
    assert isinstance(m.gravity_error_deg, float) and m.gravity_error_deg < 1e-6
    assert m.fraction_with_estimate == pytest.approx(2.0)  # 200 poses for 100 frames counted
    assert m.failures == 1 and m.reinitializations == 1


def test_known_height_offset_gives_its_ape() -> None:
    """Half the poses 5 cm too high, half 5 cm too low: no alignment can remove it (yaw and a
    translation take the mean out), so every pose is 5 cm off."""
    truth = _loop()
    p = truth.p_W_B.copy()
    p[:100, 2] += 0.05
    p[100:, 2] -= 0.05
    est = Trajectory(t_ns=truth.t_ns, p_W_B=p, q_W_B_xyzw=truth.q_W_B_xyzw)
    m = vio_metrics(truth, _moved(est, -30.0, (1.0, 2.0, 0.0)), COUNTS)
    assert isinstance(m.ape_4dof, ApeSummary)
    np.testing.assert_allclose(
        [m.ape_4dof.rmse_m, m.ape_4dof.mean_m, m.ape_4dof.median_m, m.ape_4dof.max_m],
        0.05,
        atol=1e-9,
    )


def _straight(seconds: float = 10.0, speed_m_s: float = 1.0, rate_hz: float = 20.0) -> Trajectory:
    t = np.arange(0.0, seconds + 1e-9, 1.0 / rate_hz)
    p = np.column_stack([speed_m_s * t, np.zeros_like(t), np.ones_like(t)])
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    return Trajectory(t_ns=np.round(t * 1e9).astype(np.int64), p_W_B=p, q_W_B_xyzw=q)


def test_final_drift_of_a_known_sideways_creep() -> None:
    """Exact for 2 s, then creeping sideways at 5 cm/s: 0.4 m off after 10 m, 4 %."""
    truth = _straight()
    t_s = truth.t_s
    p = truth.p_W_B.copy()
    p[:, 1] += 0.05 * np.maximum(t_s - 2.0, 0.0)
    est = _moved(Trajectory(t_ns=truth.t_ns, p_W_B=p, q_W_B_xyzw=truth.q_W_B_xyzw), 25.0, (5, 5, 0))
    assert drift_final_pct(truth, est, first_s=2.0) == pytest.approx(4.0, abs=1e-9)
    m = vio_metrics(truth, est, COUNTS, drift_first_s=2.0)
    assert m.final_error_m == pytest.approx(0.4, abs=1e-9)


def test_final_drift_aligns_a_start_at_rest() -> None:
    """A vehicle at rest for 2 s: the alignment comes from the attitudes, not the positions."""
    truth = _straight()
    p = truth.p_W_B.copy()
    p[:40, 0] = 0.0  # at rest for the first 2 s
    p[40:, 0] -= p[40, 0]
    truth = Trajectory(t_ns=truth.t_ns, p_W_B=p, q_W_B_xyzw=truth.q_W_B_xyzw)
    est = _moved(truth, 90.0, (1.0, 1.0, 1.0))
    assert drift_final_pct(truth, est, first_s=2.0) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("distance_m", [0.00003, 0.014, 0.99])
def test_no_drift_in_percent_under_a_metre_travelled(distance_m: float) -> None:
    """Issue 21, item 14: 297.94 % for a 0.03 mm path, 67 % for 1.4 cm at rest."""
    truth = _straight(seconds=10.0, speed_m_s=distance_m / 10.0)
    p = truth.p_W_B.copy()
    p[:, 1] += 0.001 * truth.t_s  # 1 cm off at the end
    m = vio_metrics(
        truth, Trajectory(t_ns=truth.t_ns, p_W_B=p, q_W_B_xyzw=truth.q_W_B_xyzw), COUNTS
    )
    assert is_na(m.drift_final_pct) and "1 m" in str(m.drift_final_pct)
    assert m.final_error_m == pytest.approx(0.01 - 0.001 * 1.0, abs=1e-3)  # still given, in m
    assert "n/a under 1 m travelled" in m.drift_definitions


def test_drift_in_percent_from_a_metre_travelled() -> None:
    truth = _straight(seconds=10.0, speed_m_s=0.11)  # 1.1 m
    p = truth.p_W_B.copy()
    p[-1, 1] += 0.022
    m = vio_metrics(
        truth, Trajectory(t_ns=truth.t_ns, p_W_B=p, q_W_B_xyzw=truth.q_W_B_xyzw), COUNTS
    )
    assert m.drift_final_pct == pytest.approx(2.0, abs=1e-6)


def test_rpe_drift_of_a_scale_error() -> None:
    """2 % too long a path: every 1 m of truth is 1.02 m estimated, 2 % of RPE drift."""
    truth = _straight(seconds=10.0)
    est = Trajectory(t_ns=truth.t_ns, p_W_B=truth.p_W_B * [1.02, 1, 1], q_W_B_xyzw=truth.q_W_B_xyzw)
    m = vio_metrics(truth, est, COUNTS)
    assert isinstance(m.rpe_1m, RpeSummary)
    # evo's all pairs keep the last starts' pairs up to 10 % short of 1 m (0.95, 0.9 m): their
    # error is 2 % of their length, which moves the mean by under 1e-4 m
    assert m.rpe_1m.trans_mean_m == pytest.approx(0.02, abs=1e-4)
    assert m.rpe_1m.trans_rmse_m <= 0.02 + 1e-12 and m.rpe_1m.rot_mean_deg < 1e-9
    assert is_na(m.rpe_10m)  # a 10 m path has no pairs 10 m apart with room to spare
    assert m.drift_rpe_pct == pytest.approx(2.0, abs=0.01)
    assert "1 m" in m.drift_definitions


def test_gravity_error_is_the_tilt_not_the_yaw() -> None:
    ref = Rotation.from_euler("z", 40.0, degrees=True)  # level: body x is horizontal
    est = (
        Rotation.from_euler("z", 123.0, degrees=True)
        * ref
        * Rotation.from_euler("x", 0.5, degrees=True)
    )
    assert gravity_error_deg(est, ref) == pytest.approx(0.5, abs=1e-9)


def _random_cov(rng: np.random.Generator) -> np.ndarray:
    A = rng.normal(size=(6, 6)) * np.array([0.02] * 3 + [0.05] * 3)
    return A @ A.T + np.diag([1e-4] * 3 + [4e-4] * 3)


def test_nees_of_known_gaussian_errors_is_one() -> None:
    """Errors drawn from the covariance the estimate claims: mean NEES / 6 near 1, inside the
    band, and 95 % of the frames inside one draw's band; a covariance 4x too small fails."""
    rng = np.random.default_rng(7)
    n = 4000
    cov = _random_cov(rng)
    xi = rng.multivariate_normal(np.zeros(6), cov, size=n)
    est = _moved(_loop(n=n, seconds=200.0), 0.0, (0, 0, 0))
    R_true = est.R_W_B * Rotation.from_rotvec(xi[:, :3])
    p_true = est.p_W_B + est.R_W_B.apply(xi[:, 3:])
    ref = Trajectory(t_ns=est.t_ns, p_W_B=p_true, q_W_B_xyzw=R_true.as_quat())
    s = pose_nees_summary(pose_nees(ref, est, np.broadcast_to(cov, (n, 6, 6))))
    assert s.band_low < s.mean_over_dof < s.band_high
    assert s.mean_over_dof == pytest.approx(1.0, abs=0.05)
    assert s.fraction_in_band == pytest.approx(0.95, abs=0.015)
    over = pose_nees_summary(pose_nees(ref, est, np.broadcast_to(cov / 4, (n, 6, 6))))
    assert over.mean_over_dof > over.band_high and over.mean_over_dof == pytest.approx(
        4.0, rel=0.06
    )


def test_nees_split_tells_an_overconfident_translation_from_an_honest_rotation() -> None:
    """Rotation errors as claimed, translation errors twice the claimed sigma: the pose NEES
    is the full one, the rotation's alone is 1 per dimension and the translation's 4."""
    rng = np.random.default_rng(11)
    n = 4000
    cov = np.diag([1e-4] * 3 + [4e-4] * 3)
    xi = rng.multivariate_normal(np.zeros(6), cov, size=n) * np.array([1.0] * 3 + [2.0] * 3)
    est = _moved(_loop(n=n, seconds=200.0), 0.0, (0, 0, 0))
    R_true = est.R_W_B * Rotation.from_rotvec(xi[:, :3])
    p_true = est.p_W_B + est.R_W_B.apply(xi[:, 3:])
    ref = Trajectory(t_ns=est.t_ns, p_W_B=p_true, q_W_B_xyzw=R_true.as_quat())
    parts = pose_nees_parts(ref, est, np.broadcast_to(cov, (n, 6, 6)))
    np.testing.assert_allclose(parts[:, 0], pose_nees(ref, est, np.broadcast_to(cov, (n, 6, 6))))
    assert parts[:, 1].mean() / 3 == pytest.approx(1.0, abs=0.06)
    assert parts[:, 2].mean() / 3 == pytest.approx(4.0, rel=0.06)
    # a diagonal covariance: the pose's NEES is the sum of its parts
    np.testing.assert_allclose(parts[:, 0], parts[:, 1] + parts[:, 2], rtol=1e-9)


def test_nees_band_of_one_sample_is_chi_square_6() -> None:
    lo, hi = nees_band(1)
    assert 6 * lo == pytest.approx(1.2373, abs=1e-3) and 6 * hi == pytest.approx(14.449, abs=1e-3)


def _drifting(truth: Trajectory, rng: np.random.Generator) -> tuple[Trajectory, np.ndarray]:
    """An estimate of ``truth`` as an odometry makes it: yaw and position drifting as random
    walks from its first pose, roll and pitch with independent errors, and the covariance that
    says so (the walks' variance grows by a step's each pose), in the estimate's body frame."""
    n = len(truth)
    s_yaw, s_p, s_rp = 0.002, 0.004, 0.003  # per step (rad, m) and roll/pitch (rad)
    yaw = np.cumsum(rng.normal(0.0, s_yaw, n))
    drift = np.cumsum(rng.normal(0.0, s_p, (n, 3)), axis=0)
    tilt = rng.normal(0.0, s_rp, (n, 2))
    err_W = Rotation.from_rotvec(np.column_stack([tilt, yaw]))  # R_ref = err_W * R_est
    R_est = err_W.inv() * truth.R_W_B
    est = Trajectory(t_ns=truth.t_ns, p_W_B=truth.p_W_B - drift, q_W_B_xyzw=R_est.as_quat())
    k = np.arange(1, n + 1, dtype=np.float64)
    cov_W = np.zeros((n, 6, 6))
    cov_W[:, 0, 0] = cov_W[:, 1, 1] = s_rp**2
    cov_W[:, 2, 2] = k * s_yaw**2
    for i in range(3, 6):
        cov_W[:, i, i] = k * s_p**2
    J = np.zeros((n, 6, 6))  # world = R_est * body, rotation and translation alike
    J[:, :3, :3] = J[:, 3:, 3:] = R_est.as_matrix()
    return est, np.einsum("nji,njk,nkl->nil", J, cov_W, J)


def test_run_metrics_hold_an_odometry_drifting_from_its_first_pose() -> None:
    """An estimate whose yaw and position drift from its first pose, told so by a covariance
    that grows with the drift, and moved by an arbitrary yaw and shift (its own gauge): its
    NEES / 6 is 1 over many runs. Aligned over the whole run instead, the mean drift taken
    off would leave the first poses with errors their small covariance cannot hold."""
    rng = np.random.default_rng(3)
    truth = _loop(n=300, seconds=30.0)
    means = []
    for _ in range(30):
        est, cov = _drifting(truth, rng)
        m = vio_metrics(truth, _moved(est, 45.0, (2, 0, 1)), COUNTS, cov_pose=cov)
        assert isinstance(m.nees_pose, NeesSummary)
        means.append(m.nees_pose.mean_over_dof)
    assert 0.85 < float(np.mean(means)) < 1.15, means


def test_an_odometry_whose_world_is_its_first_pose_is_aligned_on_all_of_it() -> None:
    """A SLAM's world is its first camera's pose, tilted: errors drawn from the covariance it
    claims, its world turned 20 degrees about x and shifted. Aligned on the whole first pose
    (``levelled=False``) its NEES / 6 is 1; aligned in yaw and position only, the tilt counts
    as error."""
    rng = np.random.default_rng(11)
    n = 2000
    cov = _random_cov(rng) / 25
    xi = rng.multivariate_normal(np.zeros(6), cov, size=n)
    xi[0] = 0.0  # (the gauge: the first pose is the world's)
    est = _loop(n=n, seconds=200.0)
    R_true = est.R_W_B * Rotation.from_rotvec(xi[:, :3])
    p_true = est.p_W_B + est.R_W_B.apply(xi[:, 3:])
    ref = Trajectory(t_ns=est.t_ns, p_W_B=p_true, q_W_B_xyzw=R_true.as_quat())
    tilted = est.transformed(Rotation.from_euler("x", 20.0, degrees=True), np.array([1.0, 2, 3]))
    covs = np.broadcast_to(cov, (n, 6, 6))
    whole = vio_metrics(ref, tilted, COUNTS, cov_pose=covs, levelled=False).nees_pose
    four = vio_metrics(ref, tilted, COUNTS, cov_pose=covs).nees_pose
    assert isinstance(whole, NeesSummary) and isinstance(four, NeesSummary)
    assert whole.mean_over_dof == pytest.approx(1.0, abs=0.08)
    assert four.mean_over_dof > 100.0


def test_no_ground_truth_says_why_and_keeps_the_counts() -> None:
    m = vio_metrics(None, _loop(n=50), COUNTS)
    assert is_na(m.ape_4dof) and "no ground truth" in str(m.ape_4dof)
    assert is_na(m.drift_final_pct) and is_na(m.nees_pose)
    assert m.frames_with_estimate == 50 and m.failures == 1


def test_a_handful_of_poses_is_not_scored() -> None:
    """An estimator that starts at the end of a span gives 2 poses, which any 4-DoF alignment
    fits exactly: the run says so instead of an ATE of 0."""
    truth = _loop(n=9)
    m = vio_metrics(truth, _moved(truth, 10.0, (0.1, 0.2, 0.3)), COUNTS)
    assert is_na(m.ape_4dof) and "only 9 estimated pose(s)" in str(m.ape_4dof)
    assert is_na(m.final_error_m) and m.frames_with_estimate == 9
