"""Loop closure judged against the ground truth (``eval/loop_eval.py``) on laps where the answer
is known: two laps of a circle, keyframes 9 degrees of arc apart, places made up by hand."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from quadnav.errors import EvalError
from quadnav.eval.loop_eval import LoopEvalConfig, evaluate_loops, plot_loop_graph
from quadnav.eval.na import is_na
from quadnav.geometry.trajectory import Trajectory
from quadnav.units import NS_PER_S

RADIUS = 2.0  # m
LAP_S = 20.0
PER_LAP = 40  # keyframes a lap: 9 degrees of arc, 0.31 m apart
T0 = 1_000 * NS_PER_S
#: the body is an IMU mounted x up, as the built-in rigs' are: its attitude is far from level,
#: so a yaw read off Euler angles of the body would be wrong
R_MOUNT = Rotation.from_euler("y", -110.0, degrees=True)


def _pose(t_s: float, *, yaw_extra_deg: float = 0.0) -> tuple[np.ndarray, Rotation]:
    a = 2.0 * np.pi * t_s / LAP_S
    lap2 = t_s >= LAP_S
    p = np.array([RADIUS * np.cos(a), RADIUS * np.sin(a), 1.0 + 0.3 * lap2])
    heading = Rotation.from_euler("z", a + np.pi / 2 + np.radians(yaw_extra_deg))
    return p, heading * R_MOUNT


def _trajectory(times_s: np.ndarray, name: str) -> Trajectory:
    poses = [_pose(float(t)) for t in times_s]
    return Trajectory(
        t_ns=T0 + np.round(times_s * NS_PER_S).astype(np.int64),
        p_W_B=np.array([p for p, _ in poses]),
        q_W_B_xyzw=np.array([R.as_quat() for _, R in poses]),
        name=name,
    )


TRUTH = _trajectory(np.arange(0.0, 2 * LAP_S, 0.01), "truth")
KF_S = np.arange(2 * PER_LAP) * LAP_S / PER_LAP
KEYFRAMES = _trajectory(KF_S, "keyframes")


def _t(k: int) -> int:
    return int(KEYFRAMES.t_ns[k])


@dataclass(frozen=True)
class Place:
    old: int
    new: int
    t_old_ns: int
    t_new_ns: int
    stage: str
    n_pnp: int
    T_old_new: tuple[float, ...] | None


def _truth_relative(old: int, new: int) -> tuple[np.ndarray, Rotation]:
    po, Ro = _pose(float(KF_S[old]))
    pn, Rn = _pose(float(KF_S[new]))
    return Ro.inv().apply(pn - po), Ro.inv() * Rn


def _place(old: int, new: int, *, stage: str = "accepted", dp=(0.0, 0.0, 0.0), measured=None):
    """A place between keyframes ``old`` and ``new``: measured as the truth has it, moved by
    ``dp`` (m, old body frame), or as ``measured`` (p, R) says."""
    p, R = _truth_relative(old, new) if measured is None else measured
    T = (*(p + np.asarray(dp)).tolist(), *R.as_quat().tolist()) if stage == "accepted" else None
    return Place(old, new, _t(old), _t(new), stage, 40, T)


def _drifting(traj: Trajectory) -> Trajectory:
    """``traj`` in another world frame (turned 40 degrees, moved) with a growing drift along x."""
    R = Rotation.from_euler("z", 40.0, degrees=True)
    moved = traj.transformed(R, np.array([3.0, -1.0, 0.5]))
    drift = np.outer((traj.t_ns - traj.t_ns[0]) / NS_PER_S, [0.01, 0.0, 0.0])
    return Trajectory(t_ns=moved.t_ns, p_W_B=moved.p_W_B + drift, q_W_B_xyzw=moved.q_W_B_xyzw)


# A true loop, a look-alike (another place, measured as if the same), a loop at the same place
# measured 0.5 m off, and a rejected candidate at the same place.
PLACES = [
    _place(10, 50, dp=(0.02, -0.01, 0.0)),
    _place(5, 60, measured=(np.array([0.0, 0.0, 0.3]), Rotation.identity())),
    _place(25, 65, dp=(0.5, 0.0, 0.0)),
    _place(30, 70, stage="pnp"),
]

# Revisits, counted by hand: within a lap a keyframe is 9 degrees of arc (0.31 m chord) from its
# neighbour; one 30 or more keyframes earlier is within 1 m (27 degrees of arc, 0.93 m chord,
# 27 degrees of yaw) only for keyframes 37, 38 and 39 of the first lap (keyframe 0 is 3, 2 and
# 1 steps on); on the second lap every keyframe is 0.3 m above the same keyframe of the first.
REVISITS = 3 + PER_LAP


def test_a_true_loop_a_look_alike_and_a_badly_measured_one() -> None:
    ev = evaluate_loops(PLACES, _drifting(KEYFRAMES), KEYFRAMES, TRUTH)
    verdicts = [p.verdict for p in ev.places]
    assert verdicts == ["true", "false", "false", "rejected, same place"]
    assert (ev.accepted, ev.rejected, ev.true, ev.false) == (3, 1, 1, 2)
    assert ev.precision == pytest.approx(1 / 3)
    assert ev.rejected_same_place == 1
    true, alike, bad, _ = ev.places
    assert true.error_m == pytest.approx(np.hypot(0.02, 0.01), abs=1e-9)
    assert true.truth_distance_m == pytest.approx(0.3, abs=1e-9)  # straight above
    assert bad.error_m == pytest.approx(0.5, abs=1e-9) and bad.same_place
    assert not alike.same_place
    # 45 degrees of arc to 180: a chord of 2 R sin(67.5 deg), 0.3 m up
    assert alike.truth_distance_m == pytest.approx(np.hypot(4 * np.sin(np.radians(67.5)), 0.3))
    # the median of the accepted loops' errors: 0.022 m, about 4 m (the look-alike) and 0.5 m
    assert ev.error_median_m == pytest.approx(0.5, abs=1e-9)


def test_recall_counts_the_revisits_and_those_a_true_loop_closed_near() -> None:
    ev = evaluate_loops(PLACES, KEYFRAMES, KEYFRAMES, TRUTH)
    assert ev.revisits == REVISITS
    # the only true loop closed at keyframe 50: revisits 45-55 within the 5 keyframes
    assert ev.found == 11 and ev.recall == pytest.approx(11 / REVISITS)
    exact = evaluate_loops(PLACES, KEYFRAMES, KEYFRAMES, TRUTH, LoopEvalConfig(recall_window=0))
    assert exact.found == 1
    # a second true loop (at 70) finds 11 revisits more; a revisit missed lowers recall
    more = evaluate_loops([*PLACES, _place(30, 72)], KEYFRAMES, KEYFRAMES, TRUTH)
    assert more.found == 22 and more.recall > ev.recall
    # a window of 44 keyframes: 36 degrees of arc or more, but for the second lap's last
    # keyframes (77-79), 27, 18 and 9 degrees short of two laps on from keyframes 0-2
    wide = LoopEvalConfig(exclude_keyframes=44)
    assert evaluate_loops(PLACES, KEYFRAMES, KEYFRAMES, TRUTH, wide).revisits == 3
    none = LoopEvalConfig(exclude_keyframes=80)
    assert is_na(evaluate_loops(PLACES, KEYFRAMES, KEYFRAMES, TRUTH, none).recall)


def test_the_same_place_needs_the_yaw_too() -> None:
    """Keyframes at the same spot turned 40 degrees about the vertical are not the same place,
    20 degrees are, however the body is mounted."""
    p, R = _pose(5.0)
    for yaw, same in ((40.0, False), (20.0, True), (-20.0, True)):
        _, R2 = _pose(5.0, yaw_extra_deg=yaw)
        truth = Trajectory(
            t_ns=np.array([T0, T0 + NS_PER_S]), p_W_B=np.array([p, p]),
            q_W_B_xyzw=np.array([R.as_quat(), R2.as_quat()]),
        )  # fmt: skip
        place = Place(0, 40, T0, T0 + NS_PER_S, "fundamental", 0, None)
        (score,) = evaluate_loops([place], truth, None, truth).places
        assert score.truth_yaw_deg == pytest.approx(abs(yaw), abs=1e-6)
        assert score.same_place is same


def test_the_pose_graph_taking_out_the_drift_shows_in_the_keyframe_errors() -> None:
    odo = _drifting(KEYFRAMES)
    corrected = Trajectory(t_ns=odo.t_ns, p_W_B=odo.p_W_B - np.outer(
        (odo.t_ns - odo.t_ns[0]) / NS_PER_S, [0.01, 0.0, 0.0]), q_W_B_xyzw=odo.q_W_B_xyzw)  # fmt: skip
    ev = evaluate_loops(PLACES, odo, corrected, TRUTH)
    m = ev.as_metrics()
    assert m["loop_keyframes_ape_rmse_after_m"] == pytest.approx(0.0, abs=1e-9)
    # 0.01 m/s for 39.5 s, the best line through it taken out by the alignment: about 0.1 m
    assert 0.05 < m["loop_keyframes_ape_rmse_before_m"] < 0.2
    assert ev.error_after_m is not None and len(ev.error_after_m) == len(KEYFRAMES)
    # the correction: where the loop puts keyframe 50 against where the drifting odometry did
    # (0.2 m of drift in the 20 s from keyframe 10), give or take the loop's own 0.022 m error
    err = np.hypot(0.02, 0.01)
    assert 0.2 - err - 1e-9 <= ev.places[0].correction_m <= 0.2 + err + 1e-9


def test_without_truth_counts_only_and_a_one_panel_figure(tmp_path: Path) -> None:
    ev = evaluate_loops(PLACES, KEYFRAMES, KEYFRAMES, None)
    assert (ev.accepted, ev.rejected) == (3, 1)
    assert [p.verdict for p in ev.places] == ["accepted"] * 3 + ["rejected"]
    m = ev.as_metrics()
    assert m["loop_accepted"] == 3
    for key in ("loop_precision", "loop_recall", "loop_true", "loop_false",
                "loop_measurement_error_median_m", "loop_keyframes_ape_rmse_after_m"):  # fmt: skip
        assert is_na(m[key]), key
    alone = plot_loop_graph(ev, tmp_path / "alone.png", T0)
    both = plot_loop_graph(
        evaluate_loops(PLACES, KEYFRAMES, KEYFRAMES, TRUTH), tmp_path / "b.png", T0
    )
    with Image.open(alone) as a, Image.open(both) as b:
        assert a.size[0] < 0.6 * b.size[0]  # the error panel only with a truth


def test_places_outside_the_truth_are_not_scored() -> None:
    half = TRUTH.select(slice(0, len(TRUTH) // 2 + 100))  # the first lap and 0.99 s more
    ev = evaluate_loops(PLACES, KEYFRAMES, KEYFRAMES, half)
    assert [p.verdict for p in ev.places] == ["accepted"] * 3 + ["rejected"]
    assert is_na(ev.precision) and ev.true == 0 and ev.false == 0
    # the first lap's last 3 keyframes and the second's first 2 (at 20 and 20.5 s)
    assert ev.revisits == 5


def test_nonsense_thresholds_are_refused() -> None:
    with pytest.raises(EvalError, match="same_place_m"):
        LoopEvalConfig(same_place_m=-1.0)
    with pytest.raises(EvalError, match="exclude_keyframes"):
        LoopEvalConfig(exclude_keyframes=0)


def test_revisits_over_many_keyframes_match_a_pair_by_pair_count() -> None:
    """Three laps of 90 keyframes (more than a block of the comparison), against a count pair
    by pair from the laps' own arc angles (heading = arc angle + 90 degrees)."""
    times = np.arange(270) * LAP_S / 90
    keyframes = _trajectory(times, "keyframes")
    truth = _trajectory(np.arange(0.0, 3 * LAP_S, 0.05), "truth")
    arc = 2.0 * np.pi * times / LAP_S
    expected = 0
    for j in range(len(times)):
        for i in range(j - 30 + 1):
            turn = abs((arc[j] - arc[i] + np.pi) % (2 * np.pi) - np.pi)
            apart = np.linalg.norm(keyframes.p_W_B[j] - keyframes.p_W_B[i])
            if apart < 1.0 and turn < np.radians(30.0):
                expected += 1
                break
    ev = evaluate_loops([], keyframes, keyframes, truth)
    assert ev.revisits == expected
    # the reference itself: the first lap's last 7 keyframes (4 degrees apart: 28 degrees of
    # arc is a 0.97 m chord) and every keyframe of the later laps
    assert expected == 7 + 180


