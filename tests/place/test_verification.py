"""Geometric verification of a recognised place: a true revisit passes with its relative pose,
another place, a view too far turned and too few features do not."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import PlaceError
from quadnav.geometry.rotations import Pose
from quadnav.odometry import KeyframeRecord
from quadnav.place.verification import VerificationConfig, match_descriptors, verify_place

FOCAL_PX = 460.0
#: a forward-looking camera on a FLU body (x forward): z_C = x_B, x_C = -y_B, y_C = -z_B
T_B_C = Pose(Rotation.from_matrix([[0, 0, 1], [-1, 0, 0], [0, -1, 0]]), np.array([0.1, 0, 0]))


def _body(yaw_deg: float, p: tuple[float, float, float]) -> Pose:
    return Pose(Rotation.from_euler("z", yaw_deg, degrees=True), np.array(p, float))


def _record(
    index: int,
    T_W_B: Pose,
    X_W: np.ndarray,
    desc: np.ndarray,
    rng,
    *,
    with_points: bool,
    noise_px: float = 0.5,
) -> KeyframeRecord:
    """A keyframe seeing the points ``X_W`` that lie in front of it (pixel noise added)."""
    T_C_W = (T_W_B @ T_B_C).inverse()
    Xc = T_C_W @ X_W
    vis = np.flatnonzero(Xc[:, 2] > 0.3)
    xy = Xc[vis, :2] / Xc[vis, 2:] + rng.normal(0, noise_px / FOCAL_PX, (len(vis), 2))
    inside = np.abs(xy).max(axis=1) < 0.8
    vis, xy = vis[inside], xy[inside]
    ids = vis.astype(np.int64) + 1000 * index
    return KeyframeRecord(
        index=index, t_ns=index * 10**8, reset_counter=0, T_W_B=T_W_B, cov_pose=np.eye(6) * 1e-4,
        camera="cam0", image=None, ids=ids, uv_px=xy * FOCAL_PX + 376, xy=xy,
        descriptors=desc[vis], described=np.ones(len(vis), bool),
        landmark_ids=ids if with_points else np.zeros(0, np.int64),
        landmarks_W=X_W[vis] if with_points else np.zeros((0, 3)),
    )  # fmt: skip


def _flip_bits(desc: np.ndarray, n_bits: int, rng) -> np.ndarray:
    """``desc`` with ``n_bits`` random bits of each row flipped (a descriptor seen again)."""
    bits = np.unpackbits(desc, axis=1)
    for row in bits:
        row[rng.choice(256, n_bits, replace=False)] ^= 1
    return np.packbits(bits, axis=1)


def _scene(seed: int, n: int = 300):
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(3, 6, n), rng.uniform(-3, 3, n), rng.uniform(-1.5, 2.5, n)])
    desc = rng.integers(0, 256, (n, 32), dtype=np.uint8)
    return rng, X, desc


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_revisit_passes_with_the_relative_pose_among_outliers(seed: int) -> None:
    rng, X, desc = _scene(seed)
    old = _record(1, _body(0.0, (0, 0, 0)), X, desc, rng, with_points=True)
    T_true = _body(12.0, (0.4, -0.3, 0.1))
    seen = _flip_bits(desc, 12, rng)
    wrong = rng.random(len(X)) < 0.2  # a fifth of the query's descriptors belong elsewhere
    seen[wrong] = rng.integers(0, 256, (int(wrong.sum()), 32), dtype=np.uint8)
    # the query's own odometry has drifted: its pose in its world is not the truth
    q = _record(7, T_true, X, seen, rng, with_points=False)
    q = KeyframeRecord(
        **{**{f: getattr(q, f) for f in q.__slots__}, "T_W_B": _body(20.0, (1, 1, 0))}
    )
    v = verify_place(q, old, focal_px=FOCAL_PX, T_B_C=T_B_C)
    assert v.accepted and v.loop is not None, v
    d = T_true.inverse() @ v.loop.T_Wo_Bq
    assert np.linalg.norm(d.p_A_B) < 0.01
    assert np.degrees(d.R_A_B.magnitude()) < 0.2
    rel = old.T_W_B.inverse() @ T_true
    assert np.linalg.norm(v.loop.T_Bo_Bq.p_A_B - rel.p_A_B) < 0.01
    assert abs(v.yaw_deg - 12.0) < 0.3
    # the inliers pair the same points
    assert np.all(old.ids[v.loop.old_rows] % 1000 == q.ids[v.loop.query_rows] % 1000)
    assert v.n_pnp >= 0.7 * len(v.loop.old_rows) and v.n_matches > v.n_pnp * 0.9


def test_another_place_is_rejected_at_the_descriptors() -> None:
    rng, X, desc = _scene(3)
    old = _record(1, _body(0.0, (0, 0, 0)), X, desc, rng, with_points=True)
    _, X2, desc2 = _scene(4)
    q = _record(2, _body(5.0, (0.2, 0, 0)), X2, desc2, rng, with_points=False)
    v = verify_place(q, old, focal_px=FOCAL_PX, T_B_C=T_B_C)
    assert not v.accepted and v.stage == "matches" and v.n_matches < 25


def test_same_descriptors_on_a_scrambled_geometry_fail_the_geometric_steps() -> None:
    """Perceptual aliasing: the words agree but the points are where the query's are not."""
    rng, X, desc = _scene(5)
    old = _record(1, _body(0.0, (0, 0, 0)), X, desc, rng, with_points=True)
    q = _record(2, _body(3.0, (0.2, 0, 0)), X, desc, rng, with_points=False)
    perm = rng.permutation(len(q.ids))
    q = KeyframeRecord(**{**{f: getattr(q, f) for f in q.__slots__},
                          "descriptors": q.descriptors[perm]})  # fmt: skip
    v = verify_place(q, old, focal_px=FOCAL_PX, T_B_C=T_B_C)
    assert not v.accepted and v.stage in ("fundamental", "pnp")


