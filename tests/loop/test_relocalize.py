"""Relocalization: after a camera blackout the odometry's pose is a dead reckoning; the first
keyframes after it are looked up in the map and, when two agree, the output moves back into
the map's frame at once. A look-alike place metres away is refused."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.geometry.rotations import Pose
from quadnav.loop import LoopClosure, LoopConfig
from quadnav.messages import ImageFrame
from quadnav.odometry import OdometryState
from quadnav.posegraph import PoseGraphConfig
from tests.loop.drifting import CAMERA, PER_LAP, DriftingOdometry

LOOP = LoopConfig(
    executor="thread",
    graph=PoseGraphConfig(sequential_sigma_m=0.015, sequential_sigma_yaw_rad=0.006,
                          loop_sigma_m=0.02, loop_sigma_yaw_rad=0.01),
)  # fmt: skip
FRAME_S = 0.2
#: frames 50-64 withheld: 3 s without images in the second lap
BLACKOUT = range(PER_LAP + 10, PER_LAP + 25)
#: what 3 s on the IMU alone did to the odometry's pose
DEAD_RECKONING = Pose(Rotation.from_euler("z", 4.0, degrees=True), np.array([0.35, -0.25, 0.05]))


def _frame(k: int) -> ImageFrame:
    return ImageFrame(
        t_ns=round(k * FRAME_S * 1e9), camera="cam0", load=lambda: np.zeros((8, 8), np.uint8)
    )


def _error(st: OdometryState, truth: Pose) -> float:
    return float(np.linalg.norm(st.T_W_B.p_A_B - truth.p_A_B))


def _fly(loop: LoopClosure, odo: DriftingOdometry, skip: range) -> dict[int, OdometryState]:
    out = {}
    for k in range(len(odo.truth)):
        if k in skip:
            continue
        st = loop.push(_frame(k))
        assert st is not None
        out[k] = st
    loop.keyframes(final=True)
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_after_a_blackout_the_output_is_back_in_the_map_within_a_second(seed: int) -> None:
    odo = DriftingOdometry(seed, jump_at=BLACKOUT.stop, jump=DEAD_RECKONING)
    loop = LoopClosure(odo, CAMERA, config=LOOP)
    try:
        out = _fly(loop, odo, BLACKOUT)
        kinds = [e.kind for e in loop.events]
        assert "image_gap" in kinds
        joins = [j for j in loop.stats.joins if j["how"] == "relocalized"]
        assert len(joins) == 1, loop.stats.joins
        back_s = (int(joins[0]["t_ns"]) - _frame(BLACKOUT.stop).t_ns) / 1e9  # type: ignore[call-overload]
        assert 0 <= back_s <= 1.0, back_s
        k_in = BLACKOUT.stop + round(back_s / FRAME_S)
        # the output moved back by about what the dead reckoning put it off (0.43 m), to the
        # map's own error (the first lap's drift where the keyframe matched), with its reset
        # counter up
        assert float(joins[0]["jump_m"]) > 0.25, joins  # type: ignore[arg-type]
        after = [_error(out[k], odo.truth[k]) for k in range(k_in, k_in + 5)]
        assert after[0] < 0.15 and np.mean(after) < 0.2, after
        assert out[k_in].reset_counter > out[BLACKOUT.start - 1].reset_counter
        assert len(loop.segments.items) == 2
    finally:
        loop.close()


def test_a_look_alike_room_metres_away_is_no_relocalization() -> None:
    """After the blackout the vehicle is in a copy of the room 3 m along: the pictures match the
    first lap's and the geometry verifies, but the place is metres from where the odometry was
    before the gap: refused, the segment stays unjoined, the output is not moved."""
    odo = DriftingOdometry(6, shift_m=3.0, jump_at=BLACKOUT.stop, jump=DEAD_RECKONING)
    loop = LoopClosure(odo, CAMERA, config=LOOP)
    try:
        out = _fly(loop, odo, BLACKOUT)
        assert not [j for j in loop.stats.joins if j["how"] == "relocalized"], loop.stats.joins
        assert loop.stats.relocalize_rejected["jump"] >= 2, loop.stats.relocalize_rejected
        k = len(odo.truth) - 1
        assert out[k].reset_counter == out[BLACKOUT.stop].reset_counter
    finally:
        loop.close()


def test_without_a_gap_nothing_relocalizes() -> None:
    odo = DriftingOdometry(3)
    loop = LoopClosure(odo, CAMERA, config=LOOP)
    try:
        _fly(loop, odo, range(0))
        assert not loop.stats.joins and len(loop.segments.items) == 1
        assert not [e for e in loop.events if e.kind in ("image_gap", "relocalized")]
    finally:
        loop.close()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_after_an_odometry_reset_the_output_goes_on_then_rejoins_the_map(seed: int) -> None:
    """The odometry re-initialises in the second lap, in a frame of its own (its origin where
    the body is, 1-2 m from the first frame's): the output does not jump there (the new frame
    is taken where the output was, as a navigation filter following it expects), and once two
    places agree it is back in the map, with its reset counter raised at that jump only."""
    reset_at = PER_LAP + 10
    odo = DriftingOdometry(seed, reset_at=reset_at)
    loop = LoopClosure(odo, CAMERA, config=LOOP)
    try:
        out = _fly(loop, odo, range(0))
        before, first = out[reset_at - 1], out[reset_at]
        assert odo.odo[reset_at].p_A_B @ odo.odo[reset_at].p_A_B < 1e-12  # (its own origin)
        # one frame's motion (0.16 m) and the drift, not the 1-2 m between the frames
        step = float(np.linalg.norm(odo.truth[reset_at].p_A_B - odo.truth[reset_at - 1].p_A_B))
        assert _error(first, before.T_W_B) < step + 0.1, (_error(first, before.T_W_B), step)
        assert first.reset_counter == before.reset_counter + 1  # (the odometry's own reset)
        joins = [j for j in loop.stats.joins if j["how"] == "relocalized"]
        assert len(joins) == 1, loop.stats.joins
        k_in = max(k for k in out if out[k].t_ns <= int(joins[0]["t_ns"]))  # type: ignore[call-overload]
        assert out[k_in].reset_counter == first.reset_counter + 1
        k_end = len(odo.truth) - 1
        assert _error(out[k_end], odo.truth[k_end]) < 0.15
    finally:
        loop.close()
