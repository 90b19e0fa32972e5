"""The EKF-SLAM's image front end on exact synthetic corners: the per-pixel rays are the lens
model's, and the vectorised active search keeps its rules (gate, nearest descriptor, a corner
claimed twice goes to the closer feature, ties to the lowest index)."""

from __future__ import annotations

import numpy as np

from evp.ekf_slam.filter import chi2_quantile
from evp.ekf_slam.tracking import Corners, PixelRays, hamming, search
from evp.types import CameraModel

CAMERA = CameraModel(48, 32, 40.0, 42.0, 23.5, 15.5, k1=0.05, k2=-0.1, p1=0.002, p2=-0.001)


def test_pixel_rays_are_the_lens_models_inversion():
    rays = PixelRays(CAMERA)
    whole = np.array([[0.0, 0.0], [47.0, 31.0], [12.0, 20.0]])
    np.testing.assert_array_equal(rays.normalised(whole), CAMERA.undistort_points(whole))
    off_grid = np.array([[12.5, 20.25], [-1.0, 3.0]])  # between pixels, outside the image
    np.testing.assert_array_equal(rays.normalised(off_grid), CAMERA.undistort_points(off_grid))
    assert rays.normalised(np.zeros((0, 2))).shape == (0, 2)


class _Descriptors:
    """A describer with known descriptors; ``missing`` corners cannot be described."""

    def __init__(self, descriptors: np.ndarray, missing: set[int]):
        self.descriptors, self.missing = descriptors, missing

    def describe(self, indices):
        return {int(i): self.descriptors[i] for i in indices if int(i) not in self.missing}


def _one_by_one(predicted, covariance, own, normalised, descriptors, missing, gate, max_hamming):
    """The search's rules written out feature by feature (the oracle)."""
    best: dict[int, tuple[int, int]] = {}
    for row in range(len(predicted)):
        offsets = normalised - predicted[row]
        inside = np.einsum("na,ab,nb->n", offsets, np.linalg.inv(covariance[row]), offsets) <= gate
        indices = [i for i in np.flatnonzero(inside) if i not in missing]
        if not indices:
            continue
        distance = np.minimum(hamming(descriptors[indices], own[row][0]), hamming(descriptors[indices], own[row][1]))
        j = int(np.argmin(distance))
        if distance[j] <= max_hamming and (indices[j] not in best or distance[j] < best[indices[j]][0]):
            best[indices[j]] = (int(distance[j]), row)
    return sorted((row, corner) for corner, (_, row) in best.items())


def test_vectorised_search_keeps_the_rules():
    rng = np.random.default_rng(3)
    matched = 0
    for trial in range(20):
        corners, features = 60, 12
        normalised = rng.uniform(-0.5, 0.5, (corners, 2))
        descriptors = rng.integers(0, 4, (corners, 32), dtype=np.uint8)  # few bits: many ties
        predicted = normalised[rng.integers(0, corners, features)] + rng.normal(0, 0.02, (features, 2))
        A = rng.normal(0, 0.05, (features, 2, 2))
        covariance = A @ A.transpose(0, 2, 1) + np.eye(2) * 1e-3
        own = [(descriptors[rng.integers(corners)], rng.integers(0, 4, 32, dtype=np.uint8)) for _ in range(features)]
        missing = set(rng.integers(0, corners, 5).tolist())
        found = search(predicted, covariance, own, Corners(normalised * 40, normalised, ()), _Descriptors(descriptors, missing), 0.99, 30)
        assert found == _one_by_one(predicted, covariance, own, normalised, descriptors, missing, chi2_quantile(0.99, 2), 30), trial
        matched += len(found)
    assert matched > 50  # the trials do match (ties and shared corners included)
