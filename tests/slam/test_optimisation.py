"""Pose-only optimisation on exact synthetic data."""

import numpy as np
from scipy.spatial.transform import Rotation

from evp.slam.pose_optimizer import optimise_pose, rotation_std_deg
from evp.types import CameraModel, LensModel
from tests.optim.test_bundle_adjustment import K, pose, project


def test_pose_optimisation_is_exact_and_flags_outliers():
    rng = np.random.default_rng(0)
    points = rng.uniform([-3, -2, 3], [3, 2, 8], (200, 3))
    truth = pose([0.1, -0.2, 0.05], [0.3, -0.1, 0.2])
    observed = project(truth, points)
    observed[:20] += rng.uniform(30, 60, (20, 2))  # gross mismatches
    start = pose([0.12, -0.18, 0.06], [0.35, -0.05, 0.1])
    T, inlier = optimise_pose(start, points, observed, np.ones(200), K)
    assert np.abs(T - truth).max() < 1e-6
    assert not inlier[:20].any() and inlier[20:].all()


def _floor_points(rng, rows: tuple[float, float], count: int = 80) -> np.ndarray:
    """Points of a plane at depth 1 seen over the full width and the given image rows."""
    uv = np.c_[rng.uniform(20, 620, count), rng.uniform(*rows, count)]
    return np.c_[(uv - K[:2, 2]) / K[0, 0], np.ones(count)]


def test_rotation_std_predicts_the_scatter_of_the_optimised_pose():
    """The standard deviation reported for each axis is the scatter of the pose that one pixel of
    noise gives (Monte Carlo, 300 draws), and a strip of coplanar points fixes the tilt worse
    than the same number across the image (what makes a loop seen over part of a view weak)."""
    rng = np.random.default_rng(3)
    strip, full = _floor_points(rng, (20, 140)), _floor_points(rng, (20, 360))
    truth = np.eye(4)
    predicted = rotation_std_deg(truth, strip, np.ones(len(strip)), K)
    exact = project(truth, strip)
    errors = []
    for _ in range(300):
        T, _ = optimise_pose(truth, strip, exact + rng.normal(0, 1.0, exact.shape), np.ones(len(strip)), K, rounds=1)
        errors.append(np.degrees(Rotation.from_matrix(T[:3, :3]).as_rotvec()))
    measured = np.std(errors, axis=0)
    assert np.allclose(measured, predicted, rtol=0.2), (measured, predicted)
    assert predicted[0] > 2 * rotation_std_deg(truth, full, np.ones(len(full)), K)[0]
    # coarser pyramid levels (larger sigmas, smaller information) widen it in proportion
    assert np.allclose(rotation_std_deg(truth, strip, np.full(len(strip), 0.25), K), 2 * predicted)


def test_pose_optimisation_does_not_solve_the_same_round_twice(monkeypatch):
    """A round whose inlier set and kernel equal those of a converged round would not move the
    pose: with no outliers only the first robust and the first plain round take steps."""
    import evp.slam.pose_optimizer as pose_optimizer

    steps = []
    step = pose_optimizer._gauss_newton_step
    monkeypatch.setattr(
        pose_optimizer, "_gauss_newton_step", lambda T, inliers, robust: steps.append(robust) or step(T, inliers, robust)
    )
    rng = np.random.default_rng(3)
    points = rng.uniform([-3, -2, 3], [3, 2, 8], (100, 3))
    truth = pose([0.1, -0.2, 0.05], [0.3, -0.1, 0.2])
    T, inlier = optimise_pose(pose([0.12, -0.18, 0.06], [0.35, -0.05, 0.1]), points, project(truth, points), np.ones(100), K)
    assert np.abs(T - truth).max() < 1e-6 and inlier.all()
    robust_steps, plain_steps = steps.count(True), steps.count(False)
    assert 2 <= robust_steps <= 10 and plain_steps == 1  # a plain solve from the optimum: one tiny step


def test_fisheye_features_are_weighed_by_their_noise_in_the_detected_image():
    """Points up to 65 degrees off the axis of a fisheye, with one pixel of noise in the detected
    image: in undistorted pixels the periphery is several times noisier radially. Weighed through
    the lens Jacobian, the predicted rotation scatter is the measured one (Monte Carlo) and
    smaller than what the same optimiser reaches with level weights alone."""
    rng = np.random.default_rng(5)
    fisheye = CameraModel(640, 380, K[0, 0], K[1, 1], K[0, 2], K[1, 2], lens=LensModel.EQUIDISTANT)
    theta, phi = np.radians(65) * np.sqrt(rng.uniform(0, 1, 120)), rng.uniform(0, 2 * np.pi, 120)
    points = np.c_[np.tan(theta) * np.cos(phi), np.tan(theta) * np.sin(phi), np.ones(120)] * rng.uniform(2, 6, (120, 1))
    lens = fisheye.pixel_jacobian(points[:, :2] / points[:, 2:])
    truth, ones, exact = np.eye(4), np.ones(120), project(np.eye(4), points)
    predicted = rotation_std_deg(truth, points, ones, K, lens)
    weighed, unweighed = [], []
    for _ in range(150):
        observed = exact + np.einsum("nij,nj->ni", np.linalg.inv(lens), rng.normal(0, 1.0, (120, 2)))  # detected noise, undistorted
        for errors, jacobian in ((weighed, lens), (unweighed, None)):
            T, _ = optimise_pose(truth, points, observed, ones, K, jacobian, rounds=1)
            errors.append(np.degrees(Rotation.from_matrix(T[:3, :3]).as_rotvec()))
    measured = np.std(weighed, axis=0)
    assert np.allclose(measured, predicted, rtol=0.25), (measured, predicted)
    assert np.all(measured < np.std(unweighed, axis=0))
