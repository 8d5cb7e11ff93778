"""The SLAM map's index of who observes each point, against counting every keyframe's keypoints;
the fusion of points a keyframe made again with the old ones."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.geometry.rotations import Pose
from quadnav.sim.render import Renderer
from quadnav.slam import SlamConfig, StereoTracker, stereo_frame
from quadnav.slam.local_mapping import fuse_neighbours
from quadnav.slam.loop_closing import _fuse
from quadnav.slam.map import SlamMap
from quadnav.vision.orb import OrbExtractor
from tests.slam.test_tracking import RIG, B, _pose
from tests.slam.test_tracking import renderer as renderer  # (the fixture)

N_KP = 40


@dataclass
class _Features:
    descriptors: NDArray[np.uint8]
    octave: NDArray[np.int64]


@dataclass
class _Frame:
    """What the map reads of a frame when points are made by triangulation."""

    features: _Features

    def __len__(self) -> int:
        return N_KP


def _frame(rng: np.random.Generator) -> _Frame:
    d = rng.integers(0, 256, (N_KP, 32), dtype=np.uint8)
    return _Frame(_Features(d, np.zeros(N_KP, np.int64)))


def _counted(m: SlamMap, ids: NDArray[np.int64]) -> NDArray[np.int64]:
    """Each keyframe's keypoints whose point is one of ``ids``, counted one by one."""
    want = set(ids.tolist())
    return np.array([sum(int(p) in want for p in kf.points) for kf in m.keyframes], np.int64)


def _free(kf: object, rng: np.random.Generator, n: int) -> NDArray[np.int64]:
    free = np.flatnonzero(kf.points < 0)  # type: ignore[attr-defined]
    return rng.permutation(free)[:n]


def _step(m: SlamMap, rng: np.random.Generator) -> None:
    """One of what tracking, local mapping and loop closing do to a map, at random."""
    op = rng.integers(6) if len(m.keyframes) > 1 else 0
    kfs = m.keyframes
    good = np.flatnonzero(~m.bad)
    if op == 0:
        m.add_keyframe(Pose.identity(), _frame(rng))  # type: ignore[arg-type]
    elif op == 1:  # points made by two keyframes
        a, b = kfs[-1], kfs[int(rng.integers(len(kfs) - 1))]
        n = min(len(_free(a, rng, 8)), len(_free(b, rng, 8)))
        ka, kb = _free(a, rng, n), _free(b, rng, n)
        m.add_triangulated((a, b), (ka, kb), rng.normal(size=(n, 3)))
    elif op == 2 and len(good):  # a keyframe finds old points (one of them twice)
        kf = kfs[int(rng.integers(len(kfs)))]
        kps = _free(kf, rng, 5)
        ids = rng.choice(good, size=len(kps))
        if len(ids) > 1:
            ids[1] = ids[0]
        m.observe(kf, kps, ids)
    elif op == 3:  # outliers forgotten
        kf = kfs[int(rng.integers(len(kfs)))]
        kp, _ = kf.observed
        m.forget(kf, rng.permutation(kp)[:3])
    elif op == 4 and len(m.X_W):  # points culled
        m.cull(rng.integers(len(m.X_W), size=4))
    elif op == 5 and len(good) >= 4:  # a loop's fusion: old points replace a keyframe's
        kf = kfs[int(rng.integers(len(kfs)))]
        kp = rng.permutation(N_KP)[:4]
        _fuse(m, kf, kp, rng.choice(good, size=4, replace=False))


