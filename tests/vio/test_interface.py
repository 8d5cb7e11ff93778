"""The odometry interface on the real VIO (a rendered room sequence through EuRoC's mono rig, a
still start then motion): one ``push`` for IMU samples and frames, keyframe records handed out
once, consistent with themselves (their landmarks project onto their keypoints, their
descriptors follow their tracks), and memory bounded when nobody reads them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from quadnav.io.datasets import VisualInertialDataset
from quadnav.odometry import TRACKING_EVENTS, KeyframeRecord, OdometryState
from quadnav.vio import VioConfig, VioEstimator
from tests.vio.rendered import rendered


@dataclass
class _Run:
    ds: VisualInertialDataset
    vio: VioEstimator
    lazy: VioEstimator  # never asked for its keyframes until the end
    states: list[OdometryState]
    records: list[KeyframeRecord]
    batches: list[int]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> _Run:
    ds = rendered(
        tmp_path_factory, "room_easy", duration_s=6.0, still_s=1.0, rig="euroc_mono", seed=3
    )
    vio = VioEstimator(ds.rig, VioConfig())
    lazy = VioEstimator(ds.rig, VioConfig(max_unread_keyframes=2))
    states, records, batches = [], [], []
    for item in ds.stream():
        s = vio.push(item)
        lazy.push(item)
        if s is not None:
            states.append(s)
        got = vio.keyframes()
        if got:
            batches.append(len(got))
            records.extend(got)
    records.extend(vio.keyframes(final=True))
    return _Run(ds=ds, vio=vio, lazy=lazy, states=states, records=records, batches=batches)


def test_keyframes_are_handed_out_once_in_order(run: _Run) -> None:
    idx = [r.index for r in run.records]
    assert len(idx) >= 8
    assert idx == sorted(set(idx)), "each keyframe once, in order"
    assert all(np.diff([r.t_ns for r in run.records]) > 0)
    assert run.vio.keyframes() == [] and run.vio.keyframes(final=True) == []
    assert [e.kind for e in run.vio.events if e.kind in TRACKING_EVENTS] == ["initialized"]
    # most were published while the run went on (as they left the window), not at the end
    assert sum(run.batches) >= len(idx) - VioConfig().window_keyframes - 1


def test_a_records_landmarks_project_onto_its_keypoints(run: _Run) -> None:
    f = run.ds.rig.camera("cam0").camera.fx
    errors = []
    with_landmarks = 0
    for r in run.records:
        if len(r.landmark_ids) == 0:
            continue
        with_landmarks += 1
        assert set(r.landmark_ids.tolist()) <= set(r.ids.tolist())
        assert r.T_B_C is not None, "the extrinsic the odometry used (refined online)"
        c = (r.T_W_B @ r.T_B_C).inverse() @ r.landmarks_W
        assert np.all(c[:, 2] > 0), "landmarks in front of the keyframe's camera"
        at = {int(j): k for k, j in enumerate(r.ids)}
        xy = r.xy[[at[int(j)] for j in r.landmark_ids]]
        errors.append(np.median(np.linalg.norm(c[:, :2] / c[:, 2:3] - xy, axis=1)) * f)
    assert with_landmarks >= 0.7 * len(run.records)
    assert float(np.median(errors)) < 1.5, f"median reprojection {np.median(errors):.2f} px"


def test_descriptors_follow_their_tracks(run: _Run) -> None:
    """The same track's ORB descriptor in two consecutive keyframes is far closer (Hamming) than
    two different tracks' are: the descriptors sit at their keypoints."""
    same, other = [], []
    for a, b in zip(run.records, run.records[1:], strict=False):
        assert a.descriptors is not None and a.described is not None
        # a corner within 16 px of the border cannot be described (tracks leave the image there)
        assert a.descriptors.shape == (len(a.ids), 32) and a.described.mean() > 0.7
        assert b.descriptors is not None and b.described is not None
        _, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
        ok = a.described[ia] & b.described[ib]
        bits = np.unpackbits(a.descriptors[ia][ok] ^ b.descriptors[ib][ok], axis=1).sum(axis=1)
        same.extend(bits.tolist())
        shuffled = np.unpackbits(
            a.descriptors[ia][ok] ^ np.roll(b.descriptors[ib][ok], 7, axis=0), axis=1
        ).sum(axis=1)
        other.extend(shuffled.tolist())
    assert len(same) > 200
    assert np.median(same) < 0.5 * np.median(other)


