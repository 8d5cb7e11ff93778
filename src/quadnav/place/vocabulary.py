"""A vocabulary tree over 256-bit binary descriptors (ORB/BRIEF), DBoW2's bag of words.

The tree has ``branching`` children per node and ``depth`` levels below the root; its leaves are
the words. A descriptor descends from the root to the child centre nearest in Hamming distance,
level by level, for all descriptors at once (numpy, 64-bit popcounts). A node with too few
training descriptors to split is a leaf above the last level, as in DBoW2.

An image's bag of words is DBoW2's tf-idf vector: ``tf = n_w / n`` (of its ``n`` descriptors,
``n_w`` fall in word ``w``) times ``idf = log(N / N_w)`` (of ``N`` training images, ``N_w`` contain
``w``), normalised to unit L1 norm. Two vectors score DBoW2's L1 score
``1 - |v - w|_1 / 2`` (1 for the same vector, 0 for vectors with no word in common).

The shipped vocabulary (``data/orb_vocabulary.npz``, trained by
``scripts/train_place_vocabulary.py``) loads on first use of :func:`default_vocabulary`.
"""

from __future__ import annotations

import hashlib
import zipfile
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import PlaceError

__all__ = [
    "DESCRIPTOR_BYTES",
    "VOCABULARY_FORMAT",
    "BowVector",
    "Vocabulary",
    "check_descriptors",
    "default_vocabulary",
    "hamming",
    "l1_score",
    "load_vocabulary",
]

#: Bytes of a descriptor the vocabulary takes (256 bits: ORB, BRIEF-256).
DESCRIPTOR_BYTES = 32
#: What a vocabulary file says it is; a file without it (or another version) is refused.
VOCABULARY_FORMAT = "quadnav-binary-vocabulary-1"
#: The shipped vocabulary, package data beside this module.
_DEFAULT = "orb_vocabulary.npz"

U8 = NDArray[np.uint8]
IntArray = NDArray[np.int64]
FloatArray = NDArray[np.float64]


def check_descriptors(descriptors: object, what: str = "descriptors") -> U8:
    """``descriptors`` as a C-contiguous ``(N, 32)`` uint8 array, or a one-line PlaceError."""
    d = np.asarray(descriptors)
    if d.dtype != np.uint8 or d.ndim != 2 or d.shape[1] != DESCRIPTOR_BYTES:
        raise PlaceError(
            f"{what} must be (N, {DESCRIPTOR_BYTES}) uint8 (256-bit ORB/BRIEF), "
            f"got {d.shape} {d.dtype}"
        )
    return np.ascontiguousarray(d)


def hamming(a: U8, b: U8) -> NDArray[np.int32]:
    """Hamming distances of broadcastable ``(..., 32)`` uint8 descriptors, over the last axis."""
    x = np.bitwise_xor(a.view(np.uint64), b.view(np.uint64))
    return np.asarray(np.bitwise_count(x).sum(axis=-1, dtype=np.int32), np.int32)


@dataclass(frozen=True, slots=True)
class BowVector:
    """A bag of words: the sorted distinct ``words`` of an image and their tf-idf ``weights``,
    which sum to 1 (both empty when no descriptor had a word of positive weight)."""

    words: NDArray[np.int32]
    weights: FloatArray

    def __len__(self) -> int:
        return len(self.words)


def l1_score(a: BowVector, b: BowVector) -> float:
    """DBoW2's L1 score of two L1-normalised bags: ``1 - |a - b|_1 / 2``, in [0, 1]."""
    _, ia, ib = np.intersect1d(a.words, b.words, assume_unique=True, return_indices=True)
    va, vb = a.weights[ia], b.weights[ib]
    # over the common words |va - vb| - |va| - |vb|; the others add |v| to both norms
    return float(-0.5 * np.sum(np.abs(va - vb) - np.abs(va) - np.abs(vb)))


