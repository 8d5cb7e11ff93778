"""The database (inverted and direct index) and the loop detector (normalised scores, islands,
temporal consistency, the excluded window) on synthetic keyframes."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.errors import PlaceError
from quadnav.place import (
    Database,
    LoopDetector,
    LoopDetectorConfig,
    QueryResult,
    default_vocabulary,
    l1_score,
)
from quadnav.place.detector import islands


def _strip(seed: int, n: int = 6000) -> np.ndarray:
    """A long row of random descriptors: the 'wall' a camera pans along."""
    return np.random.default_rng(seed).integers(0, 256, (n, 32), dtype=np.uint8)


def _view(strip: np.ndarray, place: int, rng: np.random.Generator) -> np.ndarray:
    """The keyframe at ``place``: 300 descriptors from 50 * place on, 85 % kept, 1 % bits
    flipped (neighbouring places share 250 of 300)."""
    d = strip[50 * place : 50 * place + 300]
    d = d[rng.random(len(d)) < 0.85]
    return d ^ np.packbits(rng.random((len(d), 256)) < 0.01, axis=1)


def test_database_scores_are_the_pairwise_l1_scores() -> None:
    db = Database(default_vocabulary())
    rng = np.random.default_rng(0)
    strip = _strip(0)
    ids = [db.add(_view(strip, p, rng)) for p in range(0, 40, 2)]
    assert ids == list(range(20)) and len(db) == 20
    q = default_vocabulary().bow(_view(strip, 10, rng))
    want = np.array([l1_score(q, db.bow(i)) for i in ids])
    np.testing.assert_allclose(db.scores(q), want, atol=1e-6)  # float32 postings
    res = db.query(q, max_results=3)
    assert [r.entry for r in res] == list(np.argsort(-want, kind="stable")[:3])
    assert res[0].entry == 5  # place 10 was added fifth
    assert all(r.entry <= 2 for r in db.query(q, max_entry=2))


def test_direct_index_groups_features_by_node() -> None:
    vocab = default_vocabulary()
    db = Database(vocab, direct_level=2)
    d = _view(_strip(1), 0, np.random.default_rng(1))
    entry = db.add(d)
    direct = db.direct(entry)
    _, nodes = vocab.descend(d, level=2)
    assert (vocab.level[nodes] <= 2).all()
    seen = []
    for node in direct.nodes.tolist():
        idx = direct.features_of(node)
        assert (nodes[idx] == node).all()
        seen += idx.tolist()
    assert sorted(seen) == list(range(len(d)))
    assert len(direct.features_of(-5)) == 0


def test_islands_group_close_entries_and_rank_by_summed_score() -> None:
    res = tuple(
        QueryResult(entry=e, score=s)
        for e, s in [(10, 0.2), (12, 0.3), (40, 0.35), (13, 0.1), (50, 0.05), (41, 0.3)]
    )
    got = islands(res, gap=3, min_size=1)
    assert [(i.first, i.last, i.best) for i in got] == [(40, 41, 40), (10, 13, 12), (50, 50, 50)]
    assert got[0].score == pytest.approx(0.65) and got[1].score == pytest.approx(0.6)
    assert [(i.first, i.last) for i in islands(res, gap=1, min_size=2)] == [(40, 41), (12, 13)]


def _run(seed: int, config: LoopDetectorConfig) -> list:
    """Two passes over places 0..39 of a strip; returns the detections."""
    rng = np.random.default_rng(seed)
    strip = _strip(seed)
    det = LoopDetector(config=config)
    return [det.push(_view(strip, p, rng)) for p in list(range(40)) + list(range(40))]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_detector_finds_the_second_pass_after_k_consistent_queries(seed: int) -> None:
    k = 4
    cfg = LoopDetectorConfig(exclude_recent=10, temporal_consistency=k)
    out = _run(seed, cfg)
    assert [d.entry for d in out] == list(range(80))
    assert all(d.status == "too_few_entries" for d in out[:11])
    assert not any(d.detected for d in out[:40])  # the first pass revisits nothing
    second = out[40:]
    first = next(i for i, d in enumerate(second) if d.detected)
    # the keyframe before place 0 shows place 39: the first query may have no prior score
    jumped = second[0].status == "low_prior_score"
    assert first == k - 1 + jumped  # k consistent queries, then a loop on every one
    assert all(d.detected for d in second[first:])
    for place, d in enumerate(second[jumped:], start=jumped):
        assert d.match is not None and abs(d.match - place) <= 1


def test_excluded_window_leaves_out_recent_entries() -> None:
    out = _run(3, LoopDetectorConfig(exclude_recent=60, temporal_consistency=1))
    # with 60 entries left out, the second pass sees only places up to (entry - 61)
    for d in out:
        assert all(r.entry <= d.entry - 61 for r in d.results)
    assert not any(d.detected for d in out[:61])


def test_bad_input_is_one_line() -> None:
    det = LoopDetector()
    with pytest.raises(PlaceError, match=r"\(N, 32\) uint8") as e:
        det.push(np.zeros((10, 32), np.int16))
    assert "\n" not in str(e.value)
    with pytest.raises(PlaceError, match="no database entry"):
        det.database.bow(0)
    with pytest.raises(PlaceError, match="direct_level"):
        Database(default_vocabulary(), direct_level=9)
    assert len(det.database) == 0  # nothing was added
    with pytest.raises(PlaceError, match="temporal_consistency must be an integer >= 1"):
        LoopDetectorConfig(temporal_consistency=0)
    with pytest.raises(PlaceError, match="min_normalised_score must be finite"):
        LoopDetectorConfig(min_normalised_score=float("nan"))


def test_a_keyframe_without_descriptors_is_added_and_matches_nothing() -> None:
    det = LoopDetector(config=LoopDetectorConfig(exclude_recent=0, temporal_consistency=1))
    strip = _strip(4)
    rng = np.random.default_rng(4)
    det.push(_view(strip, 0, rng))
    empty = det.push(np.zeros((0, 32), np.uint8))
    assert empty.entry == 1 and empty.status == "no_results" and len(det.database.bow(1)) == 0
    after = det.push(_view(strip, 0, rng))  # its prior (the empty keyframe) scores 0
    assert after.status == "low_prior_score" and after.results[0].entry == 0
