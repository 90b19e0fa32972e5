"""A bag-of-words vocabulary of ORB descriptors (DBoW2's, as ORB-SLAM uses it for place recognition).

A tree of ``branching`` children per node, ``depth`` levels deep, is trained by hierarchical
k-medians in Hamming space (k-means++ seeding, bitwise-majority centres); its leaves are the words.
An image becomes a sparse vector of tf-idf word weights (idf: log of the training images over those
holding the word), L1-normalised; two vectors score ``1 - |a - b|_1 / 2`` in [0, 1]. A word stands
for a kind of corner, wherever in the image and at whatever rotation it appears, so the vector
recognises a place seen again from another heading or position (a thumbnail compares pixels in
place and does not).

Nothing can be downloaded where EVP runs: the shipped vocabulary is trained by EVP itself on images
it renders (``evp vocabulary build``; see ``sim/vocabulary_images.py``), and users can train one on
their own flights. Its files are in ``evp.io.vocabulary_files``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from evp.errors import DataError, UsageError
from evp.vision.matching import hamming_pairs

DESCRIPTOR_BYTES = 32


@dataclass(frozen=True)
class BowVector:
    """Word ids, ascending and unique, and their L1-normalised tf-idf weights."""

    words: np.ndarray  # (W,) int32
    weights: np.ndarray  # (W,) float64

    def __len__(self) -> int:
        return len(self.words)


def bow_score(a: BowVector, b: BowVector) -> float:
    """DBoW2's L1 score: 1 - |a - b|_1 / 2, from the words the two share (0: none, 1: the same)."""
    _, ia, ib = np.intersect1d(a.words, b.words, assume_unique=True, return_indices=True)
    wa, wb = a.weights[ia], b.weights[ib]
    return float(0.5 * np.sum(np.abs(wa) + np.abs(wb) - np.abs(wa - wb)))


@dataclass(frozen=True)
class Vocabulary:
    branching: int
    depth: int
    centres: np.ndarray  # (nodes, 32) uint8; node 0 is the root (no centre)
    children: np.ndarray  # (nodes, branching) int32, -1 where none; a leaf has none
    word_of_node: np.ndarray  # (nodes,) int32, -1 for inner nodes
    idf: np.ndarray  # (words,) float64
    notes: dict = field(default_factory=dict)  # what it was trained on

    @property
    def n_words(self) -> int:
        return len(self.idf)

    def words(self, descriptors: np.ndarray) -> np.ndarray:
        """The word of each (N, 32) descriptor: down the tree, the nearest child at each level."""
        node = np.zeros(len(descriptors), np.int64)
        rows_all = np.arange(len(descriptors))
        for _ in range(self.depth):
            inner = self.word_of_node[node] < 0
            if not inner.any():
                break
            rows = rows_all[inner]
            kids = self.children[node[rows]]  # (n, branching)
            valid = kids >= 0
            pair_rows = np.repeat(rows, self.branching)
            distances = hamming_pairs(descriptors, self.centres, pair_rows, np.maximum(kids, 0).ravel()).reshape(kids.shape)
            distances[~valid] = np.inf
            node[rows] = kids[np.arange(len(rows)), np.argmin(distances, axis=1)]
        return self.word_of_node[node]

    def transform(self, descriptors: np.ndarray) -> BowVector:
        if len(descriptors) == 0:
            return BowVector(np.zeros(0, np.int32), np.zeros(0))
        words, counts = np.unique(self.words(descriptors), return_counts=True)
        weights = counts / len(descriptors) * self.idf[words]
        keep = weights > 0
        words, weights = words[keep], weights[keep]
        total = weights.sum()
        return BowVector(words.astype(np.int32), weights / total if total > 0 else weights)

    def problems(self) -> list[str]:
        """What makes the tree inconsistent (arrays of the wrong type or size, indices out of
        range); empty for a sound vocabulary."""
        nodes = len(self.centres)
        problems = []
        if self.centres.dtype != np.uint8 or self.centres.shape[1:] != (DESCRIPTOR_BYTES,):
            problems.append("centres are not 32-byte ORB descriptors")
        if self.children.shape != (nodes, self.branching) or self.word_of_node.shape != (nodes,):
            problems.append("tree arrays of inconsistent sizes")
        elif self.children.max(initial=-1) >= nodes or (self.word_of_node >= len(self.idf)).any():
            problems.append("a node or word index out of range")
        return problems