@dataclass(frozen=True, slots=True, eq=False)
class Vocabulary:
    """A trained tree: node centres ``(n_nodes, 32)`` uint8 (node 0 is the root, without a
    centre), each node's ``parent`` (-1 for the root), and ``idf`` per word. Words are the
    leaves in node order; ``children``, ``level``, ``word_of_node`` and ``node_of_word`` are
    derived."""

    centres: U8
    parent: NDArray[np.int32]
    idf: NDArray[np.float32]
    branching: int
    depth: int
    children: NDArray[np.int32]
    level: NDArray[np.int8]
    word_of_node: NDArray[np.int32]
    node_of_word: NDArray[np.int32]
    centres64: NDArray[np.uint64]  # the centres as 4 64-bit words each, for popcounts

    @classmethod
    def from_tree(
        cls, centres: U8, parent: NDArray[np.int32], idf: NDArray[np.float32], *, branching: int
    ) -> Vocabulary:
        """The vocabulary of a tree given by its centres and parents (parents before children)
        and the idf of its leaves in node order; checks that they fit together."""
        centres = check_descriptors(centres, "vocabulary centres")
        parent = np.asarray(parent, np.int32)
        n = len(centres)
        if n < 2 or parent.shape != (n,) or parent[0] != -1:
            raise PlaceError("vocabulary: the tree needs a root (parent -1) and a parent per node")
        if not ((parent[1:] >= 0) & (parent[1:] < np.arange(1, n))).all():
            raise PlaceError("vocabulary: every node's parent must come before it")
        counts = np.bincount(parent[1:], minlength=n)
        if counts.max() > branching or branching < 2:
            raise PlaceError(f"vocabulary: a node has more than branching={branching} children")
        children = np.full((n, branching), -1, np.int32)
        kids = np.arange(1, n, dtype=np.int32)
        order = np.argsort(parent[1:], kind="stable")
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        slot = np.arange(n - 1) - first[parent[1:][order]]
        children[parent[1:][order], slot] = kids[order]
        level = np.zeros(n, np.int8)
        for _ in range(127):  # a node's level settles once its parent's has
            new = np.concatenate([[0], level[parent[1:]] + 1]).astype(np.int8)
            if np.array_equal(new, level):
                break
            level = new
        leaf = counts == 0
        leaf[0] = False
        node_of_word = np.flatnonzero(leaf).astype(np.int32)
        idf = np.asarray(idf, np.float32)
        if idf.shape != (len(node_of_word),) or not (np.isfinite(idf) & (idf >= 0)).all():
            raise PlaceError(f"vocabulary: idf must be {len(node_of_word)} finite weights >= 0")
        word_of_node = np.full(n, -1, np.int32)
        word_of_node[node_of_word] = np.arange(len(node_of_word), dtype=np.int32)
        return cls(
            centres, parent, idf, branching, int(level.max()), children, level,
            word_of_node, node_of_word, np.ascontiguousarray(centres).view(np.uint64),
        )  # fmt: skip

    @property
    def n_words(self) -> int:
        return len(self.node_of_word)

    def descend(self, descriptors: object, *, level: int = 0) -> tuple[IntArray, IntArray]:
        """Each descriptor's word and its node at ``level`` below the root (its leaf where the
        leaf lies higher): two ``(N,)`` arrays. Vectorised over the descriptors."""
        d = check_descriptors(descriptors).view(np.uint64)
        node = np.zeros(len(d), np.int64)
        at_level = node
        for step in range(self.depth):
            ch = np.take(self.children, node, axis=0)
            inner = ch[:, 0] >= 0
            every = bool(inner.all())
            if not every and not inner.any():
                break
            c = ch if every else ch[inner]
            x = np.take(self.centres64, c, axis=0) ^ (d if every else d[inner])[:, None, :]
            bits = np.bitwise_count(x)
            dist = bits[..., 0].astype(np.int16) + bits[..., 1] + bits[..., 2] + bits[..., 3]
            dist[c < 0] = np.iinfo(np.int16).max
            best = c[np.arange(len(c)), dist.argmin(axis=1)]
            if every:
                node = best.astype(np.int64)
            else:
                node = node.copy()
                node[inner] = best
            if step < level:
                at_level = node
        return self.word_of_node[node].astype(np.int64), at_level

    def bow(self, descriptors: object) -> BowVector:
        """The L1-normalised tf-idf bag of words of an image's descriptors."""
        words, _ = self.descend(descriptors)
        return self.bow_of_words(words)

    def bow_of_words(self, words: IntArray) -> BowVector:
        """The bag of words of an image whose descriptors fell in ``words``."""
        uniq, counts = np.unique(words, return_counts=True)
        w = counts / max(len(words), 1) * self.idf[uniq]
        keep = w > 0
        total = float(w[keep].sum())
        if total <= 0:
            return BowVector(np.zeros(0, np.int32), np.zeros(0))
        return BowVector(uniq[keep].astype(np.int32), w[keep] / total)

    @property
    def fingerprint(self) -> str:
        """A short hash of the tree and its weights: a map's bags of words are only good with
        the vocabulary they were made with."""
        return _fingerprint(self.centres.tobytes(), self.parent.tobytes(), self.idf.tobytes())

    def to_arrays(self) -> dict[str, Any]:
        """What :func:`load_vocabulary` reads back (``numpy.savez_compressed(path, **...)``)."""
        return {
            "format": np.array(VOCABULARY_FORMAT),
            "centres": self.centres,
            "parent": self.parent,
            "idf": self.idf,
            "branching": np.array(self.branching),
        }


def _fingerprint(*parts: bytes) -> str:
    h = hashlib.sha256()
    for part in parts:
        h.update(part)
    return h.hexdigest()[:16]


def load_vocabulary(path: Path | str) -> Vocabulary:
    """A vocabulary saved from :meth:`Vocabulary.to_arrays`; a missing, corrupt or foreign file
    is a one-line PlaceError."""
    try:
        with np.load(path, allow_pickle=False) as z:
            if "format" not in z.files or str(z["format"]) != VOCABULARY_FORMAT:
                raise PlaceError(f"{path}: not a quadnav vocabulary ({VOCABULARY_FORMAT})")
            arrays = {k: z[k] for k in ("centres", "parent", "idf", "branching")}
    except PlaceError:
        raise
    except FileNotFoundError:
        raise PlaceError(f"{path}: no such vocabulary file") from None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
        raise PlaceError(f"{path}: corrupt vocabulary file ({type(e).__name__}: {e})") from None
    return Vocabulary.from_tree(
        arrays["centres"], arrays["parent"], arrays["idf"], branching=int(arrays["branching"])
    )


@lru_cache(maxsize=1)
def default_vocabulary() -> Vocabulary:
    """The vocabulary shipped with quadnav (loaded once, on first use)."""
    with resources.as_file(resources.files("quadnav.place") / "data" / _DEFAULT) as path:
        return load_vocabulary(path)
