"""Place recognition over the map's keyframes (ORB-SLAM's KeyFrameDatabase on DBoW2 vectors).

An inverted file (word -> keyframes holding it) finds the keyframes sharing words with a query;
those sharing at least 80 % as many words as the best one are scored, and each score is summed
over the keyframe's 10 best covisible neighbours, so a place seen by several keyframes outranks a
single look-alike. Groups scoring at least 75 % of the best group answer, each by its best-scoring
keyframe. Relocalisation asks with a lost frame; loop detection asks with a new keyframe, leaving
out the keyframes already covisible with it and those scoring below its own neighbours.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Mapping
from itertools import chain
from typing import Protocol

from evp.vision.vocabulary import BowVector, bow_score

MIN_COMMON_WORDS_SHARE = 0.8
RETAIN_SHARE = 0.75
GROUP_NEIGHBOURS = 10


class _Covisible(Protocol):
    def best_covisible(self, count: int, min_weight: int = 1) -> list[int]: ...


class KeyframeDatabase:
    def __init__(self) -> None:
        self.vectors: dict[int, BowVector] = {}
        self._postings: defaultdict[int, set[int]] = defaultdict(set)

    def __len__(self) -> int:
        return len(self.vectors)

    def add(self, kf_id: int, bow: BowVector) -> None:
        self.vectors[kf_id] = bow
        for word in bow.words.tolist():
            self._postings[word].add(kf_id)

    def remove(self, kf_id: int) -> None:
        bow = self.vectors.pop(kf_id, None)
        if bow is None:
            return
        for word in bow.words.tolist():
            holders = self._postings.get(word)
            if holders is not None:
                holders.discard(kf_id)
                if not holders:
                    del self._postings[word]

    def relocalisation_candidates(self, bow: BowVector, keyframes: Mapping[int, _Covisible], count: int) -> list[int]:
        """Keyframes where a lost frame may be, best group first (at most ``count``)."""
        return self._ranked(bow, keyframes, set(), 0.0)[:count]

    def loop_candidates(self, kf_id: int, keyframes: Mapping[int, _Covisible], connected: set[int], min_score: float) -> list[int]:
        """Keyframes not ``connected`` to ``kf_id`` that look like it at least as much as
        ``min_score`` (the least score of its own covisible neighbours), best group first."""
        return self._ranked(self.vectors[kf_id], keyframes, connected | {kf_id}, min_score)

    def score(self, a: int, b: int) -> float:
        return bow_score(self.vectors[a], self.vectors[b])

    def _ranked(self, bow: BowVector, keyframes: Mapping[int, _Covisible], excluded: set[int], min_score: float) -> list[int]:
        shared = Counter(chain.from_iterable(self._postings.get(word, ()) for word in bow.words.tolist()))
        for kf_id in excluded:
            shared.pop(kf_id, None)
        if not shared:
            return []
        min_common = MIN_COMMON_WORDS_SHARE * max(shared.values())
        scores = {k: bow_score(bow, self.vectors[k]) for k, n in shared.items() if n > min_common and k in keyframes}
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
