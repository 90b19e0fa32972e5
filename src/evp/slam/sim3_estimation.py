"""The similarity between two keyframes' cameras from matched map points (ORB-SLAM's Sim3Solver
and OptimizeSim3), used to verify and measure a loop.

RANSAC over minimal sets of three 3-D correspondences (Umeyama's closed form); a correspondence
is an inlier when each point reprojects within the chi-square bound into the other keyframe's
image. The winner is refined by minimising those reprojection errors in both images (depths of a
monocular map are far less certain than its image positions).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from evp.errors import EvaluationError
from evp.geometry.alignment import umeyama
from evp.geometry.sim3 import Sim3
from evp.optim.reprojection import CHI2_2DOF, HUBER_DELTA, in_detected_pixels, pinhole_pixels, reprojection_chi2

MIN_INLIERS = 20


def _inliers(
    S_ab: Sim3, Xa: np.ndarray, Xb: np.ndarray, uv_a: np.ndarray, uv_b: np.ndarray, w_a: np.ndarray, w_b: np.ndarray, K: np.ndarray, lens: tuple
) -> np.ndarray:
    in_a = reprojection_chi2(S_ab.apply(Xb), uv_a, K, w_a, lens[0]) < CHI2_2DOF
    in_b = reprojection_chi2(S_ab.inverse().apply(Xa), uv_b, K, w_b, lens[1]) < CHI2_2DOF
    return in_a & in_b


def estimate_sim3(
    Xa: np.ndarray,
    Xb: np.ndarray,
    uv_a: np.ndarray,
    uv_b: np.ndarray,
    inv_sigma2_a: np.ndarray,
    inv_sigma2_b: np.ndarray,
    K: np.ndarray,
    iterations: int = 300,
    seed: int = 0,
    lens_a: np.ndarray | None = None,
    lens_b: np.ndarray | None = None,
) -> tuple[Sim3, np.ndarray] | None:
    """``S_ab`` mapping camera-b coordinates to camera-a coordinates, and the inlier mask, from
    matched points ``Xa`` / ``Xb`` (each in its own camera's frame) seen at undistorted pixels
    ``uv_a`` / ``uv_b`` (errors weighed in the detected image through ``lens_a`` / ``lens_b``,
    ``Features.lens_jacobian``); None without :data:`MIN_INLIERS` consistent matches."""
    n = len(Xa)
    if n < MIN_INLIERS:
        return None
    rng = np.random.default_rng(seed)
    best, best_inliers = None, np.zeros(n, bool)
    for _ in range(iterations):
        sample = rng.choice(n, 3, replace=False)
        try:
            fit = umeyama(Xb[sample], Xa[sample], with_scale=True)
        except EvaluationError:
            continue
        if fit.degenerate or not fit.scale > 0:
            continue
        S = Sim3.one(fit.scale, fit.rotation, fit.translation)
        inliers = _inliers(S, Xa, Xb, uv_a, uv_b, inv_sigma2_a, inv_sigma2_b, K, (lens_a, lens_b))
        if inliers.sum() > best_inliers.sum():
            best, best_inliers = S, inliers
    if best is None or best_inliers.sum() < MIN_INLIERS:
        return None
    kept_lens = tuple(None if lens is None else lens[best_inliers] for lens in (lens_a, lens_b))
    refined = refine_sim3(
        best, Xa[best_inliers], Xb[best_inliers], uv_a[best_inliers], uv_b[best_inliers], inv_sigma2_a[best_inliers], inv_sigma2_b[best_inliers], K, kept_lens
    )
    inliers = _inliers(refined, Xa, Xb, uv_a, uv_b, inv_sigma2_a, inv_sigma2_b, K, (lens_a, lens_b))
    if inliers.sum() < MIN_INLIERS:
        return None
    return refined, inliers


def refine_sim3(
    S_ab: Sim3, Xa: np.ndarray, Xb: np.ndarray, uv_a: np.ndarray, uv_b: np.ndarray, w_a: np.ndarray, w_b: np.ndarray, K: np.ndarray, lens: tuple = (None, None)
) -> Sim3:
    """Minimise both images' reprojection errors (Huber, in the detected images: ``lens`` holds
    each image's lens Jacobians or None) over the 7 parameters of ``S_ab``."""
    sqrt_a, sqrt_b = np.sqrt(w_a)[:, None], np.sqrt(w_b)[:, None]

    def residuals(xi: np.ndarray) -> np.ndarray:
        S = Sim3.exp(xi) @ S_ab
        r_a = in_detected_pixels(pinhole_pixels(S.apply(Xb), K) - uv_a, lens[0]) * sqrt_a
        r_b = in_detected_pixels(pinhole_pixels(S.inverse().apply(Xa), K) - uv_b, lens[1]) * sqrt_b
        return np.nan_to_num(np.concatenate([r_a, r_b]).ravel(), nan=1e3)

    result = least_squares(residuals, np.zeros(7), loss="huber", f_scale=HUBER_DELTA, max_nfev=50)
    return Sim3.exp(result.x) @ S_ab