def test_a_loop_measured_right_is_true_even_beyond_the_same_place_distance() -> None:
    """Keyframes 10 and 54: 36 degrees of arc (a 1.24 m chord) and 0.3 m up, turned 36
    degrees: not the same place by the thresholds, but a loop measuring their relative pose
    to 1 cm is a right edge; measured as if they coincided it is false."""
    right = _place(10, 54, dp=(0.01, 0.0, 0.0))
    wrong = _place(10, 54, measured=(np.zeros(3), Rotation.identity()))
    ev = evaluate_loops([right, wrong], KEYFRAMES, KEYFRAMES, TRUTH)
    assert [p.same_place for p in ev.places] == [False, False]
    assert ev.places[0].truth_distance_m == pytest.approx(np.hypot(4 * np.sin(np.pi / 10), 0.3))
    assert [p.verdict for p in ev.places] == ["true", "false"]
    assert ev.precision == pytest.approx(0.5)


def _with_error(traj: Trajectory, err: np.ndarray) -> Trajectory:
    return Trajectory(t_ns=traj.t_ns, p_W_B=traj.p_W_B + err, q_W_B_xyzw=traj.q_W_B_xyzw)


def test_the_revisit_bound_takes_out_a_drift_between_revisits_but_not_jitter() -> None:
    """Perfect loops at every revisit: a drift that builds up over the second lap (1 cm a
    keyframe along x, 0.5 cm along y) is taken out; an error that jumps from one keyframe to the
    next (2 cm, white) is not: loops tie places, they cannot smooth the odometry between them."""
    from quadnav.eval.loop_eval import _aligned as aligned
    from quadnav.eval.loop_eval import revisit_bound
    from quadnav.posegraph import PoseGraphConfig

    graph = PoseGraphConfig(sequential_sigma_m=0.02)
    k = np.arange(len(KEYFRAMES))
    drift = np.outer(np.clip(k - PER_LAP, 0, None), [0.01, 0.005, 0.0])
    drifted = _with_error(KEYFRAMES, drift)
    _, err, _ = aligned(TRUTH, drifted)
    before = float(np.sqrt(np.mean(err**2)))
    bound = revisit_bound(drifted, TRUTH, graph)
    assert isinstance(bound, float) and before > 0.1
    assert bound < 0.2 * before, (bound, before)
    rng = np.random.default_rng(0)
    jitter = _with_error(KEYFRAMES, rng.normal(0.0, 0.02, (len(KEYFRAMES), 3)))
    _, err, _ = aligned(TRUTH, jitter)
    before = float(np.sqrt(np.mean(err**2)))
    bound = revisit_bound(jitter, TRUTH, graph)
    assert isinstance(bound, float) and bound > 0.8 * before, (bound, before)


