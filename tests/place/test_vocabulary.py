"""The vocabulary tree: training from a seed, descent, bags of words, DBoW2's L1 score, the
shipped file and bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quadnav.errors import PlaceError
from quadnav.place import BowVector, default_vocabulary, l1_score, load_vocabulary
from quadnav.place.train import k_majority, train_vocabulary
from quadnav.place.vocabulary import Vocabulary

SHIPPED = Path(__file__).resolve().parents[2] / "src/quadnav/place/data/orb_vocabulary.npz"


def _flip(d: np.ndarray, p: float, rng: np.random.Generator) -> np.ndarray:
    return d ^ np.packbits(rng.random((len(d), 256)) < p, axis=1)


def _noisy_clusters(seed: int, n: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, (60, 32), dtype=np.uint8)
    d = _flip(base[rng.integers(0, 60, n)], 0.05, rng)
    return d, np.arange(n) // 30


def test_training_is_deterministic_from_the_seed() -> None:
    d, img = _noisy_clusters(0)
    a = train_vocabulary(d, img, branching=5, depth=3, rng=np.random.default_rng(7))
    b = train_vocabulary(d, img, branching=5, depth=3, rng=np.random.default_rng(7))
    c = train_vocabulary(d, img, branching=5, depth=3, rng=np.random.default_rng(8))
    np.testing.assert_array_equal(a.centres, b.centres)
    np.testing.assert_array_equal(a.parent, b.parent)
    np.testing.assert_array_equal(a.idf, b.idf)
    assert a.centres.shape != c.centres.shape or not np.array_equal(a.centres, c.centres)
    words_a, _ = a.descend(d)
    np.testing.assert_array_equal(words_a, b.descend(d)[0])


def _clean_tree(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """4 random roots, 4 children each 24 bits away from their root, 10 copies of each child."""
    rng = np.random.default_rng(seed)
    roots = rng.integers(0, 256, (4, 32), dtype=np.uint8)
    kids = []
    for r in roots:
        for j in range(4):
            bits = np.zeros(256, bool)
            bits[j * 24 : (j + 1) * 24] = True  # disjoint flips: the root is their majority
            kids.append(r ^ np.packbits(bits))
    leaves = np.array(kids)
    return rng.permutation(np.repeat(leaves, 10, axis=0)), leaves


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_centre_descends_to_its_own_leaf(seed: int) -> None:
    d, leaves = _clean_tree(seed)
    v = train_vocabulary(
        d, np.arange(len(d)), branching=4, depth=2, rng=np.random.default_rng(seed)
    )
    assert v.n_words == 16
    # every leaf's centre is one of the children, and descends to its own word
    words, _ = v.descend(v.centres[v.node_of_word])
    np.testing.assert_array_equal(words, np.arange(v.n_words))
    assert {bytes(c) for c in v.centres[v.node_of_word]} == {bytes(c) for c in leaves}
    # a child with 8 more bits flipped still lands in its own leaf
    noisy = _flip(leaves, 8 / 256, np.random.default_rng(seed))
    got, at1 = v.descend(noisy, level=1)
    want, _ = v.descend(leaves)
    assert (got == want).mean() >= 0.9
    np.testing.assert_array_equal(at1, v.parent[v.node_of_word[got]])  # its leaf's parent


def test_k_majority_centre_is_the_bitwise_majority() -> None:
    rng = np.random.default_rng(3)
    d = rng.integers(0, 256, (7, 32), dtype=np.uint8)
    labels, centres = k_majority(d, 1, rng)
    bits = np.unpackbits(d, axis=1)
    want = np.packbits(bits.sum(axis=0) >= 4)  # 7 rows: a bit set in at least 4
    assert labels.tolist() == [0] * 7
    np.testing.assert_array_equal(centres[0], want)


def _bow(words: list[int], weights: list[float]) -> BowVector:
    w = np.asarray(weights, float)
    return BowVector(np.asarray(words, np.int32), w / w.sum())


def test_l1_score_identical_disjoint_and_dense_formula() -> None:
    a = _bow([1, 5, 9], [0.2, 0.3, 0.5])
    assert l1_score(a, a) == pytest.approx(1.0)
    assert l1_score(a, _bow([2, 6], [1.0, 1.0])) == pytest.approx(0.0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        dense = rng.random((2, 30)) * (rng.random((2, 30)) < 0.4)
        dense[:, 0] += 0.01  # never empty
        dense /= dense.sum(axis=1, keepdims=True)
        u, v = (BowVector(np.flatnonzero(x).astype(np.int32), x[x > 0]) for x in dense)
        want = 1.0 - 0.5 * np.abs(dense[0] - dense[1]).sum()
        assert l1_score(u, v) == pytest.approx(want, abs=1e-12)
        assert l1_score(v, u) == pytest.approx(want, abs=1e-12)


def test_bow_is_l1_normalised_tf_idf() -> None:
    v = default_vocabulary()
    d = np.random.default_rng(0).integers(0, 256, (200, 32), dtype=np.uint8)
    words, _ = v.descend(d)
    bow = v.bow(d)
    assert bow.weights.sum() == pytest.approx(1.0)
    w = int(bow.words[0])
    tf = np.count_nonzero(words == w) / len(d)
    raw = {int(x): np.count_nonzero(words == x) / len(d) * v.idf[x] for x in np.unique(words)}
    assert bow.weights[0] == pytest.approx(tf * v.idf[w] / sum(raw.values()), rel=1e-5)


def test_shipped_vocabulary_loads_and_round_trips(tmp_path: Path) -> None:
    v = default_vocabulary()
    assert v.branching == 10 and v.depth == 5
    assert SHIPPED.stat().st_size < 4_000_000
    assert 10_000 < v.n_words <= 10**5
    path = tmp_path / "v.npz"
    np.savez_compressed(path, **v.to_arrays())
    w = load_vocabulary(path)
    np.testing.assert_array_equal(w.centres, v.centres)
    np.testing.assert_array_equal(w.idf, v.idf)


def _one_line(err: pytest.ExceptionInfo[PlaceError]) -> str:
    msg = str(err.value)
    assert "\n" not in msg
    return msg


def test_missing_corrupt_or_foreign_vocabulary_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(PlaceError, match="no such vocabulary") as e:
        load_vocabulary(tmp_path / "none.npz")
    _one_line(e)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(SHIPPED.read_bytes()[:5000])  # truncated
    with pytest.raises(PlaceError, match="corrupt") as e:
        load_vocabulary(bad)
    _one_line(e)
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, centres=np.zeros((3, 32), np.uint8))
    with pytest.raises(PlaceError, match="not a quadnav vocabulary") as e:
        load_vocabulary(foreign)
    _one_line(e)
    arrays = default_vocabulary().to_arrays()
    arrays["parent"] = arrays["parent"][::-1].copy()  # children before parents
    broken = tmp_path / "broken.npz"
    np.savez(broken, **arrays)
    with pytest.raises(PlaceError, match="parent") as e:
        load_vocabulary(broken)
    _one_line(e)


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((5, 32), np.float32),
        np.zeros((5, 31), np.uint8),
        np.zeros(32, np.uint8),
        [[1, 2, 3]],
    ],
)
def test_bad_descriptors_are_one_line_errors(bad: object) -> None:
    with pytest.raises(PlaceError, match=r"\(N, 32\) uint8") as e:
        default_vocabulary().bow(bad)
    _one_line(e)


def test_tree_needs_consistent_arrays() -> None:
    with pytest.raises(PlaceError, match="more than branching"):
        Vocabulary.from_tree(
            np.zeros((4, 32), np.uint8), np.array([-1, 0, 0, 0]), np.ones(3), branching=2
        )
    with pytest.raises(PlaceError, match="idf"):
        Vocabulary.from_tree(
            np.zeros((3, 32), np.uint8), np.array([-1, 0, 0]), np.ones(5), branching=2
        )
