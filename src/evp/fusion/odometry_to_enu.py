"""Odometry -> ENU transforms estimated with RANSAC: the paper's affine, or a similarity (Sim3).

Modes (seed 002): "3d+baro" fits a 3-D transform on (x, y, z) and then replaces the altitude with
the barometer's; "2d+baro" fits a planar transform on (x, y) only (the odometry frame's z being
vertical after a vertical take-off) and takes the altitude from the barometer.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from evp.fusion.gps_input import AlignmentError
from evp.geometry.alignment import umeyama

MODES = ("2d+baro", "3d+baro")
MODELS = ("affine", "similarity")


@dataclass(frozen=True)
class OdomToEnu:
    """``enu = A @ odom + b`` (3-D) or on x, y only (2-D); altitude from the barometer when given."""

    mode: str
    model: str
    matrix: np.ndarray  # (3, 4) for 3-D, (2, 3) for 2-D

    def apply(self, odom: np.ndarray, baro_up: np.ndarray | None = None) -> np.ndarray:
        odom = np.atleast_2d(odom)
        if self.mode == "3d+baro":
            enu = odom @ self.matrix[:, :3].T + self.matrix[:, 3]
        else:
            xy = odom[:, :2] @ self.matrix[:, :2].T + self.matrix[:, 2]
            enu = np.column_stack([xy, np.full(len(xy), np.nan)])
        if baro_up is not None:
            enu[:, 2] = baro_up
        return enu

    @property
    def scale(self) -> float:
        """Mean scale (metres of ENU per odometry unit)."""
        linear = self.matrix[:, :3] if self.mode == "3d+baro" else self.matrix[:, :2]
        return float(np.abs(np.linalg.det(linear)) ** (1.0 / linear.shape[0]))


def _ransac_similarity_3d(src: np.ndarray, dst: np.ndarray, threshold: float, rng: np.random.Generator, iterations: int = 300) -> tuple[np.ndarray, np.ndarray]:
    best = np.zeros(len(src), bool)
    for _ in range(iterations):
        sample = rng.choice(len(src), 3, replace=False)
        try:
            candidate = umeyama(src[sample], dst[sample], with_scale=True)
        except Exception:  # degenerate minimal sample (collinear points): draw again
            continue
        inliers = np.linalg.norm(candidate.apply(src) - dst, axis=1) < threshold
        if inliers.sum() > best.sum():
            best = inliers
    if best.sum() < 3:
        raise AlignmentError("no similarity transform fits the pairs (RANSAC found fewer than 3 inliers)")
    fit = umeyama(src[best], dst[best], with_scale=True)
    return np.column_stack([fit.scale * fit.rotation, fit.translation]), best


def fit_transform(odom: np.ndarray, enu: np.ndarray, mode: str, model: str, threshold_m: float, seed: int = 0) -> tuple[OdomToEnu, np.ndarray]:
    """RANSAC fit; returns the transform and the inlier mask. ``seed`` seeds the 3-D similarity's
    own RANSAC; OpenCV's estimators seed theirs with a constant (the same fit on every call)."""
    if mode not in MODES or model not in MODELS:
        raise AlignmentError(f"unknown alignment {mode}/{model} (modes {MODES}, models {MODELS})")
    minimum = 4 if mode == "3d+baro" and model == "affine" else 3
    if len(odom) < minimum:
        raise AlignmentError(f"{len(odom)} pairs are too few for a {mode} {model} fit (at least {minimum})")
    src = np.ascontiguousarray(odom, dtype=np.float64)
    dst = np.ascontiguousarray(enu, dtype=np.float64)
    if mode == "3d+baro":
        if model == "similarity":
            matrix, inliers = _ransac_similarity_3d(src, dst, threshold_m, np.random.default_rng(seed))
        else:
            ok, matrix, inliers = cv2.estimateAffine3D(src, dst, ransacThreshold=threshold_m, confidence=0.999)
            if not ok or matrix is None:
                raise AlignmentError("RANSAC found no 3-D affine transform")
            inliers = inliers.ravel().astype(bool)
    else:
        estimate = cv2.estimateAffine2D if model == "affine" else cv2.estimateAffinePartial2D
        matrix, inliers = estimate(
            np.ascontiguousarray(src[:, :2]),
            np.ascontiguousarray(dst[:, :2]),
            method=cv2.RANSAC,
            ransacReprojThreshold=threshold_m,
            maxIters=2000,
            confidence=0.999,
        )
        if matrix is None:
            raise AlignmentError(f"RANSAC found no 2-D {model} transform")
        inliers = inliers.ravel().astype(bool)
    if not np.isfinite(matrix).all():
        raise AlignmentError("the fitted transform is not finite (degenerate pairs)")
    return OdomToEnu(mode, model, np.asarray(matrix, dtype=float)), inliers
