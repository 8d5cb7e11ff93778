"""The SLAM's own loop closing (issue 24, item 4) on a rendered stereo sequence of the room: out
along an arc and back along it, with a drift of 8 cm and 2 degrees put into the map at the
turn (the keyframes made after it, their points and the tracker moved, their links to the
older points cut, as a drifting odometry would leave them). Coming back, the first keyframes are
recognised, the loop is closed and the estimate returns to the truth; the final trajectory (the
frames through their keyframes as the loop left them) takes the drift out of the frames before."""

from __future__ import annotations

import dataclasses
import re
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.geometry.rotations import Pose
from quadnav.slam import SlamConfig, StereoTracker, stereo_frame
from quadnav.slam.config import LoopClosingConfig
from quadnav.slam.local_mapping import GlobalAdjustment
from quadnav.slam.loop_closing import LoopCloser, LoopClosingReport
from quadnav.slam.map import SlamMap
from quadnav.vision.orb import OrbExtractor
from tests.slam.test_tracking import RIG, B, _errors, _pose
from tests.slam.test_tracking import renderer as renderer  # (the fixture)

DRIFT = Pose(Rotation.from_euler("z", 2.0, degrees=True), np.array([0.08, -0.03, 0.0]))


def _drift(tracker: StereoTracker, first: int) -> None:
    """The keyframes from ``first`` on, the points they made and the tracker's pose moved by
    ``DRIFT`` (in the world); their observations of older points forgotten."""
    m = tracker.map
    for kf in m.keyframes[first:]:
        kf.T_C_W = kf.T_C_W @ DRIFT.inverse()
        seen = np.flatnonzero(kf.points >= 0)
        m.forget(kf, seen[m.first_keyframe[kf.points[seen]] < first])
    new = m.first_keyframe >= first
    m.X_W[new] = DRIFT @ m.X_W[new]
    assert tracker._T_C_W_last is not None
    tracker._T_C_W_last = tracker._T_C_W_last @ DRIFT.inverse()
    tracker._last_points = np.zeros(0, np.int64)
    tracker._reference = m.keyframes[-1]


N = 30


def _config(loop: LoopClosingConfig) -> SlamConfig:
    # (local mapping off: its triangulation would tie the drifted keyframes back to the first
    # points before the loop is seen; here loop closing alone is judged)
    return SlamConfig(local_keyframes=4, keyframe_every=6, local_mapping=False, loop_closing=loop)


def _out_and_back(
    cfg: SlamConfig, renderer: object, n: int
) -> tuple[StereoTracker, list[Pose], list[Pose | None], list[tuple[int, LoopClosingReport]]]:
    """The arc out and back, the drift put in at the turn: the tracker, truth, estimates and
    the loops closed (frame, report)."""
    ex = OrbExtractor(cfg.orb)
    ks = [*range(n), *range(n - 1, -1, -1)]
    tracker = StereoTracker(cfg)
    truth, est, loops = [], [], []
    for i, k in enumerate(ks):
        T = _pose(k, n)
        right = T @ Pose(Rotation.identity(), np.array([B, 0.0, 0.0]))
        frame = stereo_frame(i * 50_000_000, renderer.render(T).image,  # type: ignore[attr-defined]
                             renderer.render(right).image, RIG, ex, cfg)  # type: ignore[attr-defined]  # fmt: skip
        r = tracker.track(frame)
        assert r.state == "tracking", (i, r)
        truth.append(T)
        est.append(r.T_W_C)
        if r.loop is not None:
            loops.append((i, r.loop))
        if i == n - 1:
            _drift(tracker, len(tracker.map.keyframes) - 1)
    return tracker, truth, est, loops


def test_a_loop_back_to_the_start_is_closed_and_takes_the_drift_out(renderer: object) -> None:
    cfg = _config(LoopClosingConfig(min_gap_keyframes=3, consistency=1))
    tracker, truth, est, loops = _out_and_back(cfg, renderer, N)
    n = N
    err = _errors(truth, est)
    assert loops, "no loop closed"
    i, loop = loops[0]
    assert loop.old < loop.new and loop.inliers >= 40 and loop.fused > 0, loop
    assert err[n + 1] > 0.06, err[n + 1]  # (the drift was there before the loop)
    print(loop, err[i - 1 : i + 3])
    # the frames after it are tracked on the first points again: the drift is gone
    assert max(err[i + 1 :]) < 0.02, (i, err[i:])
    assert err[i] < err[i - 1] - 0.01 and loop.moved_m > 0.01, (err[i - 1 : i + 1], loop)
    # the final trajectory (ORB-SLAM2's saved one): every frame through its reference keyframe
    # as the loop left it, so the frames tracked on the drifted keyframes come back too
    t_final, T_final = tracker.final_poses()
    assert len(t_final) == 2 * n and (np.diff(t_final) > 0).all()
    final = _errors(truth, [Pose.from_matrix(T) for T in T_final])
    assert max(final[n + 1 : i]) < 0.03, (final[n + 1 : i], err[n + 1 : i])
    assert np.mean(final[n + 1 : i]) < 0.5 * np.mean(err[n + 1 : i])


