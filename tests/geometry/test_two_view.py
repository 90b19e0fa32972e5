"""Initialisation recovers the relative pose on exact synthetic scenes, and refuses ambiguity."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.geometry.two_view import complete_two_view, two_view_candidate


def initial_two_view(x1, x2, focal, min_parallax_deg=1.0, min_triangulated=50):
    """The start SLAM makes: the unambiguous motion, then its map if its parallax is enough."""
    candidate = two_view_candidate(x1, x2, focal, min_triangulated)
    return None if candidate is None else complete_two_view(candidate, x1, x2, focal, min_parallax_deg, min_triangulated)


def _views(points_world: np.ndarray, R21: np.ndarray, t21: np.ndarray, noise_px: float, focal: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    x1 = points_world[:, :2] / points_world[:, 2:3]
    in2 = points_world @ R21.T + t21
    x2 = in2[:, :2] / in2[:, 2:3]
    return x1 + rng.normal(0, noise_px / focal, x1.shape), x2 + rng.normal(0, noise_px / focal, x2.shape)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


@pytest.mark.parametrize("scene", ["planar", "non-planar"])
def test_initialisation_recovers_relative_pose(scene):
    rng = np.random.default_rng(1)
    n = 400
    if scene == "planar":  # a tilted wall 4 m away
        uv = rng.uniform(-2, 2, (n, 2))
        points = np.c_[uv, 4.0 + 0.3 * uv[:, 0]]
    else:
        points = rng.uniform([-2, -1.5, 3], [2, 1.5, 7], (n, 3))
    R21 = Rotation.from_euler("xyz", [2.0, -4.0, 1.0], degrees=True).as_matrix()
    t21 = np.array([-1.0, 0.2, 0.0])
    x1, x2 = _views(points, R21, t21, 0.1, 450.0)
    result = initial_two_view(x1, x2, 450.0)
    assert result is not None
    assert result.model == ("homography" if scene == "planar" else "fundamental")
    rotation_error = np.degrees(Rotation.from_matrix(result.T21[:3, :3] @ R21.T).magnitude())
    assert rotation_error < 0.1
    assert _angle_deg(result.T21[:3, 3], t21) < 1.0
    assert result.good.sum() > 0.8 * n


def test_twofold_planar_ambiguity_is_refused():
    """A short baseline over a plane: two motions explain the homography with every point in
    front of both cameras. ORB-SLAM's rule refuses it and waits for a later frame."""
    rng = np.random.default_rng(1)
    uv = rng.uniform(-2, 2, (400, 2))
    points = np.c_[uv, 4.0 + 0.3 * uv[:, 0]]
    R21 = Rotation.from_euler("xyz", [2.0, -4.0, 1.0], degrees=True).as_matrix()
    x1, x2 = _views(points, R21, np.array([-0.4, 0.05, 0.1]), 0.1, 450.0)
    assert initial_two_view(x1, x2, 450.0) is None


def test_pure_rotation_is_refused():
    """No baseline, no depth: a map started here would be wrong, so initialisation waits."""
    rng = np.random.default_rng(2)
    points = rng.uniform([-2, -1.5, 3], [2, 1.5, 7], (300, 3))
    R21 = Rotation.from_euler("y", 3.0, degrees=True).as_matrix()
    x1, x2 = _views(points, R21, np.zeros(3), 0.3, 450.0)
    assert initial_two_view(x1, x2, 450.0) is None


def test_initial_map_keeps_distant_points_with_low_but_real_parallax():
    """A short baseline over near and distant points (a slider, or a drone over a valley): the far
    points, 0.4-1.1 degrees of parallax, join the initial map (ORB-SLAM's limit, 0.36 degrees), so
    tracking has them at the start; points beyond that stay out (they are directions, not positions).
    Exact views: with noise the RANSAC model's rotation error inflates distant points' parallax (as
    in ORB-SLAM, which classifies on the same model)."""
    rng = np.random.default_rng(3)
    near = rng.uniform([-2, -1.5, 4], [2, 1.5, 6], (200, 3))
    far = rng.uniform([-10, -7, 28], [10, 7, 32], (150, 3))  # ~0.55 deg with 0.3 m of baseline
    very_far = rng.uniform([-40, -30, 150], [40, 30, 160], (100, 3))  # ~0.11 deg
    points = np.vstack([near, far, very_far])
    R21 = Rotation.from_euler("xyz", [0.5, -1.0, 0.3], degrees=True).as_matrix()
    x1, x2 = _views(points, R21, np.array([-0.3, 0.02, 0.0]), 0.0, 450.0)
    result = initial_two_view(x1, x2, 450.0)
    assert result is not None and result.model == "fundamental"
    assert result.good[:200].mean() > 0.95
    assert result.good[200:350].mean() > 0.8
    assert result.good[350:].mean() < 0.05
