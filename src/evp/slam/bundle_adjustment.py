"""Bundle adjustment of keyframe poses and map points with SciPy's sparse least squares.

Measured before choosing (bench/README.md): GTSAM's Levenberg-Marquardt solves a 15-keyframe,
3000-point window in about 1 s and holds the GIL all that time, which would stall tracking in
the other thread; SciPy's trust-region solver with this analytic sparse Jacobian converges in
5-6 evaluations and lets the tracking thread run between its steps. SciPy's Huber loss converges
slowly from large residuals (it rescales like one IRLS step per evaluation), so robustness comes
from ORB-SLAM's scheme instead: solve, drop observations beyond the chi-square bound, solve again.

Poses are parametrised by a left increment (rotation vector, translation) on their starting value;
the Jacobian is exact through SO(3)'s left Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix

from evp.geometry.transforms import skew
from evp.geometry.two_view import CHI2_2DOF
from evp.slam.projection import reprojection_chi2


@dataclass
class BundleProblem:
    """Observations (pose index, point index, undistorted pixel, octave sigma) of points by
    poses; poses flagged in ``fixed`` are held constant (the gauge and the window's border)."""

    poses: np.ndarray  # (P, 4, 4) T_cw
    points: np.ndarray  # (M, 3)
    pose_index: np.ndarray  # (N,)
    point_index: np.ndarray  # (N,)
    observed: np.ndarray  # (N, 2)
    sigma: np.ndarray  # (N,) pixel standard deviation (scale factor of the octave)
    fixed: np.ndarray  # (P,) bool
    K: np.ndarray


def _left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobians of (N, 3) rotation vectors."""
    theta = np.linalg.norm(phi, axis=1)
    out = np.repeat(np.eye(3)[None], len(phi), axis=0)
    big = theta > 1e-8
    if big.any():
        t = theta[big]
        a = phi[big] / t[:, None]
        s, c = np.sin(t) / t, (1 - np.cos(t)) / t
        out[big] = s[:, None, None] * np.eye(3) + (1 - s)[:, None, None] * np.einsum("ni,nj->nij", a, a) + c[:, None, None] * skew(a)
    return out


class _Model:
    """Residuals (pixels / sigma) and their sparse Jacobian for the active observations."""

    def __init__(self, problem: BundleProblem, active: np.ndarray):
        self.p = problem
        self.active = active
        self.free = np.flatnonzero(~problem.fixed)
        self.slot = np.full(len(problem.poses), -1)
        self.slot[self.free] = np.arange(len(self.free))
        self.n_pose_params = 6 * len(self.free)
        self.pose_index = problem.pose_index[active]
        self.point_index = problem.point_index[active]
        self.observed = problem.observed[active]
        self.inv_sigma = 1.0 / problem.sigma[active]

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p = self.p
        delta = x[: self.n_pose_params].reshape(-1, 6)
        R = p.poses[:, :3, :3].copy()
        t = p.poses[:, :3, 3].copy()
        dR = np.array([cv2.Rodrigues(v.reshape(3, 1))[0] for v in delta[:, :3]]).reshape(-1, 3, 3)
        R[self.free] = dR @ R[self.free]
        t[self.free] = np.einsum("nij,nj->ni", dR, t[self.free]) + delta[:, 3:]
        return R, t, x[self.n_pose_params :].reshape(-1, 3)

    def _camera_points(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, t, points = self.unpack(x)
        Ri = R[self.pose_index]
        return Ri, np.einsum("nij,nj->ni", Ri, points[self.point_index]) + t[self.pose_index]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        K = self.p.K
        _, pc = self._camera_points(x)
        z = np.where(np.abs(pc[:, 2]) < 1e-9, 1e-9, pc[:, 2])
        u = K[0, 0] * pc[:, 0] / z + K[0, 2]
        v = K[1, 1] * pc[:, 1] / z + K[1, 2]
        return (np.stack([u - self.observed[:, 0], v - self.observed[:, 1]], axis=1) * self.inv_sigma[:, None]).ravel()

    def jacobian(self, x: np.ndarray) -> csr_matrix:
        K = self.p.K
        Ri, pc = self._camera_points(x)
        z = np.where(np.abs(pc[:, 2]) < 1e-9, 1e-9, pc[:, 2])
        iz = 1.0 / z
        n = len(pc)
        d_proj = np.zeros((n, 2, 3))
        d_proj[:, 0, 0] = K[0, 0] * iz
        d_proj[:, 0, 2] = -K[0, 0] * pc[:, 0] * iz * iz
        d_proj[:, 1, 1] = K[1, 1] * iz
        d_proj[:, 1, 2] = -K[1, 1] * pc[:, 1] * iz * iz
        d_proj *= self.inv_sigma[:, None, None]
        rows = np.arange(2 * n).reshape(n, 2)
        all_rows = [np.repeat(rows[:, :, None], 3, axis=2).ravel()]
        col0 = self.n_pose_params + 3 * self.point_index
        all_cols = [np.broadcast_to((col0[:, None] + np.arange(3))[:, None, :], (n, 2, 3)).ravel()]
        all_vals = [(d_proj @ Ri).ravel()]  # d pc / d X = R
        slot = self.slot[self.pose_index]
        use = slot >= 0
        if use.any():
            # pc = exp(phi) (R0 X + t0) + dt: d pc/d phi = -[pc - dt]x J_l(phi), d pc/d dt = I
            delta = x[: self.n_pose_params].reshape(-1, 6)[slot[use]]
            d_rot = d_proj[use] @ (-skew(pc[use] - delta[:, 3:]) @ _left_jacobian(delta[:, :3]))
            d_pose = np.concatenate([d_rot, d_proj[use]], axis=2)
            col0 = 6 * slot[use]
            all_rows.append(np.repeat(rows[use][:, :, None], 6, axis=2).ravel())
            all_cols.append(np.broadcast_to((col0[:, None] + np.arange(6))[:, None, :], (use.sum(), 2, 6)).ravel())
            all_vals.append(d_pose.ravel())
        shape = (2 * n, self.n_pose_params + 3 * len(self.p.points))
        return csr_matrix((np.concatenate(all_vals), (np.concatenate(all_rows), np.concatenate(all_cols))), shape=shape)


def observation_chi2(problem: BundleProblem, poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    R = poses[problem.pose_index, :3, :3]
    pc = np.einsum("nij,nj->ni", R, points[problem.point_index]) + poses[problem.pose_index, :3, 3]
    return reprojection_chi2(pc, problem.observed, problem.K, 1.0 / problem.sigma**2)


def _solve(problem: BundleProblem, active: np.ndarray, evaluations: int) -> BundleProblem:
    model = _Model(problem, active)
    x0 = np.concatenate([np.zeros(model.n_pose_params), problem.points.ravel()])
    result = least_squares(
        model.residuals,
        x0,
        jac=model.jacobian,
        method="trf",
        x_scale="jac",
        tr_solver="lsmr",
        tr_options={"maxiter": 100},
        max_nfev=evaluations,
        ftol=1e-6,
        xtol=1e-10,
    )
    R, t, points = model.unpack(result.x)
    poses = np.repeat(np.eye(4)[None], len(R), axis=0)
    poses[:, :3, :3], poses[:, :3, 3] = R, t
    return BundleProblem(poses, points, problem.pose_index, problem.point_index, problem.observed, problem.sigma, problem.fixed, problem.K)


def bundle_adjust(problem: BundleProblem, evaluations: int = 6, outlier_rounds: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Optimised poses (P, 4, 4) ``T_cw``, points (M, 3), and per-observation chi-square errors.

    Each round solves on the observations still inlying, then re-classifies all of them; the
    first round already ignores gross outliers (chi-square beyond 10x the 95 % bound)."""
    chi2 = observation_chi2(problem, problem.poses, problem.points)
    active = chi2 < 10 * CHI2_2DOF
    for _ in range(outlier_rounds):
        if active.sum() < 6:
            break
        problem = _solve(problem, active, evaluations)
        chi2 = observation_chi2(problem, problem.poses, problem.points)
        active = chi2 < CHI2_2DOF
    return problem.poses, problem.points, chi2
