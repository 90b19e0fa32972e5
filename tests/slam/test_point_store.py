"""Map points keep their geometry in the map's PointStore: growth must not lose or mix rows."""

import numpy as np

from evp.slam.map import Map
from evp.vision.vocabulary import BowVector


def test_points_keep_their_values_when_the_store_grows():
    slam_map = Map()
    rng = np.random.default_rng(0)
    positions = rng.normal(size=(3000, 3))
    descriptors = rng.integers(0, 256, (3000, 32), dtype=np.uint8)
    points = [slam_map.add_point(p, d, 0) for p, d in zip(positions, descriptors, strict=True)]
    points[5].position *= 2.0  # in place, through the view
    points[7].normal = [0.0, 0.0, 1.0]
    points[7].max_distance = 4.0
    expected = positions.copy()
    expected[5] *= 2.0
    ids, stored = slam_map.point_array()
    assert np.array_equal(ids, np.arange(3000)) and np.array_equal(stored, expected)
    assert np.array_equal(slam_map.store.descriptor[:3000], descriptors)
    assert np.array_equal(points[7].normal, [0, 0, 1]) and points[7].max_distance == 4.0 and points[8].max_distance == np.inf


def _observed_map(rng: np.random.Generator) -> tuple[Map, np.ndarray]:
    """40 keyframes around the origin; 300 points each seen by 1 to 12 of them."""
    from evp.vision.orb import Features

    slam_map = Map()
    octave_count = 8
    for k in range(40):
        n = 300
        features = Features(
            np.zeros((n, 2)),
            np.zeros((n, 2)),
            np.zeros((n, 2)),
            rng.integers(0, octave_count, n),
            np.zeros(n),
            rng.integers(0, 256, (n, 32), dtype=np.uint8),
        )
        T_cw = np.eye(4)
        T_cw[:3, 3] = rng.normal(size=3) * 2.0
        slam_map.add_keyframe(float(k), T_cw, features, BowVector(np.zeros(0, np.int32), np.zeros(0)))
    for j in range(300):
        point = slam_map.add_point(rng.normal(size=3) * 5.0, np.zeros(32, np.uint8), int(rng.integers(0, 40)))
        for k in rng.choice(40, int(rng.integers(1, 13)), replace=False):
            slam_map.add_observation(point, slam_map.keyframes[int(k)], j)
    return slam_map, 1.2 ** np.arange(octave_count)


def test_refreshed_points_match_their_definitions_computed_one_by_one():
    slam_map, scale_factors = _observed_map(np.random.default_rng(1))
    slam_map.refresh_points(list(slam_map.points), scale_factors)
    for point in slam_map.points.values():
        observers = [(slam_map.keyframes[k], i) for k, i in point.observations.items()]
        rays = np.array([point.position - kf.centre for kf, _ in observers])
        normal = (rays / np.linalg.norm(rays, axis=1)[:, None]).sum(axis=0)
        assert np.allclose(point.normal, normal / np.linalg.norm(normal))
        reference, index = next(((kf, i) for kf, i in observers if kf.id == point.first_kf), observers[0])
        distance = np.linalg.norm(point.position - reference.centre) * scale_factors[reference.features.octave[index]]
        assert np.isclose(point.max_distance, distance) and np.isclose(point.min_distance, distance / scale_factors[-1])
        descriptors = np.array([kf.features.descriptors[i] for kf, i in observers])
        bits = np.unpackbits(descriptors, axis=1)
        median = np.median((bits[:, None, :] != bits[None, :, :]).sum(axis=2), axis=1)
        expected = descriptors[int(np.argmin(median))] if len(descriptors) > 2 else descriptors[0]
        assert np.array_equal(point.descriptor, expected)