def train_vocabulary(
    descriptor_sets: list[np.ndarray],
    branching: int = 10,
    depth: int = 4,
    iterations: int = 10,
    seed: int = 0,
    notes: dict | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Vocabulary:
    """A vocabulary from the descriptors of training images (one (N, 32) array per image).

    ``progress(done, total)`` is called as nodes are clustered (``total`` grows while the tree
    does)."""
    if branching < 2 or depth < 1:
        raise UsageError(f"a vocabulary needs branching >= 2 and depth >= 1, not {branching} and {depth}")
    sets = [np.ascontiguousarray(d, np.uint8).reshape(-1, DESCRIPTOR_BYTES) for d in descriptor_sets]
    descriptors = np.concatenate(sets) if sets else np.zeros((0, DESCRIPTOR_BYTES), np.uint8)
    if len(descriptors) < branching:
        raise DataError(f"{len(descriptors)} descriptors cannot train a vocabulary of {branching} branches")
    rng = np.random.default_rng(seed)
    centres = [np.zeros(DESCRIPTOR_BYTES, np.uint8)]
    children: list[list[int]] = [[]]
    levels = [0]
    pending = [(0, np.arange(len(descriptors)))]
    done = 0
    while pending:
        node, members = pending.pop(0)
        if levels[node] < depth and len(members) > 1:  # one descriptor left: a word already
            if len(members) <= branching:
                groups = [members[[i]] for i in range(len(members))]
                group_centres = descriptors[members]
            else:
                group_centres, labels = _k_medians(descriptors[members], branching, iterations, rng)
                groups = [members[labels == c] for c in range(len(group_centres))]
            for centre, group in zip(group_centres, groups):
                child = len(centres)
                centres.append(centre)
                children.append([])
                levels.append(levels[node] + 1)
                children[node].append(child)
                pending.append((child, group))
        done += 1
        if progress is not None:
            progress(done, done + len(pending))
    return _with_weights(sets, branching, depth, np.array(centres), children, notes or {})


def _with_weights(sets: list[np.ndarray], branching: int, depth: int, centres: np.ndarray, children: list[list[int]], notes: dict) -> Vocabulary:
    table = np.full((len(centres), branching), -1, np.int32)
    for node, kids in enumerate(children):
        table[node, : len(kids)] = kids
    leaves = np.flatnonzero(table[:, 0] < 0)
    word_of_node = np.full(len(centres), -1, np.int32)
    word_of_node[leaves] = np.arange(len(leaves))
    unweighted = Vocabulary(branching, depth, centres, table, word_of_node, np.ones(len(leaves)), notes)
    images_with_word = np.zeros(len(leaves))
    for image in sets:
        if len(image):
            images_with_word[np.unique(unweighted.words(image))] += 1
    images = max(1, sum(len(image) > 0 for image in sets))
    with np.errstate(divide="ignore"):
        idf = np.where(images_with_word > 0, np.log(images / np.maximum(images_with_word, 1)), 0.0)
    return Vocabulary(branching, depth, centres, table, word_of_node, idf, notes)


def _distances_to(descriptors: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Hamming distance of every descriptor to one centre."""
    return hamming_pairs(descriptors, centre[None], np.arange(len(descriptors)), np.zeros(len(descriptors), int))


def _k_medians(descriptors: np.ndarray, k: int, iterations: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """k centres (bitwise majority of their members) and each descriptor's label; k-means++
    seeding, as DBoW2. Clusters left empty are dropped, so fewer than k may come back."""
    chosen = [descriptors[rng.integers(len(descriptors))]]
    nearest = _distances_to(descriptors, chosen[0]).astype(float)
    for _ in range(k - 1):
        weights = nearest**2
        if weights.sum() == 0:
            break  # every descriptor equals a centre already
        chosen.append(descriptors[rng.choice(len(descriptors), p=weights / weights.sum())])
        nearest = np.minimum(nearest, _distances_to(descriptors, chosen[-1]))
    centres = np.array(chosen)
    bits = np.unpackbits(descriptors, axis=1).astype(np.float32)
    labels = np.full(len(descriptors), -1)
    for _ in range(iterations):
        distances = np.stack([_distances_to(descriptors, c) for c in centres], axis=1)
        new_labels = np.argmin(distances, axis=1)
        if np.array_equal(new_labels, labels):
            break
        labels = new_labels
        one_hot = np.zeros((len(centres), len(descriptors)), np.float32)
        one_hot[labels, np.arange(len(descriptors))] = 1.0
        sizes = one_hot.sum(axis=1)
        used = sizes > 0
        majority = (one_hot[used] @ bits) > 0.5 * sizes[used, None]  # ties go to 0, as in DBoW2
        centres = np.packbits(majority.astype(np.uint8), axis=1)
        labels = np.cumsum(used)[labels] - 1  # renumber over the clusters kept
    return centres, labels
