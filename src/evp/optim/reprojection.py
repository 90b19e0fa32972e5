"""The reprojection error every estimator weighs its observations by, and its statistical gates."""

from __future__ import annotations

import numpy as np

CHI2_1DOF = 3.841  # 95 % for a point-to-line distance
CHI2_2DOF = 5.991  # 95 % for a point-to-point distance
HUBER_DELTA = np.sqrt(CHI2_2DOF)  # robust kernel width on whitened reprojection errors (ORB-SLAM's)


def pinhole_pixels(points_cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Undistorted pixel coordinates (N, 2) of camera-frame points; NaN behind the camera."""
    z = points_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = points_cam[:, :2] / z[:, None] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    uv[~(z > 0)] = np.nan
    return uv


def reprojection_chi2(points_cam: np.ndarray, observed: np.ndarray, K: np.ndarray, inv_sigma2: np.ndarray) -> np.ndarray:
    """Squared reprojection errors weighted by the observation's octave; infinite behind the camera."""
    chi2 = np.sum((pinhole_pixels(points_cam, K) - observed) ** 2, axis=1) * inv_sigma2
    return np.where(np.isfinite(chi2), chi2, np.inf)
