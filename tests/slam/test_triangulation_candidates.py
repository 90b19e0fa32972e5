"""Local mapping's search for new point pairs: only pairs near each other's epipolar line have
their descriptors compared, so the band must keep every true correspondence and little else."""

import numpy as np
from scipy.spatial.transform import Rotation

from evp.slam.local_mapping import _epipolar_candidates, _essential


def _camera(rotvec, t):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def test_band_keeps_true_pairs_and_equals_the_distance_rule():
    rng = np.random.default_rng(0)
    fx = 450.0
    Ta, Tb = _camera([0, 0, 0], [0, 0, 0]), _camera([0.02, -0.05, 0.01], [-0.3, 0.05, 0.02])
    points = rng.uniform([-3, -2, 4], [3, 2, 9], (400, 3))

    def normalised(T, X):
        pc = X @ T[:3, :3].T + T[:3, 3]
        return pc[:, :2] / pc[:, 2:3]

    xa = normalised(Ta, points)
    xb = normalised(Tb, points) + rng.normal(0, 0.5 / fx, (400, 2))  # half-pixel noise
    xb = np.vstack([xb, rng.uniform(-0.7, 0.7, (400, 2))])  # as many keypoints with no partner
    tolerance = np.full(len(xb), 2.0 / fx)  # 2 pixels
    E = _essential(Ta, Tb)
    rows, cols = _epipolar_candidates(E, xa, xb, tolerance)
    pairs = set(zip(rows.tolist(), cols.tolist(), strict=True))
    assert all((k, k) in pairs for k in range(400))
    # the same pairs as the point-to-line distance computed in full, in double precision
    lines = np.c_[xa, np.ones(len(xa))] @ E.T
    distance = np.abs(lines @ np.c_[xb, np.ones(len(xb))].T) / np.hypot(lines[:, 0], lines[:, 1])[:, None]
    expected = distance <= tolerance[None, :]
    near_edge = np.abs(distance - tolerance[None, :]) < 1e-6  # float32 may decide these either way
    got = np.zeros_like(expected)
    got[rows, cols] = True
    assert np.array_equal(got[~near_edge], expected[~near_edge])
    assert got.mean() < 0.05  # a band, not the whole table
