"""The landmark book's admission (``vio/landmarks.py``): the parallax and the DLT points it
computes for all tracks at once are those of one track at a time, and on a known window the
tracks that should enter do, at their points, and the others wait."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.multiview import triangulate_track
from quadnav.vio.config import VioConfig
from quadnav.vio.frontend import FeatureManager
from quadnav.vio.landmarks import LandmarkBook, _bearing_angles, _dlt_points

FloatArray = NDArray[np.float64]
#: Keyframes 0.2 m apart along x, looking along z (R_C_W = I).
CENTRES = {k: np.array([0.2 * k, 0.05 * k * k, 0.0]) for k in range(6)}
P = {k: np.hstack([np.eye(3), -c[:, None]]) for k, c in CENTRES.items()}


def _seen(X: FloatArray, ks: range | list[int]) -> dict[int, FloatArray]:
    return {k: (X - CENTRES[k])[:2] / (X - CENTRES[k])[2] for k in ks}


def _one_angle(obs: dict[int, FloatArray]) -> float:
    """The parallax of one track as the book measured it before it measured all at once."""
    k0, k1 = min(obs), max(obs)
    b0 = np.linalg.solve(P[k0][:, :3], np.array([*obs[k0], 1.0]))
    b1 = np.linalg.solve(P[k1][:, :3], np.array([*obs[k1], 1.0]))
    c = float(b0 @ b1) / float(np.linalg.norm(b0) * np.linalg.norm(b1))
    return float(np.arccos(min(1.0, max(-1.0, c))))


def test_all_tracks_at_once_give_each_tracks_own_parallax_and_point() -> None:
    rng = np.random.default_rng(4)
    tracks = []
    for _ in range(60):
        X = rng.uniform([-2.0, -1.5, 2.0], [2.0, 1.5, 8.0])
        ks = sorted(rng.choice(6, size=int(rng.integers(2, 7)), replace=False).tolist())
        tracks.append({k: xy + rng.normal(0.0, 1e-3, 2) for k, xy in _seen(X, ks).items()})
    angles = _bearing_angles(tracks, P)
    points = _dlt_points(tracks, P)
    assert len({len(t) for t in tracks}) >= 4  # several numbers of views, triangulated apart
    for obs, angle, p in zip(tracks, angles, points, strict=True):
        assert abs(angle - _one_angle(obs)) <= 1e-12
        one = triangulate_track(obs, P)
        assert one is not None and p is not None and np.array_equal(p, one)
    assert _bearing_angles([], P).shape == (0,) and _dlt_points([], P) == []


def test_admission_lets_in_the_tracks_that_should_enter_at_their_points() -> None:
    """Three views: in at its point; two views 0.2 m apart at 30 m (parallax 3 px at 460 px,
    15 needed): waits; a track whose last view jumped 0.05 (23 px): kept out; two far apart
    views of a near point: in. Asked again with the same views, nothing new enters."""
    truth = {1: np.array([0.3, -0.2, 4.0]), 2: np.array([1.0, 0.5, 30.0]),
             3: np.array([-0.5, 0.1, 3.0]), 4: np.array([0.2, 0.3, 2.5])}  # fmt: skip
    fm = FeatureManager()
    fm.tracks = {1: _seen(truth[1], [0, 1, 2]), 2: _seen(truth[2], [0, 1]),
                 3: _seen(truth[3], [0, 1, 2, 3]), 4: _seen(truth[4], [0, 5])}  # fmt: skip
    fm.tracks[3][3] = fm.tracks[3][3] + np.array([0.05, 0.0])
    book = LandmarkBook(VioConfig(), focal_px=460.0)
    adm = book.admit(fm, P, {})
    entered = {n.track: n for n in adm.new}
    assert set(entered) == {1, 4}
    for j in (1, 4):
        assert np.linalg.norm(entered[j].point_W - truth[j]) < 1e-9
        assert entered[j].anchor == min(fm.tracks[j])
    assert sorted((o.key, o.keyframe) for o in adm.observations) == sorted(
        [(entered[1].key, k) for k in (0, 1, 2)] + [(entered[4].key, k) for k in (0, 5)]
    )
    again = book.admit(fm, P, {})
    assert again.new == [] and again.observations == []


#: A stereo rig's second camera 0.11 m to the right of each keyframe's first.
PR = {k: np.hstack([np.eye(3), -(c + [0.11, 0.0, 0.0])[:, None]]) for k, c in CENTRES.items()}


def _seen_right(X: FloatArray, ks: list[int]) -> dict[int, FloatArray]:
    return {k: (X - CENTRES[k] - [0.11, 0.0, 0.0])[:2] / (X - CENTRES[k])[2] for k in ks}


def test_stereo_views_triangulated_at_once_give_each_tracks_own_point() -> None:
    rng = np.random.default_rng(5)
    Pv = {(k, 0): m for k, m in P.items()} | {(k, 1): m for k, m in PR.items()}
    tracks = []
    for _ in range(40):
        X = rng.uniform([-2.0, -1.5, 1.0], [2.0, 1.5, 5.0])
        left = sorted(rng.choice(6, size=int(rng.integers(0, 4)), replace=False).tolist())
        right = sorted(rng.choice(6, size=int(rng.integers(1, 3)), replace=False).tolist())
        views = {(k, 0): xy for k, xy in _seen(X, left).items()}
        views |= {(k, 1): xy + rng.normal(0.0, 1e-3, 2) for k, xy in _seen_right(X, right).items()}
        tracks.append(views)
    for views, p in zip(tracks, _dlt_points(tracks, Pv), strict=True):
        one = triangulate_track(views, Pv)
        assert (p is None) == (one is None)
        assert p is None or one is None or np.array_equal(p, one)


def test_a_near_point_seen_in_stereo_enters_from_one_keyframe() -> None:
    """One keyframe's views in both cameras let a point 2 m away in (0.11 m baseline); one
    60 m away (beyond ``stereo_max_depth_baselines``) waits."""
    near, far = np.array([0.3, 0.2, 2.0]), np.array([-1.0, 0.5, 59.0])
    fm = FeatureManager()
    fm.tracks = {1: _seen(near, [2]), 2: _seen(far, [2])}
    fm.right = {1: _seen_right(near, [2]), 2: _seen_right(far, [2])}
    book = LandmarkBook(VioConfig(), focal_px=460.0, baseline_m=0.11)
    adm = book.admit(fm, P, PR)
    assert [n.track for n in adm.new] == [1]
    assert np.linalg.norm(adm.new[0].point_W - near) < 1e-9
    assert sorted((o.keyframe, o.side) for o in adm.observations) == [(2, 0), (2, 1)]
