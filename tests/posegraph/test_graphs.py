"""The 4-DoF, SE(3) and Sim(3) graphs on a simulated drifting odometry round a loop (5 seeds):
loop edges bring the error well below the drift, a false loop is down-weighted by the robust
kernel, roll and pitch stay the odometry's in the 4-DoF graph, the first keyframe stays put; bad
input is a one-line error."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import PoseGraphError, QuadnavError
from quadnav.geometry.rotations import Pose
from quadnav.posegraph import (
    LoopEdge,
    PoseGraphConfig,
    PoseGraphProblem,
    PoseGraphResult,
    anchors,
    build_graph,
    levenberg_marquardt,
    sequential_covariances,
    solve,
    split_yaw,
)
from quadnav.posegraph.simulate import DriftingLoop, drifting_loop, position_rmse

SEEDS = range(5)
N = 200
CONFIGS = {
    "4dof native": PoseGraphConfig(kind="4dof", four_dof_factor="native"),
    "4dof custom": PoseGraphConfig(kind="4dof", four_dof_factor="custom"),
    "se3": PoseGraphConfig(kind="se3"),
    "sim3": PoseGraphConfig(kind="sim3"),
}


def _loop(seed: int) -> DriftingLoop:
    return drifting_loop(np.random.default_rng(seed), keyframes=N, per_lap=100, loops=5)


def _solve(
    d: DriftingLoop, config: PoseGraphConfig, loops: tuple[LoopEdge, ...] | None = None
) -> PoseGraphResult:
    return solve(
        PoseGraphProblem.from_poses(
            range(N), d.odometry, d.loops if loops is None else loops, config=config
        )
    )


@pytest.mark.parametrize("name", CONFIGS)
def test_loop_edges_bring_the_error_well_below_the_drift(name: str) -> None:
    ratios = []
    for seed in SEEDS:
        d = _loop(seed)
        ratios.append(
            position_rmse(_solve(d, CONFIGS[name]).poses, d.truth)
            / position_rmse(d.odometry, d.truth)
        )
    # the first lap keeps its own drift (its loops tie later laps to it): about half goes
    assert np.mean(ratios) < 0.6, ratios
    assert max(ratios) < 0.8, ratios


@pytest.mark.parametrize("name", ["4dof native", "4dof custom", "se3"])
def test_a_false_loop_is_down_weighted_by_the_robust_kernel(name: str) -> None:
    false = LoopEdge(old=20, new=170, T_old_new=Pose.identity())  # two places 10 m apart
    for seed in SEEDS:
        d = _loop(seed)
        robust = _solve(d, CONFIGS[name], (*d.loops, false))
        plain = _solve(
            d,
            PoseGraphConfig(
                kind=CONFIGS[name].kind,
                four_dof_factor=CONFIGS[name].four_dof_factor,
                robust="none",
            ),
            (*d.loops, false),
        )
        drift = position_rmse(d.odometry, d.truth)
        assert position_rmse(plain.poses, d.truth) > 3 * drift  # without a kernel it bends the map
        assert position_rmse(robust.poses, d.truth) < drift  # with one, the true loops still win
        assert robust.loop_chi[-1] > 10 * robust.loop_chi[:-1].max()  # and it stands out


@pytest.mark.parametrize("name", ["4dof native", "4dof custom"])
def test_four_dof_graph_keeps_roll_and_pitch(name: str) -> None:
    d = _loop(0)
    result = _solve(d, CONFIGS[name])
    moved = 0.0
    for odo, corrected in zip(d.odometry, result.poses, strict=True):
        yaw_o, tilt_o = split_yaw(odo.R_A_B.as_matrix())
        yaw_c, tilt_c = split_yaw(corrected.R_A_B.as_matrix())
        np.testing.assert_allclose(tilt_c, tilt_o, atol=1e-12)
        moved = max(moved, abs(np.remainder(yaw_c - yaw_o + np.pi, 2 * np.pi) - np.pi))
    assert moved > 0.01  # while the yaw was corrected


@pytest.mark.parametrize("name", CONFIGS)
def test_first_keyframe_is_held(name: str) -> None:
    d = _loop(1)
    first = _solve(d, CONFIGS[name]).poses[0]
    np.testing.assert_allclose(first.p_A_B, d.odometry[0].p_A_B, atol=1e-5)  # held by a 1e-6 prior
    assert (first.R_A_B.inv() * d.odometry[0].R_A_B).magnitude() < 1e-5


def test_native_and_custom_four_dof_agree() -> None:
    """The two mechanisms minimise the same error to first order: their solutions differ by
    little against the correction they make."""
    for seed in SEEDS:
        d = _loop(seed)
        a = _solve(d, CONFIGS["4dof native"]).positions()
        b = _solve(d, CONFIGS["4dof custom"]).positions()
        correction = np.abs(a - np.array([p.p_A_B for p in d.odometry])).max()
        assert np.abs(a - b).max() < 0.15 * correction


def test_sim3_graph_follows_a_scale_drift() -> None:
    """An odometry whose scale drifts from 1 to 0.8 over the second lap, loops measured with
    their scale ratio: the Sim(3) graph's scales follow the drift (1 / c) and its loops fit,
    which the SE(3) graph's cannot."""
    for seed in SEEDS:
        d = _loop(seed)
        c = np.concatenate([np.ones(100), np.linspace(1.0, 0.8, 100)])
        odo = [d.odometry[0]]
        for k in range(1, N):
            step = d.odometry[k].p_A_B - d.odometry[k - 1].p_A_B
            odo.append(Pose(d.odometry[k].R_A_B, odo[-1].p_A_B + c[k] * step))
        loops = tuple(
            LoopEdge(old=e.old, new=e.new, T_old_new=e.T_old_new, scale=c[e.old] / c[e.new])
            for e in d.loops
        )
        sim3 = solve(PoseGraphProblem.from_poses(range(N), odo, loops, config=CONFIGS["sim3"]))
        se3 = solve(PoseGraphProblem.from_poses(range(N), odo, loops, config=CONFIGS["se3"]))
        assert sim3.scales is not None and se3.scales is None
        assert np.abs(sim3.scales * c - 1).max() < 0.08  # a 20 % drift followed within 8 %
        assert sim3.loop_chi.max() < se3.loop_chi.max() / 3


