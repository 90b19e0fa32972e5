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


def in_detected_pixels(errors: np.ndarray, lens_jacobian: np.ndarray | None) -> np.ndarray:
    """(N, 2) errors in undistorted pixels mapped, to first order, into the detected image, where
    the detector's noise is isotropic: ``lens_jacobian`` (N, 2, 2) is each observation's
    derivative of the detected pixel with respect to the undistorted one (``Features.lens_jacobian``);
    None, a lens without distortion, leaves them as they are."""
    if lens_jacobian is None:
        return errors
    return np.einsum("nij,nj->ni", lens_jacobian, errors)


def reprojection_chi2(
    points_cam: np.ndarray, observed: np.ndarray, K: np.ndarray, inv_sigma2: np.ndarray, lens_jacobian: np.ndarray | None = None
) -> np.ndarray:
    """Squared reprojection errors weighted by the observation's octave (and its lens, see
    :func:`in_detected_pixels`); infinite behind the camera."""
    chi2 = np.sum(in_detected_pixels(pinhole_pixels(points_cam, K) - observed, lens_jacobian) ** 2, axis=1) * inv_sigma2
    return np.where(np.isfinite(chi2), chi2, np.inf)
