"""Bundle adjustment of keyframe poses and map points: Levenberg-Marquardt on the Schur complement.

A window has a few dozen poses and thousands of points, and each point is seen by few poses, so
the normal equations are solved as g2o and Ceres do: eliminate the points (their 3x3 blocks
invert independently), solve the small dense pose system (Cholesky), back-substitute the
points. The blocks are built with batched NumPy, the elimination with SciPy sparse matrices.
Measured before choosing (bench/README.md): SciPy's ``least_squares`` (trust region, LSMR on the
full sparse Jacobian) took ~400 ms per local window; GTSAM about 1 s with the GIL held.

Robustness follows ORB-SLAM: solve with a Huber kernel, drop observations beyond the chi-square
bound, solve again without the kernel (the first round already ignores gross outliers). Poses
take left increments (rotation vector, translation) re-linearised at every iteration.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
import scipy.linalg
from scipy.sparse import bsr_matrix, csr_matrix

from evp.optim.levenberg_marquardt import StopFlag, levenberg_marquardt
from evp.optim.reprojection import CHI2_2DOF, HUBER_DELTA, in_detected_pixels, reprojection_chi2
from evp.optim.rotation import nearest_rotation
from evp.optim.sparse_solve import solve_positive_definite

MIN_REDUCTION = 1e-6  # relative cost reduction below which a solve has converged
DENSE_POSE_LIMIT = 300  # free poses above which the reduced system is solved as a sparse matrix (a whole map: its keyframes share points with few others; dense, 2000 keyframes would take 1.2 GB)


@dataclass
class BundleProblem:
    """Observations (pose index, point index, undistorted pixel, octave sigma, and the lens's
    Jacobian at the observation: ``Features.lens_jacobian``, None for a lens without distortion)
    of points by poses; poses flagged in ``fixed`` are held constant (the gauge and the window's
    border). Errors are weighed in the detected image, where the detector's noise is isotropic."""

    poses: np.ndarray  # (P, 4, 4) T_cw
    points: np.ndarray  # (M, 3)
    pose_index: np.ndarray  # (N,)
    point_index: np.ndarray  # (N,)
    observed: np.ndarray  # (N, 2)
    sigma: np.ndarray  # (N,) pixel standard deviation (scale factor of the octave)
    fixed: np.ndarray  # (P,) bool
    K: np.ndarray
    lens_jacobian: np.ndarray | None = None  # (N, 2, 2) d detected pixel / d undistorted pixel


