"""Training a vocabulary tree: hierarchical k-majority over binary descriptors (DBoW2's
hierarchical k-means with the bitwise majority as the centre of a cluster, k-means++ seeding in
Hamming distance), then DBoW2's idf from the training images.

Pure computation on descriptor arrays: ``scripts/train_place_vocabulary.py`` renders the
training worlds, describes them and calls :func:`train_vocabulary`.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import PlaceError
from quadnav.place.vocabulary import (
    DESCRIPTOR_BYTES,
    Vocabulary,
    check_descriptors,
    hamming,
)

__all__ = ["k_majority", "train_vocabulary"]

U8 = NDArray[np.uint8]
IntArray = NDArray[np.int64]


def _seeds(d: U8, k: int, rng: np.random.Generator) -> IntArray:
    """k-means++ seeding in Hamming distance: up to ``k`` distinct rows of ``d``."""
    chosen = [int(rng.integers(len(d)))]
    dist = hamming(d, d[chosen[0]]).astype(np.float64)
    while len(chosen) < k:
        p = dist**2
        total = p.sum()
        if total <= 0:  # every row equals a seed
            break
        chosen.append(int(rng.choice(len(d), p=p / total)))
        dist = np.minimum(dist, hamming(d, d[chosen[-1]]))
    return np.array(chosen, np.int64)


def k_majority(
    descriptors: U8, k: int, rng: np.random.Generator, *, max_iterations: int = 10
) -> tuple[IntArray, U8]:
    """Clusters ``descriptors`` ``(M, 32)`` into at most ``k``: each row's label and the
    centres ``(k', 32)``, each the bitwise majority of its members (a bit is set where at
    least half of them have it, as DBoW2's ORB mean). Empty clusters are dropped."""
    d = check_descriptors(descriptors)
    bits = np.unpackbits(d, axis=1).astype(np.float32)  # (M, 256)
    pop = bits.sum(axis=1)
    centres = d[_seeds(d, k, rng)]
    labels = np.full(len(d), -1, np.int64)
    for _ in range(max_iterations):
        cbits = np.unpackbits(centres, axis=1).astype(np.float32)
        dist = pop[:, None] + cbits.sum(axis=1)[None, :] - 2.0 * (bits @ cbits.T)
        new = dist.argmin(axis=1)
        if np.array_equal(new, labels):
            break
        labels = new
        onehot = (labels[:, None] == np.arange(len(centres))[None, :]).astype(np.float32)
        counts = onehot.sum(axis=0)
        sums = onehot.T @ bits
        majority = (2.0 * sums >= counts[:, None]) & (counts[:, None] > 0)
        centres = np.where(counts[:, None] > 0, np.packbits(majority, axis=1), centres)
    used = np.unique(labels)
    remap = np.full(len(centres), -1, np.int64)
    remap[used] = np.arange(len(used))
    return remap[labels], np.ascontiguousarray(centres[used])


def _tree(
    d: U8, branching: int, depth: int, rng: np.random.Generator, max_iterations: int
) -> tuple[U8, NDArray[np.int32]]:
    """Centres and parents of the tree, breadth first (a parent before its children)."""
    centres = [np.zeros(DESCRIPTOR_BYTES, np.uint8)]
    parent = [-1]
    queue: deque[tuple[int, IntArray, int]] = deque([(0, np.arange(len(d)), 0)])
    while queue:
        node, members, level = queue.popleft()
        if level >= depth or len(members) <= (branching if node else 0):
            continue  # a leaf: too deep or too few to split
        labels, cents = k_majority(d[members], branching, rng, max_iterations=max_iterations)
        for j, c in enumerate(cents):
            centres.append(c)
            parent.append(node)
            queue.append((len(parent) - 1, members[labels == j], level + 1))
    return np.array(centres, np.uint8), np.array(parent, np.int32)


def train_vocabulary(
    descriptors: object,
    image_of: object,
    *,
    branching: int = 10,
    depth: int = 5,
    rng: np.random.Generator,
    max_iterations: int = 10,
) -> Vocabulary:
    """A vocabulary tree of ``branching`` and ``depth`` from training ``descriptors``
    ``(M, 32)`` uint8, ``image_of`` ``(M,)`` saying which training image each came from (for
    DBoW2's ``idf = log(N / N_w)``; a word no training image has gets the rarest idf)."""
    d = check_descriptors(descriptors, "training descriptors")
    img = np.asarray(image_of)
    if img.shape != (len(d),) or img.dtype.kind not in "iu":
        raise PlaceError(f"image_of must be (M,) integers, one per descriptor, got {img.shape}")
    if len(d) <= branching or not 2 <= branching <= 64 or not 1 <= depth <= 8:
        raise PlaceError(
            f"cannot train branching {branching}, depth {depth} on {len(d)} descriptors"
        )
    centres, parent = _tree(d, branching, depth, rng, max_iterations)
    n_leaves = int(np.count_nonzero(np.bincount(parent[1:], minlength=len(parent))[1:] == 0))
    vocab = Vocabulary.from_tree(
        centres, parent, np.ones(n_leaves, np.float32), branching=branching
    )
    words = np.concatenate([vocab.descend(d[i : i + 65536])[0] for i in range(0, len(d), 65536)])
    _, image = np.unique(img, return_inverse=True)
    n_images = int(image.max()) + 1
    pairs = np.unique(words * n_images + image)
    n_w = np.bincount(pairs // n_images, minlength=vocab.n_words)
    idf = np.log(n_images / np.maximum(n_w, 1)).astype(np.float32)
    return Vocabulary.from_tree(centres, parent, idf, branching=branching)
