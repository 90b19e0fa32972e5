"""Place recognition over keyframes: ORB-SLAM's ranking rules on hand-made word vectors."""

from collections import Counter

import numpy as np

from evp.slam.keyframe_database import KeyframeDatabase
from evp.vision.vocabulary import BowVector


class _Keyframe:
    def __init__(self, neighbours: list[int]):
        self.covisible = Counter({k: 100 - i for i, k in enumerate(neighbours)})

    def best_covisible(self, count: int, min_weight: int = 1) -> list[int]:
        return [k for k, w in self.covisible.most_common(count) if w >= min_weight]


def _vector(words) -> BowVector:
    words = np.array(sorted(words), np.int32)
    return BowVector(words, np.full(len(words), 1.0 / len(words)))


def _place(start: int) -> set[int]:
    """Forty words of one place; places ``start`` apart by 20 share half their words."""
    return set(range(start, start + 40))


def _database(places: dict[int, set[int]], neighbours: dict[int, list[int]]):
    database = KeyframeDatabase()
    for kf_id, words in places.items():
        database.add(kf_id, _vector(words))
    return database, {kf_id: _Keyframe(neighbours.get(kf_id, [])) for kf_id in places}


def test_the_keyframe_of_the_place_comes_first():
    places = {k: _place(1000 * k) for k in range(6)}
    database, keyframes = _database(places, {})
    for kf_id, words in places.items():
        assert database.relocalisation_candidates(_vector(words), keyframes, 3) == [kf_id]
    assert database.relocalisation_candidates(_vector({999_999}), keyframes, 3) == []


def test_a_place_seen_by_several_keyframes_outranks_a_single_look_alike():
    # keyframes 1-3 see the query's place from nearby (covisible with each other: 37, 36 and 35
    # words shared); keyframe 9 alone shares 38, the best single score, but nobody backs it
    query = _place(0)
    places = {1: _place(3), 2: _place(4), 3: _place(5), 9: set(range(38)) | {5000, 5001}}
    database, keyframes = _database(places, {1: [2, 3], 2: [1, 3], 3: [1, 2]})
    assert database.relocalisation_candidates(_vector(query), {9: keyframes[9]}, 1) == [9]
    # the group's sum (0.925 + 0.9 + 0.875) is answered by its best keyframe; the lone 0.95 is
    # under 75 % of it and dropped
    assert database.relocalisation_candidates(_vector(query), keyframes, 5) == [1]


def test_keyframes_sharing_few_of_the_words_are_not_even_scored():
    # ORB-SLAM keeps keyframes with more than 80 % of the best count of shared words
    query = _place(0)
    database, keyframes = _database({1: _place(0), 2: _place(30)}, {})  # 40 shared against 10
    assert database.relocalisation_candidates(_vector(query), keyframes, 5) == [1]


def test_loop_candidates_leave_out_connected_keyframes_and_those_under_the_bar():
    places = {0: _place(0), 1: _place(2), 5: _place(4), 6: _place(20)}
    database, keyframes = _database(places, {})
    # keyframe 5 is connected (covisible) to 6; 0 and 1 are not, 1 looks most like it
    assert database.loop_candidates(5, keyframes, connected={6}, min_score=0.0) == [1, 0]
    # nothing scores 0.99 against keyframe 5
    assert database.loop_candidates(5, keyframes, connected={6}, min_score=0.99) == []


def test_removed_keyframes_are_forgotten():
    places = {1: _place(0), 2: _place(0)}
    database, keyframes = _database(places, {})
    database.remove(1)
    database.remove(1)  # twice: no error
    assert len(database) == 1
    assert database.relocalisation_candidates(_vector(_place(0)), keyframes, 5) == [2]
    database.remove(2)
    assert database.relocalisation_candidates(_vector(_place(0)), keyframes, 5) == []