def observation_chi2(problem: BundleProblem, poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    R = poses[problem.pose_index, :3, :3]
    pc = np.einsum("nij,nj->ni", R, points[problem.point_index]) + poses[problem.pose_index, :3, 3]
    return reprojection_chi2(pc, problem.observed, problem.K, 1.0 / problem.sigma**2, problem.lens_jacobian)


def block_sums(index: np.ndarray, blocks: np.ndarray, count: int) -> np.ndarray:
    """Sum of ``blocks[n]`` grouped by ``index[n]`` into ``count`` blocks of the same shape (one
    sparse product: about twice as fast as a bincount per entry)."""
    grouping = csr_matrix((np.ones(len(index)), (index, np.arange(len(index)))), shape=(count, len(index)))
    flat = blocks.reshape(len(blocks), int(np.prod(blocks.shape[1:])))  # not -1: no blocks at all when every pose is fixed
    return np.asarray(grouping @ flat).reshape((count, *blocks.shape[1:]))


def _outer(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise outer products (n, a) x (n, b) -> (n, a, b)."""
    return u[:, :, None] * v[:, None, :]


def _through_lens(lens_jacobian: np.ndarray | None, row_u: np.ndarray, row_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobian rows (n, k) of the u and v residuals mapped into the detected image, as the
    residuals are (:func:`~evp.optim.reprojection.in_detected_pixels`); as they are without a lens."""
    if lens_jacobian is None:
        return row_u, row_v
    j = lens_jacobian
    return j[:, 0, 0, None] * row_u + j[:, 0, 1, None] * row_v, j[:, 1, 0, None] * row_u + j[:, 1, 1, None] * row_v


class _Linearisation:
    """Weighted residuals and the normal-equation blocks of the active observations at one estimate."""

    def __init__(self, problem: BundleProblem, active: np.ndarray, slot: np.ndarray, R: np.ndarray, t: np.ndarray, points: np.ndarray, robust: bool):
        K = problem.K
        pose_index, point_index = problem.pose_index[active], problem.point_index[active]
        inv_sigma = 1.0 / problem.sigma[active]
        Ri = R[pose_index]
        pc = np.einsum("nij,nj->ni", Ri, points[point_index]) + t[pose_index]
        z = np.where(np.abs(pc[:, 2]) < 1e-9, 1e-9, pc[:, 2])
        iz = 1.0 / z
        u = K[0, 0] * pc[:, 0] * iz + K[0, 2]
        v = K[1, 1] * pc[:, 1] * iz + K[1, 2]
        lens = None if problem.lens_jacobian is None else problem.lens_jacobian[active]
        r = in_detected_pixels(np.stack([u - problem.observed[active, 0], v - problem.observed[active, 1]], axis=1) * inv_sigma[:, None], lens)
        # Huber kernel as iteratively reweighted least squares: the blocks use sqrt(weight)-scaled
        # residuals and Jacobians, the cost is the robust one
        e2 = np.sum(r * r, axis=1)
        if robust:
            e = np.sqrt(e2)
            weight = np.where(e <= HUBER_DELTA, 1.0, HUBER_DELTA / np.maximum(e, 1e-12))
            self.cost = float(np.sum(np.where(e <= HUBER_DELTA, e2, 2.0 * HUBER_DELTA * e - HUBER_DELTA**2)))
        else:
            weight = np.ones(len(e2))
            self.cost = float(np.sum(e2))
        self.r = r * np.sqrt(weight)[:, None]
        # Jacobian rows written out (the projection's 2x3 derivative has two zeros): per observation
        # d r / d X = D R and d r / d (phi, t) = D [-[pc]x  I], with D = [[a, 0, b], [0, c, d]]
        w = inv_sigma * np.sqrt(weight)
        x, y = pc[:, 0], pc[:, 1]
        a, c = K[0, 0] * iz * w, K[1, 1] * iz * w
        b, d = -a * x * iz, -c * y * iz
        P0 = a[:, None] * Ri[:, 0, :] + b[:, None] * Ri[:, 2, :]
        P1 = c[:, None] * Ri[:, 1, :] + d[:, None] * Ri[:, 2, :]
        P0, P1 = _through_lens(lens, P0, P1)
        n_points, n_free = len(points), int(slot.max()) + 1 if len(slot) else 0
        self.V = block_sums(point_index, _outer(P0, P0) + _outer(P1, P1), n_points)
        self.g_point = block_sums(point_index, P0 * self.r[:, :1] + P1 * self.r[:, 1:], n_points)
        free = slot[pose_index] >= 0
        s, j = slot[pose_index][free], point_index[free]
        a, b, c, d, x, y, z = (v[free] for v in (a, b, c, d, x, y, pc[:, 2]))
        zero = np.zeros(len(a))
        Q0 = np.stack([b * y, a * z - b * x, -a * y, a, zero, b], axis=1)
        Q1 = np.stack([d * y - c * z, -d * x, c * x, zero, c, d], axis=1)
        Q0, Q1 = _through_lens(None if lens is None else lens[free], Q0, Q1)
        r_free = self.r[free]
        self.U = block_sums(s, _outer(Q0, Q0) + _outer(Q1, Q1), n_free)
        self.g_pose = block_sums(s, Q0 * r_free[:, :1] + Q1 * r_free[:, 1:], n_free)
        W = _outer(Q0, P0[free]) + _outer(Q1, P1[free])  # (n, 6, 3) pose-point coupling
        order = np.argsort(s, kind="stable")
        indptr = np.searchsorted(s[order], np.arange(n_free + 1))
        self.W = bsr_matrix((W[order], j[order], indptr), shape=(6 * n_free, 3 * n_points))

    def step(self, damping: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Pose increments (P_free, 6) and point increments (M, 3) for one Levenberg-Marquardt
        damping, or None when the reduced system is not positive definite."""
        n_points = len(self.V)
        diag3 = np.einsum("nii->ni", self.V)
        V = self.V + (damping * diag3 + 1e-9)[:, :, None] * np.eye(3)
        V_inv = np.linalg.inv(V)
        V_inv_bsr = bsr_matrix((V_inv, np.arange(n_points), np.arange(n_points + 1)), shape=(3 * n_points, 3 * n_points))
        WV = self.W @ V_inv_bsr
        rhs = -(self.g_pose.ravel() - WV @ self.g_point.ravel())
        U = self.U.copy()
        diagonal = np.einsum("nii->ni", U)  # a writable view
        diagonal *= 1 + damping
        diagonal += 1e-9
        if len(U) > DENSE_POSE_LIMIT:
            d_pose = solve_positive_definite(bsr_matrix((U, np.arange(len(U)), np.arange(len(U) + 1))) - WV @ self.W.T, rhs)
            if d_pose is None:
                return None
        else:
            S = (scipy.linalg.block_diag(*U) if len(U) else np.zeros((0, 0))) - (WV @ self.W.T).toarray()
            try:
                d_pose = scipy.linalg.cho_solve(scipy.linalg.cho_factor(S), rhs) if len(rhs) else rhs
            except np.linalg.LinAlgError:
                return None
        back = -self.g_point.ravel() - self.W.T @ d_pose
        d_point = np.einsum("nij,nj->ni", V_inv, back.reshape(-1, 3))
        return d_pose.reshape(-1, 6), d_point


def _apply(R: np.ndarray, t: np.ndarray, points: np.ndarray, free: np.ndarray, d_pose: np.ndarray, d_point: np.ndarray):
    R, t = R.copy(), t.copy()
    for i, k in enumerate(free):
        dR = cv2.Rodrigues(d_pose[i, :3].reshape(3, 1))[0]
        R[k] = dR @ R[k]
        t[k] = dR @ t[k] + d_pose[i, 3:]
    return R, t, points + d_point


def _solve(problem: BundleProblem, active: np.ndarray, iterations: int, robust: bool, stop: StopFlag | None) -> BundleProblem:
    free = np.flatnonzero(~problem.fixed)
    slot = np.full(len(problem.poses), -1)
    slot[free] = np.arange(len(free))

    def linearised(estimate: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], _Linearisation]:
        return estimate, _Linearisation(problem, active, slot, *estimate, robust)

    def step(current, damping: float):
        increments = current[1].step(damping)
        return None if increments is None else linearised(_apply(*current[0], free, *increments))

    start = linearised((problem.poses[:, :3, :3].copy(), problem.poses[:, :3, 3].copy(), problem.points.copy()))
    (R, t, points), _ = levenberg_marquardt(start, step, lambda current: current[1].cost, iterations, MIN_REDUCTION, stop)
    poses = np.repeat(np.eye(4)[None], len(R), axis=0)
    poses[:, :3, :3] = [nearest_rotation(r) for r in R]
    poses[:, :3, 3] = t
    return replace(problem, poses=poses, points=points)


def bundle_adjust(
    problem: BundleProblem, evaluations: int = 6, outlier_rounds: int = 2, first_gate_chi2: float = 10 * CHI2_2DOF, stop: StopFlag | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Optimised poses (P, 4, 4) ``T_cw``, points (M, 3), and per-observation chi-square errors.

    The first round uses the observations under ``first_gate_chi2`` at the start (gross
    outliers out; infinite when the start is too rough to tell); each round runs up to
    ``evaluations`` Levenberg-Marquardt iterations, then re-classifies all observations.
    ``stop`` (ORB-SLAM's abort flag, set by tracking when it needs the mapper) ends the
    iterations early: what was reached so far is returned."""
    chi2 = observation_chi2(problem, problem.poses, problem.points)
    active = chi2 < first_gate_chi2
    for round_index in range(outlier_rounds):
        if active.sum() < 6:
            break
        problem = _solve(problem, active, evaluations, round_index == 0, stop)
        chi2 = observation_chi2(problem, problem.poses, problem.points)
        active = chi2 < CHI2_2DOF
    return problem.poses, problem.points, chi2
