"""A database of keyframes' bags of words (DBoW2's ``TemplatedDatabase``): an inverted index
(word -> the entries that have it, with its weight there) that scores a query against every
entry at once, and a direct index (entry -> node of the tree at a chosen level -> the entry's
feature indices under it) for matching features guided by the tree later.

Entries are numbered 0, 1, ... in the order they are added.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import PlaceError
from quadnav.place.vocabulary import BowVector, Vocabulary, check_descriptors

__all__ = ["Database", "DirectIndex", "QueryResult"]

IntArray = NDArray[np.int64]
FloatArray = NDArray[np.float64]

#: Postings a word's buffer starts with (it doubles when full).
_FIRST_CAPACITY = 8


@dataclass(frozen=True, slots=True, kw_only=True)
class QueryResult:
    """An entry a query found, with DBoW2's L1 ``score`` against it (in [0, 1])."""

    entry: int
    score: float


@dataclass(frozen=True, slots=True, kw_only=True)
class DirectIndex:
    """An entry's features grouped by their node at the database's direct-index level:
    ``nodes`` (sorted, distinct), and the feature indices of ``nodes[i]`` are
    ``features[offsets[i]:offsets[i + 1]]``."""

    nodes: IntArray
    offsets: IntArray
    features: IntArray

    def features_of(self, node: int) -> IntArray:
        """The indices of the entry's features under ``node`` (empty if none)."""
        i = int(np.searchsorted(self.nodes, node))
        if i == len(self.nodes) or self.nodes[i] != node:
            return np.zeros(0, np.int64)
        return self.features[self.offsets[i] : self.offsets[i + 1]]

    @classmethod
    def of(cls, nodes: IntArray) -> DirectIndex:
        """The index of features whose nodes are ``nodes`` ``(N,)``."""
        order = np.argsort(nodes, kind="stable")
        uniq, starts = np.unique(nodes[order], return_index=True)
        return cls(nodes=uniq, offsets=np.append(starts, len(nodes)), features=order)


def _ranges(starts: IntArray, lengths: IntArray) -> IntArray:
    """The concatenated ``arange(s, s + n)`` of every start and length, without a loop."""
    total = int(lengths.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    offsets = np.cumsum(lengths) - lengths  # where each range begins in the output
    return np.repeat(starts - offsets, lengths) + np.arange(total)


class _Postings:
    """Per word a block of (entry, weight) postings in two shared pools; a full block moves to
    the pool's end at twice its capacity (amortised constant time), all words at once."""

    def __init__(self, n_words: int) -> None:
        self.start = np.zeros(n_words, np.int64)
        self.size = np.zeros(n_words, np.int64)
        self.cap = np.zeros(n_words, np.int64)
        self.entries = np.zeros(1 << 16, np.int32)
        self.weights = np.zeros(1 << 16, np.float32)
        self.end = 0  # the pool's used length

    def _grow(self, words: IntArray) -> None:
        """Moves the blocks of ``words`` (full or new) to the pool's end, twice as large."""
        cap = np.maximum(self.cap[words] * 2, _FIRST_CAPACITY)
        new_start = self.end + np.cumsum(cap) - cap
        need = self.end + int(cap.sum())
        if need > len(self.entries):
            size = max(need, 2 * len(self.entries))
            self.entries = np.resize(self.entries, size)
            self.weights = np.resize(self.weights, size)
        n = self.size[words]
        src, dst = _ranges(self.start[words], n), _ranges(new_start, n)
        self.entries[dst] = self.entries[src]
        self.weights[dst] = self.weights[src]
        self.start[words], self.cap[words] = new_start, cap
        self.end = need

    def add(self, entry: int, bow: BowVector) -> None:
        w = bow.words.astype(np.int64)
        full = w[self.size[w] == self.cap[w]]
        if len(full):
            self._grow(full)
        at = self.start[w] + self.size[w]
        self.entries[at] = entry
        self.weights[at] = bow.weights
        self.size[w] += 1

    def gather(
        self, bow: BowVector
    ) -> tuple[NDArray[np.int32], NDArray[np.float32], NDArray[np.float32]]:
        """The postings of ``bow``'s words: their entries, weights, and the query's weight."""
        w = bow.words.astype(np.int64)
        n = self.size[w]
        idx = _ranges(self.start[w], n)
        return self.entries[idx], self.weights[idx], np.repeat(bow.weights.astype(np.float32), n)


class Database:
    """Keyframes' bags of words over ``vocabulary``, with the inverted index and the direct
    index at ``direct_level`` (levels below the root; DBoW2 keeps it 4 levels up from the
    leaves of its 6-level tree, the second level: 100 nodes)."""

    def __init__(self, vocabulary: Vocabulary, *, direct_level: int = 2) -> None:
        if not 0 <= direct_level <= vocabulary.depth:
            raise PlaceError(
                f"direct_level must be 0..{vocabulary.depth} (the tree's depth), got {direct_level}"
            )
        self.vocabulary = vocabulary
        self.direct_level = direct_level
        self._postings = _Postings(vocabulary.n_words)
        self._bows: list[BowVector] = []
        self._direct: list[DirectIndex] = []

    def __len__(self) -> int:
        return len(self._bows)

    def transform(self, descriptors: object) -> tuple[BowVector, DirectIndex]:
        """An image's bag of words and its direct index (nothing is added)."""
        words, nodes = self.vocabulary.descend(descriptors, level=self.direct_level)
        return self.vocabulary.bow_of_words(words), DirectIndex.of(nodes)

    def add(self, descriptors: object) -> int:
        """Adds a keyframe's descriptors ``(N, 32)`` uint8; returns its entry id."""
        return self.add_bow(*self.transform(check_descriptors(descriptors)))

    def add_bow(self, bow: BowVector, direct: DirectIndex) -> int:
        """Adds a keyframe already transformed by :meth:`transform`; returns its entry id."""
        entry = len(self._bows)
        self._postings.add(entry, bow)
        self._bows.append(bow)
        self._direct.append(direct)
        return entry

    def bow(self, entry: int) -> BowVector:
        """The bag of words of ``entry``."""
        return self._bows[self._checked(entry)]

    def direct(self, entry: int) -> DirectIndex:
        """The direct index of ``entry``."""
        return self._direct[self._checked(entry)]

    def _checked(self, entry: int) -> int:
        if not 0 <= entry < len(self._bows):
            raise PlaceError(f"no database entry {entry} (it has {len(self._bows)})")
        return entry

    def scores(self, bow: BowVector) -> FloatArray:
        """The L1 score of ``bow`` against every entry (0 where no word is shared)."""
        e, v, q = self._postings.gather(bow)
        # DBoW2's L1 score over the common words, -(|q - v| - q - v) / 2, is min(q, v) for
        # weights >= 0
        return np.bincount(e, weights=np.minimum(q, v), minlength=len(self._bows)).astype(
            np.float64
        )

    def query(
        self, bow: BowVector, *, max_results: int = 50, max_entry: int | None = None
    ) -> tuple[QueryResult, ...]:
        """The ``max_results`` entries (at most ``max_entry``, if given) that score best against
        ``bow``, best first; entries sharing no word are left out."""
        s = self.scores(bow)
        if max_entry is not None:
            s = s[: max(max_entry + 1, 0)]
        cand = np.flatnonzero(s > 0)
        if len(cand) > max_results:
            cand = cand[np.argpartition(-s[cand], max_results - 1)[:max_results]]
        cand = cand[np.lexsort((cand, -s[cand]))]  # best first, ties by entry
        return tuple(QueryResult(entry=int(i), score=float(s[i])) for i in cand)
