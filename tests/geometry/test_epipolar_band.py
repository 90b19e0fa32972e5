"""Local mapping's search for new point pairs: only pairs near each other's epipolar line have
their descriptors compared, so the band must keep every true correspondence and nothing the
point-to-line distance rule would reject, whatever the motion puts the epipole."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.geometry.epipolar_band import epipolar_pairs, essential
from evp.geometry.transforms import se3

FX = 450.0


def _camera(rotvec, t):
    return se3(Rotation.from_rotvec(rotvec).as_matrix(), np.asarray(t, float))


def _normalised(T, X):
    pc = X @ T[:3, :3].T + T[:3, 3]
    return pc[:, :2] / pc[:, 2:3]


MOTIONS = {
    "sideways and a little forward": ([0.02, -0.05, 0.01], [-0.3, 0.05, 0.02]),
    "forward (epipole inside the image)": ([0.01, 0.02, 0.0], [0.02, -0.01, -1.2]),
    "exactly sideways (epipole at infinity)": ([0.0, 0.0, 0.0], [-0.4, 0.0, 0.0]),
    "backward with a turn": ([0.0, 0.15, 0.05], [0.05, 0.02, 0.8]),
}


@pytest.mark.parametrize("motion", MOTIONS, ids=list(MOTIONS))
def test_band_keeps_true_pairs_and_equals_the_distance_rule(motion):
    rng = np.random.default_rng(0)
    Ta, Tb = _camera([0, 0, 0], [0, 0, 0]), _camera(*MOTIONS[motion])
    points = rng.uniform([-3, -2, 4], [3, 2, 9], (400, 3))
    xa = _normalised(Ta, points)
    xb = _normalised(Tb, points) + rng.normal(0, 0.5 / FX, (400, 2))  # half-pixel noise
    xb = np.vstack([xb, rng.uniform(-0.7, 0.7, (400, 2))])  # as many keypoints with no partner
    tolerance = rng.choice([2.0, 2.4, 2.9, 4.1, 7.2], len(xb)) / FX  # pyramid levels' tolerances
    rows, cols = epipolar_pairs(Ta, Tb, xa, xb, tolerance)
    pairs = set(zip(rows.tolist(), cols.tolist(), strict=True))
    assert len(pairs) == len(rows) and np.all(np.diff(rows) >= 0)
    assert all((k, k) in pairs for k in range(400))
    # the same pairs as the point-to-line distance computed in full
    E = essential(Ta, Tb)
    lines = np.c_[xa, np.ones(len(xa))] @ E.T
    distance = np.abs(lines @ np.c_[xb, np.ones(len(xb))].T) / np.hypot(lines[:, 0], lines[:, 1])[:, None]
    expected = distance <= tolerance[None, :]
    near_edge = np.abs(distance - tolerance[None, :]) < 1e-6  # float32 may decide these either way
    got = np.zeros_like(expected)
    got[rows, cols] = True
    assert np.array_equal(got[~near_edge], expected[~near_edge])
    assert got.mean() < 0.05  # a band, not the whole table


def test_empty_inputs_give_no_pairs():
    Ta, Tb = _camera([0, 0, 0], [0, 0, 0]), _camera([0, 0, 0], [0.1, 0, 0.5])
    for xa, xb in ((np.zeros((0, 2)), np.zeros((5, 2))), (np.zeros((5, 2)), np.zeros((0, 2)))):
        rows, cols = epipolar_pairs(Ta, Tb, xa, xb, np.full(len(xb), 0.01))
        assert len(rows) == len(cols) == 0