@pytest.mark.parametrize("seed", range(5))
def test_who_observes_a_point_is_what_the_keyframes_keypoints_say(seed: int) -> None:
    rng = np.random.default_rng(seed)
    m = SlamMap()
    checked = 0
    for _ in range(400):
        _step(m, rng)
        if not len(m.X_W):
            continue
        ids = rng.integers(len(m.X_W), size=int(rng.integers(1, 30)))
        np.testing.assert_array_equal(m.sharing(ids), _counted(m, ids))
        among = m.keyframes[: max(1, len(m.keyframes) // 2)]
        np.testing.assert_array_equal(m.sharing(ids, among=among), _counted(m, ids)[: len(among)])
        checked += int(_counted(m, ids).sum() > 0)
    everything = {
        (kf.index, int(kp), int(p))
        for kf in m.keyframes
        for kp, p in enumerate(kf.points)
        if p >= 0
    }
    k, kp, p = m.observers(np.arange(len(m.X_W)))
    assert set(zip(k.tolist(), kp.tolist(), p.tolist(), strict=True)) == everything
    assert len(k) == len(everything)
    # each good point's count of observers is what the keyframes' keypoints say
    good = ~m.bad
    np.testing.assert_array_equal(m.n_obs[good], np.bincount(p, minlength=len(m.X_W))[good])
    assert checked > 200  # (the counts compared were mostly not all zero)
    for kf in m.keyframes:  # a culled point is observed by no keyframe
        assert not m.bad[kf.points[kf.points >= 0]].any()


def test_points_a_keyframe_made_again_are_fused_with_the_old_ones(renderer: Renderer) -> None:
    """The newest keyframe of a tracked arc loses half its old points and makes them again
    from its stereo depths (as a tracking that missed them would): fusing it with its
    neighbours (ORB-SLAM2's ``SearchInNeighbors``) shares those keypoints' points with the
    other keyframes again (the copies culled or taken up by them), and fuses nothing that
    does not fit its image."""
    cfg = SlamConfig(keyframe_every=4, fuse_neighbours=False)
    ex, tracker = OrbExtractor(cfg.orb), StereoTracker(cfg)
    for k in range(16):
        T = _pose(k, 40)
        right = T @ Pose(Rotation.identity(), np.array([B, 0.0, 0.0]))
        frame = stereo_frame(k * 50_000_000, renderer.render(T).image,
                             renderer.render(right).image, RIG, ex, cfg)  # fmt: skip
        assert tracker.track(frame).state == "tracking"
    m, kf = tracker.map, tracker.map.keyframes[-1]
    kp, ids = kf.observed
    again = kp[m.first_keyframe[ids] < kf.index][::2]
    m.forget(kf, again)
    copies = m.add_points(kf, again)
    assert len(again) >= 40 and (m.n_obs[copies] == 1).all()  # (seen by this keyframe alone)
    n = fuse_neighbours(m, kf, m.covisible(kf, 11)[1:])
    now = kf.points[again]
    shared = (now >= 0) & (m.n_obs[np.maximum(now, 0)] >= 2)
    # (measured: 76 % shared again; the rest a keypoint of the same place fused at another
    # level, or a descriptor too far from the old point's)
    assert n >= len(again) and shared.mean() >= 0.65, (n, shared.mean())
    alone = ~m.bad[copies] & (m.n_obs[copies] < 2)
    assert alone.mean() <= 0.15, alone.mean()
    kp, ids = kf.observed
    X = kf.T_C_W @ m.X_W[ids]
    c = kf.frame.camera
    uv = np.column_stack([c.fx * X[:, 0] / X[:, 2] + c.cx, c.fy * X[:, 1] / X[:, 2] + c.cy])
    err = np.linalg.norm(uv - kf.frame.features.uv_px[kp], axis=1)
    assert np.percentile(err, 99) < 3.0, np.percentile(err, 99)


def test_a_map_read_back_knows_who_observes_its_points(renderer: Renderer) -> None:
    """A tracked map written as arrays (as a saved map is) and read back: the same observers of
    every point as the map that was tracked, so covisibility is the same after a load."""
    cfg = SlamConfig(keyframe_every=4)
    ex, tracker = OrbExtractor(cfg.orb), StereoTracker(cfg)
    for k in range(12):
        T = _pose(k, 40)
        right = T @ Pose(Rotation.identity(), np.array([B, 0.0, 0.0]))
        tracker.track(stereo_frame(k * 50_000_000, renderer.render(T).image,
                                   renderer.render(right).image, RIG, ex, cfg))  # fmt: skip
    m = tracker.map
    back, _ = SlamMap.from_arrays(*m.to_arrays(RIG))
    everyone = np.arange(len(m.X_W))
    seen = sorted(zip(*(a.tolist() for a in m.observers(everyone)), strict=True))
    assert len(seen) > 500 and len(m.keyframes) >= 3
    assert sorted(zip(*(a.tolist() for a in back.observers(everyone)), strict=True)) == seen
    for kf in m.keyframes:
        np.testing.assert_array_equal(back.sharing(kf.points), m.sharing(kf.points))
