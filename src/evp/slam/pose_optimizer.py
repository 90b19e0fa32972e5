"""Pose-only optimisation: one camera pose against fixed 3-D points (ORB-SLAM's PoseOptimization).

A 6-parameter problem, so a small Gauss-Newton loop with a Huber kernel is the right tool here;
every larger problem goes to the bundle adjuster's solver library. Four rounds classify
observations as inliers or outliers by their chi-square error (the robust kernel is dropped in
the last rounds, as ORB-SLAM does) so that a bad match cannot drag the pose. A rotation prior
(the gyro's, :mod:`evp.slam.gyro_prior`) adds its chi-square term, as ORB-SLAM3's inertial pose
optimisation adds the IMU's.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from evp.optim.reprojection import CHI2_2DOF, HUBER_DELTA, reprojection_chi2
from evp.optim.rotation import nearest_rotation


def apply_increment(T_cw: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Left-multiply by exp of ``xi = (omega, v)``: rotation vector then translation."""
    R = cv2.Rodrigues(xi[:3].reshape(3, 1))[0]
    out = np.eye(4)
    out[:3, :3] = R @ T_cw[:3, :3]
    out[:3, 3] = R @ T_cw[:3, 3] + xi[3:]
    return out


def optimise_pose(
    T_cw: np.ndarray,
    points: np.ndarray,
    observed: np.ndarray,
    inv_sigma2: np.ndarray,
    K: np.ndarray,
    lens_jacobian: np.ndarray | None = None,
    rounds: int = 4,
    iterations: int = 10,
    rotation_prior: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Refined ``T_cw`` and the inlier mask; ``observed`` are undistorted pixel coordinates, their
    errors weighed in the detected image through ``lens_jacobian`` (``Features.lens_jacobian``).
    ``rotation_prior``: ``(R_cw, information)``, a measured rotation of the pose and its 3x3
    information (per rad^2)."""
    T = T_cw.copy()
    inlier = np.ones(len(points), bool)
    converged_on = None  # (robust, inlier set) of the last converged solve: a repeat would not move
    for round_index in range(rounds):
        robust = round_index < rounds - 2
        repeat = converged_on is not None and converged_on[0] == robust and np.array_equal(converged_on[1], inlier)
        if inlier.sum() >= 3 and not repeat:
            lens = None if lens_jacobian is None else lens_jacobian[inlier]
            fitted = _Inliers(points[inlier], observed[inlier], inv_sigma2[inlier], K, lens, rotation_prior)
            T, converged = _gauss_newton(T, fitted, robust, iterations)
            converged_on = (robust, inlier) if converged else None
        inlier = reprojection_chi2(points @ T[:3, :3].T + T[:3, 3], observed, K, inv_sigma2, lens_jacobian) < CHI2_2DOF
    T[:3, :3] = nearest_rotation(T[:3, :3])  # products of rotations drift off SO(3), slowly
    return T, inlier


@dataclass(frozen=True)
class _Inliers:
    """What one Gauss-Newton solve fits the pose to: the inliers' points, their undistorted pixels,
    information and lens Jacobians, and the rotation prior."""

    points: np.ndarray
    observed: np.ndarray
    inv_sigma2: np.ndarray
    K: np.ndarray
    lens_jacobian: np.ndarray | None
    rotation_prior: tuple[np.ndarray, np.ndarray] | None


def _gauss_newton(T: np.ndarray, inliers: _Inliers, robust: bool, iterations: int) -> tuple[np.ndarray, bool]:
    """Up to ``iterations`` Gauss-Newton steps from ``T``; the pose and whether it converged."""
    for _ in range(iterations):
        xi = _gauss_newton_step(T, inliers, robust)
        if xi is None:
            return T, False
        T = apply_increment(T, xi)
        if np.linalg.norm(xi) < 1e-5:  # such a step moves a point at unit depth 0.005 px at fx 500
            return T, True
    return T, False


def rotation_std_deg(T_cw: np.ndarray, points: np.ndarray, inv_sigma2: np.ndarray, K: np.ndarray, lens_jacobian: np.ndarray | None = None) -> np.ndarray:
    """Standard deviation (degrees) of the pose's rotation about each camera axis, at one pixel of
    noise per pyramid-level sigma in the detected image: how well these points fix the pose.
    Points in a strip of the image, on a plane, leave tilt and sideways shift nearly
    interchangeable (a large value)."""
    covariance = rotation_covariance(T_cw, points, inv_sigma2, K, lens_jacobian)
    if covariance is None:
        return np.full(3, np.inf)
    return np.degrees(np.sqrt(np.maximum(np.diag(covariance), 0.0)))


def rotation_covariance(T_cw: np.ndarray, points: np.ndarray, inv_sigma2: np.ndarray, K: np.ndarray, lens_jacobian: np.ndarray | None = None) -> np.ndarray | None:
    """Covariance (rad^2, 3x3, of a left increment) of the rotation these points fix, the
    translation left free (the rotation block of the pose covariance), at one pixel of noise per
    pyramid-level sigma; None when they do not fix the pose."""
    _, J = _residuals_and_jacobian(T_cw, points, np.zeros((len(points), 2)), K, lens_jacobian)
    WJ = (J * inv_sigma2[:, None]).reshape(-1, 6)
    information = WJ.T @ J.reshape(-1, 6)
    try:
        return np.linalg.inv(information)[:3, :3]
    except np.linalg.LinAlgError:
        return None


def _residuals_and_jacobian(T: np.ndarray, P: np.ndarray, obs: np.ndarray, K: np.ndarray, lens_jacobian: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Reprojection residuals (2, N: u rows, then v rows) and their Jacobian (2, N, 6) with
    respect to a left increment ``xi = (omega, v)`` of ``T``; both mapped into the detected image
    by ``lens_jacobian`` when there is one."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    pc = P @ T[:3, :3].T + T[:3, 3]
    iz = 1.0 / np.maximum(pc[:, 2], 1e-6)
    xz, yz = pc[:, 0] * iz, pc[:, 1] * iz
    r = np.empty((2, len(P)))
    r[0] = fx * xz + cx - obs[:, 0]
    r[1] = fy * yz + cy - obs[:, 1]
    # d(residual)/d(point in camera), then d(point)/d(xi) = [-[pc]x | I]
    J = np.zeros((2, len(P), 6))
    J[0, :, 0] = -fx * xz * yz
    J[0, :, 1] = fx * (1 + xz * xz)
    J[0, :, 2] = -fx * yz
    J[0, :, 3] = fx * iz
    J[0, :, 5] = -fx * xz * iz
    J[1, :, 0] = -fy * (1 + yz * yz)
    J[1, :, 1] = fy * xz * yz
    J[1, :, 2] = fy * xz
    J[1, :, 4] = fy * iz
    J[1, :, 5] = -fy * yz * iz
    if lens_jacobian is not None:
        r = np.einsum("nij,jn->in", lens_jacobian, r)
        J = np.einsum("nij,jnk->ink", lens_jacobian, J)
    return r, J


def _gauss_newton_step(T: np.ndarray, inliers: _Inliers, robust: bool) -> np.ndarray | None:
    """The increment ``xi`` minimising the (Huber-weighted) reprojection error, and the rotation
    prior's error ``log(R R_prior^T)`` (``omega`` plus it, to first order), to first order."""
    r, J = _residuals_and_jacobian(T, inliers.points, inliers.observed, inliers.K, inliers.lens_jacobian)
    weight = inliers.inv_sigma2
    if robust:
        e = np.sqrt((r[0] * r[0] + r[1] * r[1]) * weight)
        weight = weight * np.where(e <= HUBER_DELTA, 1.0, HUBER_DELTA / np.maximum(e, 1e-12))
    WJ = (J * weight[:, None]).reshape(-1, 6)
    H = WJ.T @ J.reshape(-1, 6) + 1e-9 * np.eye(6)
    gradient = WJ.T @ r.reshape(-1, 1)
    if inliers.rotation_prior is not None:
        R_prior, information = inliers.rotation_prior
        H[:3, :3] += information
        gradient[:3, 0] += information @ cv2.Rodrigues(T[:3, :3] @ R_prior.T)[0].ravel()
    solved, xi = cv2.solve(H, -gradient, flags=cv2.DECOMP_CHOLESKY)  # a 6x6 system: OpenCV's call costs least
    return xi.ravel() if solved else None
