"""Loop closure over an odometry that drifts: a revisited place is recognised, verified and
closed, and the corrected keyframes are far nearer the truth than the odometry's."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np
import pytest

from quadnav.geometry.rotations import Pose
from quadnav.geometry.trajectory import Trajectory
from quadnav.loop import LoopClosure, LoopConfig
from quadnav.messages import ImageFrame
from quadnav.odometry import KeyframeStep, LoopConstraint
from quadnav.posegraph import PoseGraphConfig
from tests.loop.drifting import CAMERA, FOCAL_PX, PER_LAP, T_B_C, DriftingOdometry

#: the graph told the simulated odometry's own drift per keyframe
LOOP = LoopConfig(
    executor="thread",
    graph=PoseGraphConfig(sequential_sigma_m=0.015, sequential_sigma_yaw_rad=0.006,
                          loop_sigma_m=0.02, loop_sigma_yaw_rad=0.01),
)  # fmt: skip


def _frame(k: int) -> ImageFrame:
    return ImageFrame(t_ns=k * 200_000_000, camera="cam0", load=lambda: np.zeros((8, 8), np.uint8))


def _fly_laps(loop: LoopClosure, odo: DriftingOdometry) -> list[tuple[int, int]]:
    """Every frame of ``odo`` through ``loop``, then its last keyframes; the loops it closed
    between the two laps."""
    for k in range(len(odo.truth)):
        loop.push(_frame(k))
    loop.keyframes(final=True)
    return [(o, n) for o, n in loop.stats.loops if (o < PER_LAP) != (n < PER_LAP)]


def _rmse(poses: Sequence[Pose], truth: Sequence[Pose]) -> float:
    d = np.array([p.p_A_B - t.p_A_B for p, t in zip(poses, truth, strict=True)])
    return float(np.sqrt((d**2).sum(axis=1).mean()))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_revisit_is_closed_and_the_keyframes_corrected(seed: int) -> None:
    odo = DriftingOdometry(seed)
    loop = LoopClosure(odo, CAMERA, config=LOOP)
    try:
        outputs = []
        for k in range(len(odo.truth)):
            st = loop.push(_frame(k))
            assert st is not None
            outputs.append(st)
        records = loop.keyframes(final=True)
        assert len(records) == len(odo.truth)
        assert loop.stats.accepted >= 1, loop.stats
        assert not loop.stats.rejected, loop.stats  # every place recognised here is real
        kinds = [e.kind for e in loop.events]
        assert kinds.count("loop") == loop.stats.accepted
        # each loop edge at least as uncertain as the landmarks' own error allows
        least = [LOOP.loop_floor_m**2] * 3 + [LOOP.loop_floor_yaw_rad**2]
        assert all(np.all(np.diag(e.cov) >= least) for e in loop.graph.loops())
        poses = loop.graph.keyframe_poses()
        corrected = [poses[k] for k in range(len(odo.truth))]
        second = slice(PER_LAP, None)
        drifted = _rmse(odo.odo[second], odo.truth[second])
        fixed = _rmse(corrected[second], odo.truth[second])
        assert drifted > 0.1  # the odometry did drift
        # the first lap's own drift stays (no loop sees it); the second lap is drawn to it
        assert fixed < 0.7 * drifted, (fixed, drifted)
        # the output after the loop is corrected online too, with the reset counter raised
        # when the correction jumped
        late = outputs[-1]
        assert np.linalg.norm(late.T_W_B.p_A_B - odo.truth[-1].p_A_B) < np.linalg.norm(
            odo.odo[-1].p_A_B - odo.truth[-1].p_A_B
        )
    finally:
        loop.close()


@pytest.mark.parametrize("seed", [3, 4])
def test_a_lap_in_another_room_of_the_same_shape_closes_no_loop_to_the_first(seed: int) -> None:
    odo = DriftingOdometry(seed, another_room=True)
    loop = LoopClosure(odo, CAMERA, config=LOOP)
    try:
        for k in range(len(odo.truth)):
            loop.push(_frame(k))
        loop.keyframes(final=True)
        assert loop.stats.keyframes == 2 * PER_LAP
        # the first lap meets its own start, the second its own: never one the other
        assert all((old < PER_LAP) == (new < PER_LAP) for old, new in loop.stats.loops), loop.stats
    finally:
        loop.close()


def test_the_local_map_joins_the_neighbours_landmarks_once_seen_from_the_old_camera() -> None:
    from quadnav.loop import local_map

    odo = DriftingOdometry(5)
    recs = [odo.record(k) for k in range(8, 13)]
    old = recs[2]
    merged = local_map(old, recs, T_B_C)
    own = set(old.landmark_ids.tolist())
    union = set().union(*(r.landmark_ids.tolist() for r in recs))
    assert own < set(merged.landmark_ids.tolist()) <= union  # more than its own, each once
    assert len(set(merged.landmark_ids.tolist())) == len(merged.landmark_ids)
    assert merged.index == old.index and merged.T_W_B is old.T_W_B
    # each landmark at its projection into the old keyframe's camera
    c = (old.T_W_B @ T_B_C).inverse() @ merged.landmarks_W
    assert np.all(c[:, 2] > 0)
    assert np.allclose(merged.xy, c[:, :2] / c[:, 2:], atol=1e-12)
    # its own landmarks keep the old keyframe's own descriptors
    row = {i: k for k, i in enumerate(old.ids.tolist())}
    for k, j in enumerate(merged.landmark_ids.tolist()):
        if j in row:
            assert np.array_equal(merged.descriptors[k], old.descriptors[row[j]])
    # a keyframe of another odometry frame (after a reset) lends nothing
    other = dataclasses.replace(recs[0], reset_counter=1)
    alone = local_map(old, [other, old], T_B_C)
    assert set(alone.landmark_ids.tolist()) == own


def test_a_look_alike_room_metres_away_passes_the_geometry_but_not_the_drift_check() -> None:
    """Perceptual aliasing: the second lap flies an identical room 3 m along; the pictures and
    their geometry agree with the first lap's, but the loop would move the odometry by metres
    after a few of flight."""
    odo = DriftingOdometry(6, shift_m=3.0)
    loop = LoopClosure(odo, CAMERA, config=LOOP)
    try:
        across = _fly_laps(loop, odo)
        assert not across, loop.stats
        assert loop.stats.rejected["drift"] >= 1, loop.stats
        assert any("drift" in e.detail for e in loop.events if e.kind == "loop_rejected")
    finally:
        loop.close()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_look_alike_inside_the_path_allowance_is_refused_by_the_odometrys_covariance(
    seed: int,
) -> None:
    """The identical room 0.8 m along: less than the path rule allows after the 6 m flown
    between the laps (0.3 m + 10 %), so without the odometry's covariance the second lap
    closes loops to the first; against the covariance (about 0.11 m an axis by then) the move
    is seven sigma, and every such loop is refused."""
    for use in (False, True):
        odo = DriftingOdometry(seed, shift_m=0.8)
        config = dataclasses.replace(LOOP, use_odometry_covariance=use)
        loop = LoopClosure(odo, CAMERA, config=config)
        try:
            across = _fly_laps(loop, odo)
            if not use:
                assert across, loop.stats  # what the path rule alone lets through
                continue
            assert not across, loop.stats
            assert loop.stats.rejected["drift"] >= 1, loop.stats
            assert any("chi-square" in e.detail for e in loop.events if e.kind == "loop_rejected")
        finally:
            loop.close()


def test_an_odometry_that_drifts_faster_than_the_graph_assumes_is_corrected_by_its_covariance() -> (
    None
):
    """The default graph holds a step to 5 mm; this odometry walks 1.5 cm and 0.3 degrees a
    keyframe, and says so in its covariance. Its sequential edges loosened by that growth, the
    loops pull the second lap much nearer the truth than the fixed 5 mm edges let them (four
    seeds: 0.06-0.07 m against 0.10-0.15 m)."""
    for seed in range(4):
        rmse = []
        for use in (False, True):
            odo = DriftingOdometry(seed)
            config = LoopConfig(executor="thread", use_odometry_covariance=use)
            loop = LoopClosure(odo, CAMERA, config=config)
            try:
                for k in range(len(odo.truth)):
                    loop.push(_frame(k))
                loop.keyframes(final=True)
                poses = loop.graph.keyframe_poses()
            finally:
                loop.close()
            corrected = [poses[k] for k in range(PER_LAP, len(odo.truth))]
            rmse.append(_rmse(corrected, odo.truth[PER_LAP:]))
        fixed, loosened = rmse
        assert loosened < 0.75 * fixed, (seed, rmse)


def test_the_steps_own_covariance_is_used_where_the_marginal_swings() -> None:
    """An odometry whose marginal also holds an error its poses share (0.01 m^2 per square
    metre from the start: it rises over the first half of a lap and falls over the second)
    and whose records carry each step's own covariance: the edges get the steps' variances
    (the walk's, a keyframe at a time), not the marginal's swings; without the steps the
    closer falls back on the marginal's growth (none while it falls)."""
    for steps in (True, False):
        odo = DriftingOdometry(0, swing_m2=0.01, steps=steps)
        config = LoopConfig(executor="inline", learn_step_scale=False)
        loop = LoopClosure(odo, CAMERA, config=config)
        try:
            for k in range(PER_LAP):
                loop.push(_frame(k))
            got = loop.step_variances()
        finally:
            loop.close()
        assert got is not None
        v = np.array([got[k * 200_000_000] for k in range(1, PER_LAP - 1)])
        if steps:
            np.testing.assert_allclose(v, odo.walk_m2, rtol=1e-9)
        else:  # the growth of walk + swing: more while it rises, nothing while it falls
            rising, falling = v[: PER_LAP // 2 - 2], v[PER_LAP // 2 + 1 :]
            assert (rising > odo.walk_m2).all() and (falling == 0.0).all()


def test_a_step_from_a_keyframe_before_the_last_counts_only_what_it_adds() -> None:
    """A step given from two keyframes back (the window dropped the keyframe between): the
    edge from the keyframe before gets the step's variance less the one before's."""
    odo = DriftingOdometry(1, steps=True)
    loop = LoopClosure(odo, CAMERA, config=LoopConfig(executor="inline"))
    records = [odo.record(k) for k in range(4)]
    records[3] = dataclasses.replace(
        records[3], step=KeyframeStep(after=1, cov_W=np.eye(3) * 3 * odo.walk_m2)
    )
    try:
        for r in records:
            loop._take(r)
        got = loop.step_variances()
    finally:
        loop.close()
    assert got is not None
    assert [got[r.t_ns] for r in records] == pytest.approx(
        [0.0, odo.walk_m2, odo.walk_m2, 2 * odo.walk_m2], rel=1e-9
    )


@pytest.mark.parametrize("told", [1.0, 1.0 / 9.0, 1.0 / 100.0])
def test_the_loops_find_how_much_the_steps_understate_the_drift(told: float) -> None:
    """An odometry that states its steps' variance right, 9 times too small (as a monocular
    VIO's steps leave out its scale's slow wander) or 100 times: the loops' moves against the
    steps' variance give a scale near 1 for the first, several times for the second (each
    run's loops averaged with three loops' worth of 1), and for the third no more than each
    loop may say (``max_step_scale``, 10)."""
    found = []
    for seed in range(4):
        odo = DriftingOdometry(seed, steps=True, steps_told=told)
        loop = LoopClosure(odo, CAMERA, config=LoopConfig(executor="inline"))
        try:
            _fly_laps(loop, odo)
        finally:
            loop.close()
        assert loop.stats.step_scale_loops >= 5, loop.stats
        found.append(loop.stats.step_scale)
        steps = loop.step_variances()
        assert steps is not None  # what the edges were given: the stated steps, scaled
        assert steps[PER_LAP * 200_000_000] == pytest.approx(
            odo.walk_m2 * told * loop.stats.step_scale, rel=1e-9
        )
    if told == 1.0:
        assert max(found) < 2.0, found
    elif told > 0.1:
        assert 3.0 < float(np.median(found)) < 9.0, found
    else:
        assert min(found) > 5.0 and max(found) <= 10.0, found


class _Refining(DriftingOdometry):
    """The drifting odometry as one whose final trajectory a loop closer refines: it keeps
    what it was given."""

    given: tuple[Sequence[LoopConstraint], Mapping[int, Pose]] | None = None
    smoothed: Mapping[int, Pose] = {}

    def final_keyframe_poses(self) -> Mapping[int, Pose]:
        return self.smoothed

    def final_trajectory_with(
        self, loops: Sequence[LoopConstraint], keyframe_poses: Mapping[int, Pose]
    ) -> Trajectory:
        self.given = (loops, keyframe_poses)
        self.smoothed = {k: self.truth[k] for k in keyframe_poses}  # (a perfect smoothing)
        return Trajectory(t_ns=np.zeros(0, np.int64), p_W_B=np.zeros((0, 3)),
                          q_W_B_xyzw=np.zeros((0, 4)), name="final")  # fmt: skip


def test_the_final_trajectory_is_refined_with_the_runs_loops_and_its_pose_graph() -> None:
    """A loop-refinable odometry gets, for its final trajectory, each accepted loop as a
    6-DoF constraint between its own keyframe numbers, near the truth's relative pose, at a
    covariance no tighter than the loop floors, and the pose graph's keyframe poses; one that
    cannot refine gives the corrected keyframes."""
    odo = _Refining(0)
    loop = LoopClosure(odo, CAMERA, config=LOOP)
    try:
        _fly_laps(loop, odo)
        loop.final_trajectory()
        assert odo.given is not None
        loops, poses = odo.given
        assert len(loops) == loop.stats.accepted >= 1
        assert {(c.old, c.new) for c in loops} == set(loop.stats.loops)
        for c in loops:
            true = odo.truth[c.old].inverse() @ odo.truth[c.new]
            assert np.linalg.norm(c.T_old_new.p_A_B - true.p_A_B) < 0.1
            # what it was measured from: old landmarks (ids of the room's points) and where
            # the new keyframe saw them (the truth's projection, within the 0.7 px noise)
            assert len(c.landmark_ids) >= LOOP.verification.min_inliers
            X = odo.X[c.landmark_ids] + (odo.shift if c.new >= PER_LAP else 0.0)
            Xc = (odo.truth[c.new] @ T_B_C).inverse() @ X
            assert np.abs(Xc[:, :2] / Xc[:, 2:] - c.xy).max() < 4.0 / FOCAL_PX
            assert np.all(np.diag(c.cov)[3:] >= LOOP.loop_floor_m**2 * 0.999)
            assert np.all(np.diag(c.cov)[:3] >= LOOP.loop_floor_yaw_rad**2 * 0.999)
        graph = loop.graph.keyframe_poses()
        assert set(poses) == set(graph)
        assert all(np.allclose(poses[k].p_A_B, graph[k].p_A_B) for k in poses)
    finally:
        loop.close()
    plain = DriftingOdometry(0)
    loop = LoopClosure(plain, CAMERA, config=LOOP)
    try:
        _fly_laps(loop, plain)
        got = loop.final_trajectory()
        assert len(got) == len(plain.truth)
        assert np.allclose(got.p_W_B, loop.corrected_keyframes().p_W_B)
    finally:
        loop.close()


def test_a_loops_position_covariance_is_turned_into_the_new_keyframes_frame() -> None:
    """The new keyframe turned 90 degrees from the old: the old one's x variance is the new
    one's y variance and its y the new one's x; the yaw's variance goes to all three turns."""
    from scipy.spatial.transform import Rotation

    from quadnav.loop.closer import loop_constraint

    T = Pose(Rotation.from_euler("z", 90, degrees=True), np.array([0.5, 0.0, 0.0]))
    c = loop_constraint(3, 9, T, np.diag([1e-4, 4e-4, 9e-4, 2e-5]))
    assert (c.old, c.new) == (3, 9)
    assert np.allclose(np.diag(c.cov), [2e-5, 2e-5, 2e-5, 4e-4, 1e-4, 9e-4])


def test_a_saved_map_takes_the_keyframes_where_the_final_smoothing_put_them() -> None:
    """An odometry that smooths its run at the end (here perfectly: the truth): the map
    exported holds each keyframe at its smoothed pose, its landmarks moved with it (onto the
    truth's points), without a call to the final trajectory first."""
    odo = _Refining(1)
    loop = LoopClosure(odo, CAMERA, config=LOOP)
    try:
        _fly_laps(loop, odo)
        the_map = loop.export_map()
    finally:
        loop.close()
    assert odo.given is not None and len(the_map.keyframes) == len(odo.truth)
    for kf in the_map.keyframes:
        rec = kf.record
        assert np.allclose(rec.T_W_B.p_A_B, odo.truth[rec.index].p_A_B, atol=1e-9)
        seen = odo.X[rec.landmark_ids] + (odo.shift if rec.index >= PER_LAP else 0.0)
        assert np.allclose(rec.landmarks_W, seen, atol=1e-6)