def test_a_loop_asking_more_than_the_drift_can_be_is_refused(renderer: object) -> None:
    """The same place seen again, but the bounds on the drift set below the 8 cm put in (as a
    wallpaper's period asks for more than a stereo SLAM drifts): no loop is closed, the place
    is counted as refused, and the estimate keeps its drift rather than jumping."""
    loop = LoopClosingConfig(min_gap_keyframes=3, consistency=1, max_drift_m=0.01,
                             max_drift_fraction=0.001)  # fmt: skip
    tracker, truth, est, loops = _out_and_back(_config(loop), renderer, N)
    assert loops == [] and tracker.loop_closer.rejected >= 1
    # each refusal says what the loop asked for against what the drift can be: about the
    # 8 cm put in, against the 1 cm (plus 0.1 % of the path) allowed
    assert len(tracker.loop_closer.refusals) == tracker.loop_closer.rejected
    for text in tracker.loop_closer.refusals:
        asked, bound = (float(x) for x in re.findall(r"([0-9.]+) m\b", text))
        assert 0.04 < asked < 0.15 and bound < 0.02 < asked, text
    err = _errors(truth, est)
    assert min(err[N + 1 :]) > 0.05, err  # (still drifted: nothing was corrected)


def test_a_loops_adjustment_is_bounded_to_the_newest_keyframes(
    renderer: object, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``global_ba_keyframes=3``: the adjustment after the loop moves the three newest
    keyframes, every older one keeps the pose the loop's pose graph gave it (a long run's
    adjustment after each loop stays bounded), and the drift still comes out."""
    import quadnav.slam.tracking as tracking

    seen: list[tuple[list[np.ndarray], list[np.ndarray], int]] = []
    real = tracking.global_bundle_adjustment

    def spy(m: SlamMap, **kw: Any) -> GlobalAdjustment:
        before = [kf.T_C_W.matrix() for kf in m.keyframes]
        out = real(m, **kw)
        seen.append((before, [kf.T_C_W.matrix() for kf in m.keyframes], out.keyframes))
        return out

    monkeypatch.setattr(tracking, "global_bundle_adjustment", spy)
    cfg = dataclasses.replace(
        _config(LoopClosingConfig(min_gap_keyframes=3, consistency=1)), global_ba_keyframes=3
    )
    _, truth, est, loops = _out_and_back(cfg, renderer, N)
    assert loops and len(seen) == len(loops)
    before, after, adjusted = seen[0]
    assert adjusted == 3 and len(before) > 6
    moved = [not np.array_equal(a, b) for a, b in zip(before, after, strict=True)]
    assert not any(moved[:-3]) and all(moved[-3:]), moved
    err = _errors(truth, est)
    assert max(err[loops[0][0] + 1 :]) < 0.02


def test_the_drift_a_loop_may_correct_grows_along_the_maps_shortest_way() -> None:
    """Two laps of a circle (2 m radius, 30 keyframes a lap): a loop from keyframe 58 to 28
    (the same place a lap apart) may correct 3 % of the 12.6 m lap between them, until a loop
    closed from 56 to 26 joins the laps: the way from 28 to 58 is then 4 keyframes (1.7 m) and
    a jump of 0.3 m is a place that repeats, no longer drift."""
    from quadnav.posegraph import LoopEdge
    from quadnav.slam.map import SlamKeyframe

    m = SlamMap()
    none = np.zeros(0, np.int64)
    for k in range(60):
        a = 2 * np.pi * k / 30
        T_W_C = Pose(Rotation.from_euler("z", a), np.array([2 * np.cos(a), 2 * np.sin(a), 1.0]))
        m.keyframes.append(SlamKeyframe(index=k, T_C_W=T_W_C.inverse(), frame=None, points=none))  # type: ignore[arg-type]
    kf, old = m.keyframes[58], m.keyframes[28]

    def asks(shift_m: float) -> Pose:  # (the loop's pose of keyframe 58)
        return kf.T_C_W @ Pose(Rotation.identity(), np.array([shift_m, 0.0, 0.0]))

    fresh = LoopCloser(LoopClosingConfig())
    assert fresh._implausible(kf, m, old, asks(0.3), []) is None  # (0.1 + 3 % of 12.6 m)
    assert fresh._implausible(kf, m, old, asks(0.6), []) is not None
    joined = LoopCloser(LoopClosingConfig())
    joined.closed.append(LoopClosingReport(old=26, new=56, inliers=100, moved_m=0.0,
                                           turned_rad=0.0, fused=0, edges=0))  # fmt: skip
    way = 4 * 4 * np.sin(np.pi / 30)  # (four chords of the circle)
    assert joined._way_m(m, 28, 58, []) == pytest.approx(way, rel=1e-6)
    # the same pair again as an essential edge is still one way, not twice as long
    twice = [LoopEdge(old=26, new=56, T_old_new=Pose.identity(), cov=np.eye(6))] * 2
    assert joined._way_m(m, 28, 58, twice) == pytest.approx(way, rel=1e-6)
    # a keyframe culled on the way counts where its parent has it now
    m.keyframes[57].bad, m.keyframes[57].parent = True, 56
    m.keyframes[57].T_C_P = m.keyframes[57].T_C_W @ m.keyframes[56].T_C_W.inverse()
    m.keyframes[57].T_C_W = Pose(Rotation.identity(), np.array([50.0, 0.0, 0.0]))  # (stale)
    assert joined._way_m(m, 28, 58, []) == pytest.approx(way, rel=1e-6)
    assert joined._implausible(kf, m, old, asks(0.1), []) is None
    why = joined._implausible(kf, m, old, asks(0.3), [])
    assert why is not None and "moves 0.300 m" in why and "drift can be 0.150 m" in why
