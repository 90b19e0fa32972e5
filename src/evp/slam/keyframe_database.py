"""Place recognition over the map's keyframes (ORB-SLAM's KeyFrameDatabase on DBoW2 vectors).

An inverted file (word -> keyframes holding it) finds the keyframes sharing words with a query;
those sharing at least 80 % as many words as the best one are scored, and each score is summed
over the keyframe's 10 best covisible neighbours, so a place seen by several keyframes outranks a
single look-alike. Groups scoring at least 75 % of the best group answer, each by its best-scoring
keyframe. Relocalisation asks with a lost frame; loop detection asks with a new keyframe, leaving
out the keyframes already covisible with it and those scoring below its own neighbours.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol

import numpy as np

from evp.vision.vocabulary import BowVector

MIN_COMMON_WORDS_SHARE = 0.8
RETAIN_SHARE = 0.75
GROUP_NEIGHBOURS = 10


class _Covisible(Protocol):
    def best_covisible(self, count: int, min_weight: int = 1) -> list[int]: ...


class KeyframeDatabase:
    """The inverted file is kept as flat arrays of (keyframe, word, weight) entries, appended as
    keyframes arrive: a query scores every keyframe sharing a word with one pass of NumPy over
    them (a per-keyframe Python loop cost 16 ms a keyframe at 500 keyframes). A removed
    keyframe's entries stay until they are half the arrays, then the arrays are rebuilt."""

    def __init__(self) -> None:
        self.vectors: dict[int, BowVector] = {}
        self._kf = np.zeros(0, np.int64)
        self._word = np.zeros(0, np.int64)
        self._weight = np.zeros(0)
        self._size = 0  # entries in use at the start of the arrays

    def __len__(self) -> int:
        return len(self.vectors)

    def add(self, kf_id: int, bow: BowVector) -> None:
        self.vectors[kf_id] = bow
        self._append(np.full(len(bow), kf_id), bow.words, bow.weights)

    def remove(self, kf_id: int) -> None:
        if self.vectors.pop(kf_id, None) is None:
            return
        live = sum(map(len, self.vectors.values()))
        if 2 * live < self._size:
            self._size = 0
            for other_id, bow in self.vectors.items():
                self._append(np.full(len(bow), other_id), bow.words, bow.weights)

    def _append(self, kf_ids: np.ndarray, words: np.ndarray, weights: np.ndarray) -> None:
        end = self._size + len(words)
        if end > len(self._kf):
            capacity = max(2 * len(self._kf), end, 1024)
            self._kf, self._word, self._weight = (np.resize(a, capacity) for a in (self._kf, self._word, self._weight))
        self._kf[self._size : end] = kf_ids
        self._word[self._size : end] = words
        self._weight[self._size : end] = weights
        self._size = end

    def _shared(self, bow: BowVector) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Keyframes sharing words with ``bow`` (ascending ids), how many they share, and their
        L1 scores against it (as :func:`bow_score`)."""
        words = self._word[: self._size]
        slot = np.full(max(int(words.max(initial=-1)), int(bow.words.max(initial=-1))) + 1, -1)
        slot[bow.words] = np.arange(len(bow))
        query_slot = slot[words]
        entries = np.flatnonzero(query_slot >= 0)
        kf_ids = self._kf[entries]
        live = np.zeros(int(kf_ids.max(initial=-1)) + 1, bool)
        known = np.fromiter(self.vectors, np.int64, len(self.vectors))
        live[known[known < len(live)]] = True
        entries, kf_ids = entries[live[kf_ids]], kf_ids[live[kf_ids]]
        ours, theirs = bow.weights[query_slot[entries]], self._weight[entries]
        ids, group = np.unique(kf_ids, return_inverse=True)
        common = np.bincount(group, minlength=len(ids))
        scores = 0.5 * np.bincount(group, np.abs(ours) + np.abs(theirs) - np.abs(ours - theirs), minlength=len(ids))
        return ids, common, scores

    def relocalisation_candidates(self, bow: BowVector, keyframes: Mapping[int, _Covisible], count: int) -> list[int]:
        """Keyframes where a lost frame may be, best group first (at most ``count``)."""
        return self._ranked(self._shared(bow), keyframes, set(), 0.0)[:count]

    def loop_candidates(self, kf_id: int, keyframes: Mapping[int, _Covisible], connected: set[int], neighbours: list[int]) -> list[int]:
        """Keyframes not ``connected`` to ``kf_id`` that look like it at least as much as the
        least alike of its ``neighbours`` (its best covisible keyframes), best group first."""
        shared = self._shared(self.vectors[kf_id])
        ids, _, scores = shared
        score_of = dict(zip(ids.tolist(), scores.tolist(), strict=True))
        bar = min((score_of.get(k, 0.0) for k in neighbours), default=1.0)
        return self._ranked(shared, keyframes, connected | {kf_id}, bar)

    def _ranked(
        self, shared: tuple[np.ndarray, np.ndarray, np.ndarray], keyframes: Mapping[int, _Covisible], excluded: set[int], min_score: float
    ) -> list[int]:
        ids, common, all_scores = shared
        eligible = np.fromiter((k not in excluded and k in keyframes for k in ids.tolist()), bool, len(ids))
        if not eligible.any():
            return []
        kept = eligible & (common > MIN_COMMON_WORDS_SHARE * common[eligible].max())
        scores = dict(zip(ids[kept].tolist(), all_scores[kept].tolist(), strict=True))
        groups: list[tuple[float, int]] = []
        for kf_id, score in scores.items():
            if score < min_score:
                continue
            accumulated, best, best_score = score, kf_id, score
            for neighbour in keyframes[kf_id].best_covisible(GROUP_NEIGHBOURS):
                neighbour_score = scores.get(neighbour)
                if neighbour_score is None:
                    continue
                accumulated += neighbour_score
                if neighbour_score > best_score:
                    best, best_score = neighbour, neighbour_score
            groups.append((accumulated, best))
        if not groups:
            return []
        retain = RETAIN_SHARE * max(accumulated for accumulated, _ in groups)
        ranked: list[int] = []
        for accumulated, best in sorted(groups, key=lambda group: -group[0]):
            if accumulated >= retain and best not in ranked:
                ranked.append(best)
        return ranked
