"""Place recognition over keyframes: ORB-SLAM's ranking rules on hand-made word vectors."""

from collections import Counter

import numpy as np

from evp.slam.keyframe_database import KeyframeDatabase
from evp.vision.vocabulary import BowVector, bow_score


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
    places = {0: _place(0), 1: _place(2), 5: _place(4), 6: _place(20), 7: _place(3)}
    database, keyframes = _database(places, {})
    # keyframe 5 is connected (covisible) to 6 and 7; 0 and 1 are not, 1 looks most like it
    assert database.loop_candidates(5, keyframes, connected={6, 7}, neighbours=[6]) == [1, 0]
    # the bar is the least alike neighbour's score: 7 shares 39 of 40 words, more than 1 or 0
    assert database.loop_candidates(5, keyframes, connected={6, 7}, neighbours=[6, 7]) == [1, 0]
    assert database.loop_candidates(5, keyframes, connected={6, 7}, neighbours=[7]) == []


def test_removed_keyframes_are_forgotten():
    places = {1: _place(0), 2: _place(0)}
    database, keyframes = _database(places, {})
    database.remove(1)
    database.remove(1)  # twice: no error
    assert len(database) == 1
    assert database.relocalisation_candidates(_vector(_place(0)), keyframes, 5) == [2]
    database.remove(2)
    assert database.relocalisation_candidates(_vector(_place(0)), keyframes, 5) == []


def test_scores_of_the_inverted_file_match_pairwise_scores_through_additions_and_removals():
    rng = np.random.default_rng(3)
    database = KeyframeDatabase()
    vectors = {}
    for kf_id in range(300):
        words = np.unique(rng.integers(0, 2000, rng.integers(1, 80)))
        weights = rng.random(len(words))
        vectors[kf_id] = BowVector(words.astype(np.int32), weights / weights.sum())
        database.add(kf_id, vectors[kf_id])
        if kf_id % 5 < 3:  # most culled: dead entries pass half the arrays, which are then rebuilt
            database.remove(int(rng.choice(list(database.vectors))))
    assert database._size < sum(map(len, vectors.values()))
    query = vectors[299]
    ids, common, scores = database._shared(query)
    expected = {k: bow_score(query, v) for k, v in database.vectors.items() if np.intersect1d(query.words, v.words).size}
    assert ids.tolist() == sorted(expected)
    np.testing.assert_allclose(scores, [expected[k] for k in ids.tolist()], rtol=1e-12)
    assert common.tolist() == [np.intersect1d(query.words, database.vectors[k].words).size for k in ids.tolist()]