def test_a_record_refers_to_its_image(run: _Run) -> None:
    r = run.records[len(run.records) // 2]
    assert r.image is not None and r.image.camera == "cam0" and r.camera == "cam0"
    assert abs(r.image.t_ns - r.t_ns) < 1_000_000  # the offset in use is zero here
    px = r.image.image()  # read again from its file: the record holds no pixels
    assert px.shape[:2] == (480, 752)


def test_quality_is_the_share_of_the_feature_budget(run: _Run) -> None:
    budget = VioConfig().tracker.max_features
    tracked = [s for s in run.states if s.status == "tracking"]
    assert tracked
    for s in tracked:
        assert s.quality == round(100 * min(1.0, s.tracked / budget))
    assert all(0 <= s.quality <= 100 for s in run.states)
    assert all(s.odometry().quality == s.quality for s in tracked[:5])


def test_unread_keyframes_are_dropped_and_counted(run: _Run) -> None:
    kept = run.lazy.keyframes()
    assert len(kept) <= 2
    dropped = run.lazy.rejected.get("keyframes_unread", 0)
    assert dropped >= len(run.records) - VioConfig().window_keyframes - 2
    # what it kept are its newest published keyframes, as the reading run got them
    assert [k.index for k in kept] == sorted(k.index for k in kept)


def test_a_record_carries_only_landmarks_its_views_place(run: _Run) -> None:
    """A landmark goes out with a keyframe only where the cameras that see it in the window
    span 1 degree at it: a track seen from one spot (a hover) has no depth to give a loop's
    PnP. Checked against the published keyframes themselves: each landmark's keyframe and the
    records about it that see its track (the window it left, or at the end was in) span the
    angle, as the poses were then (within 10 % of it)."""
    from quadnav.geometry.multiview import parallax_rad

    need = np.radians(VioConfig().keyframe_landmark_min_parallax_deg)
    window = VioConfig().window_keyframes
    centres = [(r.T_W_B @ r.T_B_C).p_A_B for r in run.records]
    angles = []
    for n, r in enumerate(run.records):
        near = range(max(0, n - window), min(len(run.records), n + 1 + window))
        for j, p in zip(r.landmark_ids.tolist(), r.landmarks_W, strict=True):
            cs = [centres[m] for m in near if m == n or j in run.records[m].ids]
            angles.append(parallax_rad(p, np.array(cs)))
    assert len(angles) > 200 and np.quantile(angles, 0.05) >= 0.9 * need, np.quantile(angles, 0.05)


def test_a_record_carries_its_step_from_an_earlier_keyframe(run: _Run) -> None:
    """Each record after a frame's first carries its position step's covariance from an
    earlier record of the same frame (the one before, or two before where the window dropped
    the keyframe between): symmetric, positive definite, and a few millimetres, much tighter
    than the marginal, which also holds what the poses share."""
    stepped = [r for r in run.records if r.step is not None]
    assert len(stepped) >= 0.9 * (len(run.records) - 1)
    index = {r.index: n for n, r in enumerate(run.records)}
    for r in stepped:
        assert r.step is not None
        assert r.step.after in index and index[r.step.after] in (
            index[r.index] - 1,
            index[r.index] - 2,
        )
        cov = r.step.cov_W
        np.testing.assert_allclose(cov, cov.T, atol=1e-15)
        sd = np.sqrt(np.linalg.eigvalsh(cov))
        assert sd.min() > 1e-5 and sd.max() < 0.02, (r.index, sd)
    late = stepped[len(stepped) // 2 :]
    ratio = [np.trace(r.step.cov_W) / np.trace(r.cov_pose[3:, 3:]) for r in late if r.step]
    assert float(np.median(ratio)) < 0.25
