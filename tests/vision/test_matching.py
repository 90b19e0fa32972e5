"""Guided matching: the k-d tree candidate search must pick exactly the matches a full Hamming
table with the same window, scale and ratio rules would pick."""

import numpy as np
import pytest

from evp.vision.matching import NO_MATCH, best_unique, best_unique_pairs, hamming_matrix, hamming_pairs, match_in_window, pairs_within


def _dense_window_match(desc_a, xy_a, desc_b, xy_b, radius, max_distance, ratio, octave_a=None, octave_b=None, window=1):
    distances = hamming_matrix(desc_a, desc_b)
    radius = np.broadcast_to(np.asarray(radius, float), (len(xy_a),))
    d2 = ((xy_a[:, None, :] - xy_b[None, :, :]) ** 2).sum(axis=2)
    far = d2 > (radius * radius)[:, None]
    if octave_a is not None:
        far |= np.abs(octave_a[:, None] - octave_b[None, :]) > window
    distances[far] = NO_MATCH
    return best_unique(distances, max_distance, ratio)


def _scene(rng, n_a, n_b):
    """Descriptors of b are noisy copies of a's in shuffled order, so many near ties occur."""
    base = rng.integers(0, 256, (max(n_a, n_b), 32), dtype=np.uint8)
    desc_a = base[:n_a].copy()
    desc_b = base[rng.permutation(len(base))[:n_b]].copy()
    desc_b ^= ((rng.random(desc_b.shape) < 0.05) * rng.integers(0, 256, desc_b.shape)).astype(np.uint8)
    return desc_a, rng.random((n_a, 2)) * 100, desc_b, rng.random((n_b, 2)) * 100


@pytest.mark.parametrize("seed", range(40))
def test_window_matching_equals_the_dense_table(seed):
    rng = np.random.default_rng(seed)
    desc_a, xy_a, desc_b, xy_b = _scene(rng, int(rng.integers(0, 250)), int(rng.integers(0, 250)))
    radius = rng.random(len(xy_a)) * 20 if seed % 2 else 10.0
    octave_a, octave_b = rng.integers(0, 8, len(xy_a)), rng.integers(0, 8, len(xy_b))
    for octaves in [(), (octave_a, octave_b)]:
        expected = _dense_window_match(desc_a, xy_a, desc_b, xy_b, radius, 100, 0.9, *octaves)
        got = match_in_window(desc_a, xy_a, desc_b, xy_b, radius, 100, 0.9, *octaves)
        assert np.array_equal(got[0], expected[0]) and np.array_equal(got[1], expected[1])


@pytest.mark.parametrize("seed", range(10))
def test_sparse_best_unique_equals_the_dense_table_in_any_candidate_order(seed):
    """Local mapping's epipolar candidates come grouped by row in no set order within a row."""
    rng = np.random.default_rng(seed)
    desc_a, _, desc_b, _ = _scene(rng, 120, 150)
    rows, cols = np.nonzero(rng.random((120, 150)) < 0.1)
    table = np.full((120, 150), NO_MATCH, np.float32)
    table[rows, cols] = hamming_matrix(desc_a, desc_b)[rows, cols]
    expected = best_unique(table, 100, 0.9)
    for order in (np.arange(len(rows)), rng.permutation(len(rows)), np.lexsort((rng.random(len(rows)), rows))):
        got = best_unique_pairs(rows[order], cols[order], hamming_pairs(desc_a, desc_b, rows[order], cols[order]), 100, 0.9)
        assert np.array_equal(got[0], expected[0]) and np.array_equal(got[1], expected[1])


def test_points_behind_the_camera_never_match():
    rng = np.random.default_rng(1)
    desc_a, xy_a, desc_b, xy_b = _scene(rng, 50, 50)
    xy_a[::2] = np.nan
    rows, _ = match_in_window(desc_a, xy_a, desc_b, xy_b, 30.0, 256, 1.0)
    assert len(rows) > 0 and np.all(rows % 2 == 1)


def test_pairwise_hamming_equals_the_table():
    rng = np.random.default_rng(2)
    a, b = rng.integers(0, 256, (30, 32), dtype=np.uint8), rng.integers(0, 256, (30, 32), dtype=np.uint8)
    rows, cols = rng.integers(0, 30, 500), rng.integers(0, 30, 500)
    assert np.array_equal(hamming_pairs(a, b, rows, cols), hamming_matrix(a, b)[rows, cols])
    assert hamming_pairs(a, ~a, np.arange(30), np.arange(30)).tolist() == [256.0] * 30  # no overflow


@pytest.mark.parametrize("seed", range(4))
def test_grid_search_finds_exactly_the_pairs_within_each_radius(seed):
    rng = np.random.default_rng(seed)
    xy_a = rng.uniform(-50, 700, (400, 2))
    xy_b = np.vstack([rng.uniform(-50, 700, (600, 2)), xy_a[:50] + rng.normal(0, 3, (50, 2))])
    radius = rng.choice([0.0, 2.5, 15.0, 54.0, 300.0], len(xy_a))  # level-scaled windows, and extremes
    rows, cols = pairs_within(xy_a, radius, xy_b)
    distance = np.linalg.norm(xy_a[:, None] - xy_b[None], axis=2)
    expected = np.argwhere(distance <= radius[:, None])
    got = np.c_[rows, cols]
    assert np.all(np.diff(rows) >= 0)
    np.testing.assert_array_equal(got[np.lexsort((cols, rows))], expected)
