"""The background optimiser: it publishes a correction while the caller goes on adding keyframes,
corrects the odometry's output with ``T_M_O`` and raises the reset counter when the correction
jumps; bad input is refused and counted."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import PoseGraphError
from quadnav.geometry.rotations import Pose
from quadnav.odometry import KeyframeRecord, OdometryState
from quadnav.posegraph import BackgroundPoseGraph, LoopEdge, PoseGraphConfig
from quadnav.posegraph.simulate import drifting_loop, position_rmse

N = 200


def _state(T: Pose, reset_counter: int = 0) -> OdometryState:
    return OdometryState(
        t_ns=0, T_W_B=T, v_W_B=np.array([1.0, 0.0, 0.0]), gyro_bias=np.zeros(3),
        accel_bias=np.zeros(3), cov_pose=np.eye(6) * 1e-4, cov_v=np.eye(3) * 1e-3,
        reset_counter=reset_counter,
    )  # fmt: skip


@pytest.mark.parametrize("executor", ["process", "thread"])
def test_publishes_a_correction_while_the_caller_goes_on(executor: str) -> None:
    d = drifting_loop(np.random.default_rng(0), keyframes=N, per_lap=100, loops=3)
    loops = d.loops[:2]  # the third is at the last keyframe
    last_loop = loops[-1].new
    with BackgroundPoseGraph(executor=executor) as graph:  # type: ignore[arg-type]
        for k in range(last_loop + 1):
            assert graph.add_pose(k, d.odometry[k], t_ns=k)
        for e in loops:
            assert graph.add_loop(e)
        unpublished = graph.correction().keyframe_index  # add_loop returned before any solve
        later = 0
        for k in range(last_loop + 1, N - 20):  # the caller goes on while the graph solves
            graph.add_pose(k, d.odometry[k], t_ns=k)
            later += 1
        assert graph.wait(timeout_s=120)
        for k in range(N - 20, N):  # keyframes after the solve
            graph.add_pose(k, d.odometry[k], t_ns=k)
        c = graph.correction()
        poses = graph.keyframe_poses()
    assert unpublished == -1 and later > 0
    assert graph.optimizations >= 1 and graph.failures == 0, graph.last_error
    assert last_loop <= c.keyframe_index < N - 20 and c.result is not None
    # the correction, applied to the keyframes added after the solve, corrects them too
    corrected = [poses[k] for k in range(N)]
    assert position_rmse(corrected, d.truth) < 0.7 * position_rmse(d.odometry, d.truth)
    expected_last = c.T_M_O @ d.odometry[N - 1]
    np.testing.assert_allclose(poses[N - 1].p_A_B, expected_last.p_A_B, atol=1e-12)


def test_inline_solves_when_the_loop_is_added_the_same_on_every_run() -> None:
    """``executor="inline"`` (a simulation in simulated time): each loop is solved before
    ``add_loop`` returns, so the correction is there at once, and two runs give the same
    corrections bit for bit."""
    d = drifting_loop(np.random.default_rng(0), keyframes=N, per_lap=100, loops=3)
    runs = []
    for _ in range(2):
        with BackgroundPoseGraph(executor="inline") as graph:
            seen = []
            for k in range(N):
                graph.add_pose(k, d.odometry[k], t_ns=k)
                for e in d.loops:
                    if e.new == k:
                        assert graph.add_loop(e)
                        seen.append(graph.correction().keyframe_index)
            runs.append((seen, graph.correction().T_M_O.p_A_B.copy()))
            assert graph.optimizations == len(d.loops) and graph.failures == 0
    assert runs[0][0] == [e.new for e in d.loops]  # each solved up to its own loop at once
    np.testing.assert_array_equal(runs[0][1], runs[1][1])


def test_correct_applies_T_M_O_and_raises_the_reset_counter_on_a_jump() -> None:
    d = drifting_loop(np.random.default_rng(1), keyframes=N, per_lap=100, loops=3)
    config = PoseGraphConfig(reset_jump_m=0.3, reset_jump_rad=1.0)
    with BackgroundPoseGraph(config, executor="thread") as graph:
        for k in range(N):
            graph.add_pose(k, d.odometry[k], reset_counter=2)
        state = _state(d.odometry[-1], reset_counter=2)
        assert graph.correct(state).reset_counter == 2  # nothing yet: the odometry's own
        graph.add_loop(d.loops[0])
        graph.wait(timeout_s=60)
        first = graph.correction()
        out = graph.correct(state)
        graph.add_loop(d.loops[0])  # the same loop again: the graph moves less
        graph.wait(timeout_s=60)
        second = graph.correction()
    solved = first.result.poses[-1] if first.result else None
    assert solved is not None and first.jump_m > config.reset_jump_m
    np.testing.assert_allclose(out.T_W_B.p_A_B, solved.p_A_B, atol=1e-9)
    assert (out.T_W_B.R_A_B.inv() * solved.R_A_B).magnitude() < 1e-9
    np.testing.assert_allclose(out.v_W_B, first.T_M_O.R_A_B.apply(state.v_W_B), atol=1e-12)
    np.testing.assert_array_equal(out.cov_pose, state.cov_pose)  # body frame: unchanged
    assert out.reset_counter == 2 + 1 and first.reset_counter == 1
    assert second.jump_m < config.reset_jump_m and second.reset_counter == 1


def test_bad_input_is_refused_and_counted() -> None:
    d = drifting_loop(np.random.default_rng(2), keyframes=10, per_lap=100, loops=0)
    nan = Pose(Rotation.from_rotvec([np.nan, 0.0, 0.0]), np.zeros(3))
    with BackgroundPoseGraph(executor="thread") as graph:
        for k in range(5):
            assert graph.add_pose(k, d.odometry[k])
        assert not graph.add_pose(5, nan)
        assert not graph.add_pose(3, d.odometry[5])  # not after the last
        assert not graph.add_loop(LoopEdge(old=1, new=99, T_old_new=Pose.identity()))
        assert not graph.add_loop(LoopEdge(old=1, new=4, T_old_new=Pose.identity(), cov=np.eye(6)))
        record = KeyframeRecord(
            index=7, t_ns=70, reset_counter=0, T_W_B=d.odometry[7], cov_pose=np.eye(6), camera="cam0",
            image=None, ids=np.zeros(0, np.int64), uv_px=np.zeros((0, 2)), xy=np.zeros((0, 2)),
        )  # fmt: skip
        assert graph.add_keyframe(record)
        assert graph.rejected == {
            "nonfinite_pose": 1,
            "index_order": 1,
            "unknown_keyframe": 1,
            "covariance_size": 1,
        }
        assert graph.optimizations == 0 and graph.failures == 0
        assert set(graph.keyframe_poses()) == {0, 1, 2, 3, 4, 7}
    with pytest.raises(PoseGraphError):
        BackgroundPoseGraph(PoseGraphConfig(kind="sim3"), executor="thread")


def test_a_loop_joins_a_restarted_odometry_frame_to_the_map() -> None:
    """The odometry restarts at keyframe 100 in a frame turned 0.5 rad and moved 3 m: until a
    loop reaches it, its T_M_O is the identity; after, T_M_O maps it back onto the first frame."""
    d = drifting_loop(
        np.random.default_rng(3),
        keyframes=N,
        per_lap=100,
        loops=4,
        sigma_step_m=0.002,
        sigma_step_yaw_rad=0.0004,
    )
    T_O1_O0 = Pose(Rotation.from_euler("z", 0.5), np.array([3.0, -1.0, 0.5]))
    restart = d.odometry[100]
    second = [T_O1_O0 @ restart @ restart.inverse() @ p for p in d.odometry[100:]]
    with BackgroundPoseGraph(executor="thread") as graph:
        for k in range(N):
            graph.add_pose(
                k, d.odometry[k] if k < 100 else second[k - 100], reset_counter=int(k >= 100)
            )
        np.testing.assert_array_equal(graph.T_M_O(1).matrix(), np.eye(4))
        for e in d.loops:
            assert graph.add_loop(e)
        graph.wait(timeout_s=60)
        T_M_O1 = graph.T_M_O(1)
        out = graph.correct(_state(second[-1], reset_counter=1))
    expected = T_O1_O0.inverse()  # the first frame is the map (its first keyframe held)
    # within the drift of a lap (the map is the first frame as it drifted), against 3 m and 0.5 rad
    np.testing.assert_allclose(T_M_O1.p_A_B, expected.p_A_B, atol=0.1)
    assert (T_M_O1.R_A_B.inv() * expected.R_A_B).magnitude() < 0.02
    np.testing.assert_allclose(out.T_W_B.p_A_B, d.truth[-1].p_A_B, atol=0.1)
    assert out.reset_counter >= 1 + 1  # the restart's own and the correction's jump


def test_held_keyframes_stay_and_a_new_frame_starts_where_it_is_put() -> None:
    """A loaded map: its keyframes (frame -1) held where they are; a run's frame 0 starts at the
    transform it is given (``start_frame``), is moved by ``set_frame`` before any loop, and is
    solved against the map by a loop."""
    d = drifting_loop(np.random.default_rng(3), keyframes=120, per_lap=60, loops=1)
    with BackgroundPoseGraph(executor="thread") as graph:
        for k in range(60):  # the map: the first lap's truth
            assert graph.add_pose(k, d.truth[k], reset_counter=-1, fixed=True)
        start = Pose(Rotation.from_euler("z", 0.3), np.array([1.0, -2.0, 0.0]))
        graph.start_frame(0, start)
        for k in range(60, 120):  # the run: the second lap in a frame of its own
            graph.add_pose(k, d.odometry[k], reset_counter=0)
        assert graph.T_M_O(0) is start
        moved = Pose(Rotation.from_euler("z", -0.1), np.array([0.5, 0.5, 0.0]))
        graph.set_frame(0, moved)
        assert graph.T_M_O(0) is moved
        got = graph.pose_of(70)
        assert got is not None
        np.testing.assert_allclose(got.p_A_B, (moved @ d.odometry[70]).p_A_B, atol=1e-12)
        # a loop: keyframe 90 of the run is where keyframe 30 of the map is, seen as truth
        edge = LoopEdge(old=30, new=90, T_old_new=d.truth[30].inverse() @ d.truth[90])
        assert graph.add_loop(edge)
        assert graph.wait(timeout_s=60) and graph.failures == 0, graph.last_error
        poses = graph.keyframe_poses()
    for k in range(0, 60, 7):  # the map did not move
        np.testing.assert_allclose(poses[k].p_A_B, d.truth[k].p_A_B, atol=1e-5)
    # the run's keyframe at the loop is now where the truth has it
    assert np.linalg.norm(poses[90].p_A_B - d.truth[90].p_A_B) < 0.05
