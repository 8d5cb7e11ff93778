"""Loop candidates from a stream of keyframes, as DLoopDetector (Galvez-Lopez and Tardos, 2012)
finds them before geometric verification.

For each new keyframe: its bag of words queries the database, leaving out the most recent
``exclude_recent`` entries (their views overlap the current one anyway); each score is divided by
the score of the keyframe against the previous one (DBoW2's normalised score: how much better than
its neighbour in time an old entry matches), and those below ``min_normalised_score`` go. The rest
are grouped into islands of entries close in time (consecutive ids within ``island_gap``), scored
by the sum of their members' scores; the best island is a candidate, and a loop only when the
islands of ``temporal_consistency`` successive queries overlap or lie within
``island_distance`` entries of one another. Then the keyframe is added to the database.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from quadnav.errors import PlaceError
from quadnav.place.database import Database, QueryResult
from quadnav.place.vocabulary import BowVector, Vocabulary, check_descriptors, l1_score

__all__ = ["Detection", "DetectionStatus", "Island", "LoopDetector", "LoopDetectorConfig"]

DetectionStatus = Literal[
    "too_few_entries",  # nothing older than the excluded window yet
    "no_results",  # no entry shares a word with the keyframe
    "low_prior_score",  # the keyframe scores too low against the previous one to normalise
    "low_scores",  # no normalised score above the threshold
    "no_islands",  # no island with enough members
    "not_consistent",  # an island, not yet over enough successive queries
    "detected",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopDetectorConfig:
    """DLoopDetector's parameters. Its defaults (``min_normalised_score`` 0.3, 3 consistent
    queries) are for frames at video rate, where the previous frame scores high; keyframes lie
    further apart, so both are stricter here: 0.7 and 5, chosen on seeds 10-12 of
    ``benchmarks/place.py``'s two laps in the room and the hall (not the seeds it reports).
    (A plain dataclass until a command's configuration carries it.)"""

    exclude_recent: int = 30  # most recent entries a query leaves out (dislocal)
    max_results: int = 50  # database results per query
    min_normalised_score: float = 0.7  # least score divided by the prior score (alpha)
    min_prior_score: float = 0.005  # least score against the previous keyframe
    island_gap: int = 3  # largest id gap inside an island
    min_island_size: int = 1  # fewest entries of an island
    temporal_consistency: int = 5  # successive consistent queries before a loop (k)
    island_distance: int = 3  # largest id gap between consistent islands
    max_query_gap: int = 2  # largest entry gap between queries kept consistent

    def __post_init__(self) -> None:
        least = {"exclude_recent": 0, "max_results": 1, "island_gap": 0, "min_island_size": 1,
                 "temporal_consistency": 1, "island_distance": 0, "max_query_gap": 1}  # fmt: skip
        for name, lo in least.items():
            value = getattr(self, name)
            if not isinstance(value, int) or value < lo:
                raise PlaceError(f"loop detector: {name} must be an integer >= {lo}, got {value}")
        for name in ("min_normalised_score", "min_prior_score"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise PlaceError(f"loop detector: {name} must be finite and >= 0, got {value}")


@dataclass(frozen=True, slots=True, kw_only=True)
class Island:
    """Database entries ``first..last`` close in time, their summed ``score`` and their best
    entry ``best`` (scoring ``best_score``)."""

    first: int
    last: int
    score: float
    best: int
    best_score: float

    def near(self, other: Island, gap: int) -> bool:
        """Whether the two overlap or lie within ``gap`` entries of each other."""
        return max(self.first, other.first) - min(self.last, other.last) <= gap


@dataclass(frozen=True, slots=True, kw_only=True)
class Detection:
    """What one keyframe's query found: its own ``entry`` id (it is added after the query),
    the ``status``, the ``match`` (the best island's best entry: a loop when ``status`` is
    ``detected``, else a candidate or None), its normalised score, the island and how many
    successive queries it has been consistent over."""

    entry: int
    status: DetectionStatus
    match: int | None = None
    normalised_score: float = 0.0
    island: Island | None = None
    consistent: int = 0
    results: tuple[QueryResult, ...] = ()

    @property
    def detected(self) -> bool:
        return self.status == "detected"


def islands(results: tuple[QueryResult, ...], gap: int, min_size: int) -> list[Island]:
    """DLoopDetector's islands: results grouped by entry id (consecutive within ``gap``),
    those with at least ``min_size`` members, best summed score first."""
    if not results:
        return []
    ids = np.array([r.entry for r in results])
    sc = np.array([r.score for r in results])
    order = np.argsort(ids, kind="stable")
    ids, sc = ids[order], sc[order]
    starts = np.r_[0, np.flatnonzero(np.diff(ids) > gap) + 1]
    ends = np.r_[starts[1:], len(ids)]
    label = np.repeat(np.arange(len(starts)), ends - starts)
    total = np.add.reduceat(sc, starts)
    best = np.lexsort((-sc, label))[starts]  # each island's best member (first of ties)
    keep = np.flatnonzero(ends - starts >= min_size)
    keep = keep[np.lexsort((ids[starts[keep]], -total[keep]))]
    return [
        Island(
            first=int(ids[starts[i]]),
            last=int(ids[ends[i] - 1]),
            score=float(total[i]),
            best=int(ids[best[i]]),
            best_score=float(sc[best[i]]),
        )
        for i in keep
    ]


class LoopDetector:
    """DLoopDetector over a :class:`Database` of ``vocabulary`` (the shipped one by default)."""

    def __init__(
        self, vocabulary: Vocabulary | None = None, config: LoopDetectorConfig | None = None
    ) -> None:
        if vocabulary is None:
            from quadnav.place.vocabulary import default_vocabulary

            vocabulary = default_vocabulary()
        self.config = config or LoopDetectorConfig()
        self.database = Database(vocabulary)
        self._last_island: Island | None = None
        self._last_query = -(10**9)
        self._consistent = 0

    def push(self, descriptors: object) -> Detection:
        """Queries with a keyframe's descriptors ``(N, 32)`` uint8, then adds it."""
        bow, direct = self.database.transform(check_descriptors(descriptors))
        found = self.detect(len(self.database), bow)
        self.database.add_bow(bow, direct)
        return found

    def detect(self, entry: int, bow: BowVector) -> Detection:
        """The query of :meth:`push` for a keyframe that will be ``entry`` (nothing is added)."""
        cfg = self.config
        max_entry = entry - 1 - cfg.exclude_recent
        if max_entry < 0:
            return Detection(entry=entry, status="too_few_entries")
        results = self.database.query(bow, max_results=cfg.max_results, max_entry=max_entry)
        if not results:
            return Detection(entry=entry, status="no_results")
        prior = l1_score(bow, self.database.bow(entry - 1))
        if prior < cfg.min_prior_score:
            return Detection(entry=entry, status="low_prior_score", results=results)
        kept = tuple(r for r in results if r.score >= cfg.min_normalised_score * prior)
        if not kept:
            return Detection(entry=entry, status="low_scores", results=results)
        found = islands(kept, cfg.island_gap, cfg.min_island_size)
        if not found:
            return Detection(entry=entry, status="no_islands", results=results)
        best = found[0]
        consistent = self._update_window(entry, best)
        return Detection(
            entry=entry,
            status="detected" if consistent >= cfg.temporal_consistency else "not_consistent",
            match=best.best,
            normalised_score=best.best_score / prior,
            island=best,
            consistent=consistent,
            results=results,
        )

    def _update_window(self, entry: int, island: Island) -> int:
        """DLoopDetector's temporal window: how many successive queries (at most
        ``max_query_gap`` entries apart) have had islands near one another, this one included."""
        cfg = self.config
        last = self._last_island
        if last is None or entry - self._last_query > cfg.max_query_gap:
            self._consistent = 1
        elif island.near(last, cfg.island_distance):
            self._consistent += 1
        else:
            self._consistent = 1
        self._last_island, self._last_query = island, entry
        return self._consistent
