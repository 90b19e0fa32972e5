"""Map points keep their geometry in the map's PointStore: growth must not lose or mix rows."""

import numpy as np

from evp.slam.map import Map


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
