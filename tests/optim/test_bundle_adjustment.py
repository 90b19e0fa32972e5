"""Bundle adjustment on exact synthetic data."""

import numpy as np
from scipy.spatial.transform import Rotation

from evp.geometry.transforms import se3
from evp.optim import bundle_adjustment
from evp.optim.bundle_adjustment import BundleProblem, bundle_adjust

K = np.array([[450.0, 0, 320], [0, 450.0, 190], [0, 0, 1]])


def pose(rotvec, t):
    return se3(Rotation.from_rotvec(rotvec).as_matrix(), np.asarray(t, float))


def project(T, points):
    pc = points @ T[:3, :3].T + T[:3, 3]
    return (pc[:, :2] / pc[:, 2:3]) @ K[:2, :2].T + K[:2, 2]


def _six_views(rng: np.random.Generator):
    """300 points seen exactly by 6 poses moving sideways: points, poses, pose and point index of
    each observation, observed pixels."""
    points = rng.uniform([-2, -2, 4], [2, 2, 8], (300, 3))
    truth = np.array([pose([0.02 * k, -0.01 * k, 0.0], [-0.15 * k, 0.03 * k, 0.0]) for k in range(6)])
    pose_index = np.repeat(np.arange(6), len(points))
    point_index = np.tile(np.arange(len(points)), 6)
    return points, truth, pose_index, point_index, np.vstack([project(T, points) for T in truth])


def _perturbed_six_views(seed: int) -> tuple[BundleProblem, np.ndarray, np.ndarray]:
    """The six views with the four free poses and every point perturbed: the problem, the true
    poses and points."""
    rng = np.random.default_rng(seed)
    points, truth, pose_index, point_index, observed = _six_views(rng)
    perturbed = truth.copy()
    for T in perturbed[2:]:
        T[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.005, 3)).as_matrix() @ T[:3, :3]
        T[:3, 3] += rng.normal(0, 0.01, 3)
    fixed = np.array([True, True, False, False, False, False])  # two fixed poses fix the monocular gauge
    problem = BundleProblem(perturbed, points + rng.normal(0, 0.01, points.shape), pose_index, point_index, observed, np.ones(len(observed)), fixed, K)
    return problem, truth, points


def test_bundle_adjustment_recovers_perturbed_poses_and_points():
    problem, truth, points = _perturbed_six_views(1)
    poses, refined, chi2 = bundle_adjust(problem, evaluations=20)
    assert np.abs(poses - truth).max() < 1e-6
    assert np.abs(refined - points).max() < 1e-5
    assert chi2.max() < 1e-6



def test_the_sparse_solve_of_a_whole_map_gives_the_dense_solution(monkeypatch):
    """Above DENSE_POSE_LIMIT free poses the reduced system goes to SuperLU in symmetric mode:
    the same steps as the dense Cholesky, so the same result."""
    problem, _, _ = _perturbed_six_views(3)
    dense = bundle_adjust(problem, evaluations=3)
    monkeypatch.setattr(bundle_adjustment, "DENSE_POSE_LIMIT", 0)
    sparse = bundle_adjust(problem, evaluations=3)
    for a, b in zip(dense, sparse, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)

def test_bundle_adjustment_flags_moderate_outliers_and_ends_exact():
    """Mismatches of 7 pixels pass the first round's gross-error gate (10x the chi-square bound);
    the outlier rounds must still flag every one and leave an exact solution on the rest."""
    rng = np.random.default_rng(2)
    points, truth, pose_index, point_index, observed = _six_views(rng)
    bad = rng.choice(np.flatnonzero(pose_index >= 2), 60, replace=False)
    directions = rng.normal(size=(60, 2))
    observed[bad] += 7.0 * directions / np.linalg.norm(directions, axis=1)[:, None]  # chi2 49: inside 10 x 5.991
    perturbed = truth.copy()
    for T in perturbed[2:]:
        T[:3, 3] += rng.normal(0, 0.005, 3)
    fixed = np.array([True, True, False, False, False, False])
    problem = BundleProblem(perturbed, points, pose_index, point_index, observed, np.ones(len(observed)), fixed, K)
    poses, refined, chi2 = bundle_adjust(problem, evaluations=20)
    assert np.abs(poses - truth).max() < 1e-6
    assert np.all(chi2[bad] > 5.991)
    good = np.setdiff1d(np.arange(len(observed)), bad)
    assert np.all(chi2[good] < 5.991)


class _StopAfter:
    """A stop flag that is raised after ``checks`` looks (tracking asking for the mapper mid-solve)."""

    def __init__(self, checks: int):
        self.checks = checks

    def is_set(self) -> bool:
        self.checks -= 1
        return self.checks < 0


def shifted_six_views(seed: int) -> tuple[BundleProblem, np.ndarray]:
    """The six views as a bundle problem whose four free poses are shifted by ~1 cm, and the
    true poses."""
    rng = np.random.default_rng(seed)
    points, truth, pose_index, point_index, observed = _six_views(rng)
    perturbed = truth.copy()
    for T in perturbed[2:]:
        T[:3, 3] += rng.normal(0, 0.01, 3)
    fixed = np.array([True, True, False, False, False, False])
    return BundleProblem(perturbed, points, pose_index, point_index, observed, np.ones(len(observed)), fixed, K), truth


def test_a_stopped_bundle_adjustment_returns_what_it_reached():
    problem, truth = shifted_six_views(3)
    perturbed = problem.poses
    start_error = np.abs(perturbed - truth).max()
    poses, _, _ = bundle_adjust(problem, evaluations=20, stop=_StopAfter(0))
    assert np.allclose(poses, perturbed, rtol=0, atol=1e-12)  # stopped before the first iteration: untouched
    poses, _, _ = bundle_adjust(problem, evaluations=20, stop=_StopAfter(1))
    one_step_error = np.abs(poses - truth).max()
    assert one_step_error < 0.5 * start_error  # one iteration kept
    poses, _, _ = bundle_adjust(problem, evaluations=20)
    assert np.abs(poses - truth).max() < min(1e-6, one_step_error)