def test_each_odometry_frame_is_anchored_until_a_loop_joins_it() -> None:
    d = _loop(3)
    rc = [0] * 100 + [1] * 100  # the odometry restarted at keyframe 100
    apart = PoseGraphProblem.from_poses(range(N), d.odometry, (), reset_counters=rc)
    assert anchors(apart) == [0, 100]
    result = solve(apart)
    np.testing.assert_allclose(result.positions(), [p.p_A_B for p in d.odometry], atol=1e-5)
    joined = PoseGraphProblem.from_poses(range(N), d.odometry, d.loops, reset_counters=rc)
    assert anchors(joined) == [0]


def test_bad_input_is_a_one_line_error() -> None:
    d = _loop(0)
    nan = Pose(Rotation.from_rotvec([np.nan, 0.0, 0.0]), np.zeros(3))
    cases = [
        lambda: PoseGraphProblem.from_poses([0, 1], [d.odometry[0], nan]),
        lambda: PoseGraphProblem.from_poses(
            [0, 1], d.odometry[:2], [LoopEdge(old=0, new=7, T_old_new=Pose.identity())]
        ),
        lambda: PoseGraphProblem.from_poses([1, 0], d.odometry[:2]),
        lambda: LoopEdge(
            old=0, new=1, T_old_new=Pose.identity(), cov=np.diag([1.0, 1.0, -1.0, 1.0])
        ),
        lambda: LoopEdge(old=0, new=1, T_old_new=Pose.identity(), cov=np.ones((4, 4))),
        lambda: LoopEdge(old=0, new=1, T_old_new=nan),
        lambda: solve(
            PoseGraphProblem.from_poses(
                [0, 1],
                d.odometry[:2],
                [LoopEdge(old=0, new=1, T_old_new=Pose.identity(), cov=np.eye(6))],
            )
        ),
        lambda: PoseGraphConfig(loop_sigma_m=0.0),
        lambda: PoseGraphProblem.from_poses([0, 1], d.odometry[:2], step_var=[0.0, np.nan]),
        lambda: PoseGraphProblem.from_poses([0, 1], d.odometry[:2], step_var=[0.0, -1e-4]),
        lambda: PoseGraphProblem.from_poses([0, 1], d.odometry[:2], step_var=[0.0]),
    ]
    for case in cases:
        with pytest.raises(PoseGraphError) as err:
            case()
        assert isinstance(err.value, QuadnavError) and "\n" not in str(err.value)