def test_the_revisit_bound_needs_a_truth_and_a_revisit() -> None:
    from quadnav.eval.loop_eval import revisit_bound
    from quadnav.posegraph import PoseGraphConfig

    graph = PoseGraphConfig()
    assert is_na(revisit_bound(KEYFRAMES, None, graph))
    first_half_lap = KEYFRAMES.select(np.arange(PER_LAP // 2))
    assert is_na(revisit_bound(first_half_lap, TRUTH, graph))


def test_the_revisit_bound_keeps_a_reset_odometrys_frames_apart() -> None:
    """The odometry re-initialised at the second lap, in a frame 2 m and 30 degrees from the
    first: given each keyframe's frame, the loops put the second lap back on the first (no
    drift: nothing is left); as one frame, the step across the reset pulls against them."""
    from quadnav.eval.loop_eval import revisit_bound
    from quadnav.posegraph import PoseGraphConfig

    second = np.arange(len(KEYFRAMES)) >= PER_LAP
    R = Rotation.from_euler("z", 30.0, degrees=True)
    jumped = KEYFRAMES.transformed(R, np.array([2.0, -1.0, 0.3]))
    p = np.where(second[:, None], jumped.p_W_B, KEYFRAMES.p_W_B)
    q = np.where(second[:, None], jumped.q_W_B_xyzw, KEYFRAMES.q_W_B_xyzw)
    reset = Trajectory(t_ns=KEYFRAMES.t_ns, p_W_B=p, q_W_B_xyzw=q)
    graph = PoseGraphConfig(sequential_sigma_m=0.02)
    apart = revisit_bound(reset, TRUTH, graph, segments=second.astype(np.int64))
    together = revisit_bound(reset, TRUTH, graph)
    assert isinstance(apart, float) and isinstance(together, float)
    assert apart < 0.01, apart
    assert together > 10 * apart, (together, apart)