def test_a_view_turned_further_than_allowed_fails_the_sanity_check() -> None:
    rng, X, desc = _scene(6)
    old = _record(1, _body(0.0, (0, 0, 0)), X, desc, rng, with_points=True)
    q = _record(2, _body(12.0, (0.3, 0, 0)), X, _flip_bits(desc, 8, rng), rng, with_points=False)
    assert verify_place(q, old, focal_px=FOCAL_PX, T_B_C=T_B_C).accepted
    tight = VerificationConfig(max_yaw_deg=5.0)
    v = verify_place(q, old, focal_px=FOCAL_PX, T_B_C=T_B_C, config=tight)
    assert v.stage == "sanity" and v.yaw_deg is not None and 11.0 < v.yaw_deg < 13.0


def test_a_keyframe_with_too_few_features_is_rejected_first() -> None:
    rng, X, desc = _scene(7, n=20)
    old = _record(1, _body(0.0, (0, 0, 0)), X, desc, rng, with_points=True)
    q = _record(2, _body(2.0, (0.1, 0, 0)), X, desc, rng, with_points=False)
    assert verify_place(q, old, focal_px=FOCAL_PX, T_B_C=T_B_C).stage == "descriptors"


def test_matching_keeps_the_closer_claim_and_drops_ties() -> None:
    rng = np.random.default_rng(0)
    b = rng.integers(0, 256, (5, 32), dtype=np.uint8)
    a = np.vstack([_flip_bits(b[[2]], 3, rng), _flip_bits(b[[2]], 9, rng), b[[4]], b[[4]]])
    ia, ib = match_descriptors(a, b, max_hamming=80, ratio=0.9)
    assert ia.tolist() == [0] and ib.tolist() == [2]  # row 1 lost row 2; rows 2, 3 tie on 4


@pytest.mark.parametrize(
    "bad", [np.zeros((3, 32), np.float32), np.zeros((3, 16), np.uint8), np.zeros(32, np.uint8)]
)
def test_descriptors_of_the_wrong_kind_are_a_one_line_error(bad: np.ndarray) -> None:
    with pytest.raises(PlaceError, match="descriptors"):
        match_descriptors(bad, np.zeros((3, 32), np.uint8), max_hamming=80, ratio=0.9)


def test_a_bad_focal_length_is_a_one_line_error() -> None:
    rng, X, desc = _scene(8)
    old = _record(1, _body(0.0, (0, 0, 0)), X, desc, rng, with_points=True)
    with pytest.raises(PlaceError, match="focal_px"):
        verify_place(old, old, focal_px=float("nan"), T_B_C=T_B_C)