def test_a_loop_covariance_weights_the_edge() -> None:
    """A loop given a covariance ten times tighter than the sequential chain pulls harder."""
    d = _loop(4)
    loose = tuple(
        LoopEdge(old=e.old, new=e.new, T_old_new=e.T_old_new, cov=np.diag([1.0, 1.0, 1.0, 0.1]))
        for e in d.loops
    )
    tight = tuple(
        LoopEdge(old=e.old, new=e.new, T_old_new=e.T_old_new, cov=np.diag([1e-4, 1e-4, 1e-4, 1e-5]))
        for e in d.loops
    )
    cfg = PoseGraphConfig(robust="none")
    err_loose = position_rmse(_solve(d, cfg, loose).poses, d.truth)
    err_tight = position_rmse(_solve(d, cfg, tight).poses, d.truth)
    assert err_tight < 0.7 * err_loose


def test_our_levenberg_marquardt_reaches_gtsams_minimum() -> None:
    """The custom graph's Python-driven solver against GTSAM's own optimiser on the same graph."""
    for seed in SEEDS:
        d = drifting_loop(np.random.default_rng(seed), keyframes=120, per_lap=50, loops=3)
        problem = PoseGraphProblem.from_poses(
            range(120), d.odometry, d.loops, config=CONFIGS["4dof custom"]
        )
        graph, initial, _, _ = build_graph(problem)
        ours, _ = levenberg_marquardt(graph, initial, 50, relative_tol=1e-10, absolute_tol=1e-10)
        params = gtsam.LevenbergMarquardtParams()
        params.setRelativeErrorTol(1e-10)
        params.setAbsoluteErrorTol(1e-10)
        theirs = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
        assert graph.error(ours) == pytest.approx(graph.error(theirs), rel=1e-6)
        for k in range(120):
            np.testing.assert_allclose(ours.atVector(k), theirs.atVector(k), atol=1e-5)


def test_the_odometrys_variance_growth_loosens_the_sequential_edges() -> None:
    """Two edges a keyframe (harmonic number 1 + 1/2 = 1.5), 1 cm a step: a step whose
    variance grew by 4e-4 m^2 counts 6e-4 (1.5 times), one that grew by less than the 1e-4 the
    config allows counts 1e-4; an edge spans the steps between its keyframes. The yaw keeps the
    config's sigma, and without the growth every step is the config's."""
    cfg = PoseGraphConfig(
        sequential_edges=2, sequential_sigma_m=0.01, sequential_sigma_yaw_rad=0.002
    )
    d = _loop(0)
    poses = d.odometry[:4]
    grown = PoseGraphProblem.from_poses(
        range(4), poses, config=cfg, step_var=[0.0, 4e-4, 0.0, 2e-5]
    )
    got = {(i, j): np.diag(c) for i, j, _, c in sequential_covariances(grown)}
    assert set(got) == {(0, 1), (1, 2), (0, 2), (2, 3), (1, 3)}
    expect_m2 = {(0, 1): 6e-4, (1, 2): 1e-4, (0, 2): 7e-4, (2, 3): 1e-4, (1, 3): 2e-4}
    for edge, var in expect_m2.items():
        np.testing.assert_allclose(got[edge][:3], var, rtol=1e-12)
        k = edge[1] - edge[0]
        np.testing.assert_allclose(got[edge][3], k * 0.002**2, rtol=1e-12)
    plain = PoseGraphProblem.from_poses(range(4), poses, config=cfg)
    for _i, _j, k, c in sequential_covariances(plain):
        np.testing.assert_allclose(np.diag(c), [k * 1e-4] * 3 + [k * 0.002**2], rtol=1e-12)
    se3 = PoseGraphConfig(kind="se3", sequential_edges=2, sequential_sigma_m=0.01)
    six = sequential_covariances(
        PoseGraphProblem.from_poses(range(4), poses, config=se3, step_var=[0.0, 4e-4, 0.0, 0.0])
    )
    first = np.diag(six[0][3])
    np.testing.assert_allclose(first[3:], 6e-4, rtol=1e-12)  # the translation's, after rotation
    np.testing.assert_allclose(first[:3], se3.sequential_sigma_rot_rad**2, rtol=1e-12)
