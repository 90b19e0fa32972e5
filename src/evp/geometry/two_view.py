"""Two-view geometry in undistorted pixel / normalised coordinates: triangulation with parallax
and reprojection checks, and ORB-SLAM's homography-versus-fundamental model selection."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from evp.optim.bundle_adjustment import BundleProblem, bundle_adjust
from evp.optim.reprojection import CHI2_1DOF, CHI2_2DOF, in_detected_pixels
from evp.optim.rotation import nearest_rotation

NEW_POINT_PARALLAX_COS = 0.9998  # ~1.1 deg: ORB-SLAM's parallax for a point from two keyframes
INITIAL_POINT_PARALLAX_COS = 0.99998  # ~0.36 deg: a point of the initial map (ORB-SLAM's CheckRT)


def triangulate(T1_cw: np.ndarray, T2_cw: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """World points (N, 3) from normalised coordinates in two views (linear, DLT)."""
    homogeneous = cv2.triangulatePoints(T1_cw[:3], T2_cw[:3], x1.T.astype(float), x2.T.astype(float))
    with np.errstate(divide="ignore", invalid="ignore"):
        return (homogeneous[:3] / homogeneous[3]).T


def check_points(
    points: np.ndarray,
    T1_cw: np.ndarray,
    T2_cw: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    focal: float,
    sigma2_1: np.ndarray | float,
    sigma2_2: np.ndarray | float,
    min_parallax_cos: float,
    lens_1: np.ndarray | None = None,
    lens_2: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Mask of points in front of both cameras, reprojecting within chi-square bounds (errors
    weighed in the detected image through ``lens_1`` / ``lens_2``, ``Features.lens_jacobian``),
    seen with enough parallax; and the cosine of each point's parallax angle."""
    c1 = T1_cw[:3, :3] @ points.T + T1_cw[:3, 3:4]
    c2 = T2_cw[:3, :3] @ points.T + T2_cw[:3, 3:4]
    good = np.isfinite(points).all(axis=1) & (c1[2] > 0) & (c2[2] > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        e1 = _squared_pixel_error(c1, x1, focal, lens_1)
        e2 = _squared_pixel_error(c2, x2, focal, lens_2)
        ray1 = points - (-T1_cw[:3, :3].T @ T1_cw[:3, 3])
        ray2 = points - (-T2_cw[:3, :3].T @ T2_cw[:3, 3])
        cos = np.sum(ray1 * ray2, axis=1) / (np.linalg.norm(ray1, axis=1) * np.linalg.norm(ray2, axis=1))
    good &= (e1 < CHI2_2DOF * sigma2_1) & (e2 < CHI2_2DOF * sigma2_2) & (cos < min_parallax_cos)
    return good, cos


def _squared_pixel_error(points_cam: np.ndarray, x: np.ndarray, focal: float, lens_jacobian: np.ndarray | None) -> np.ndarray:
    """Squared reprojection errors (pixels) of (3, N) camera-frame points seen at normalised ``x``."""
    if lens_jacobian is None:
        return focal**2 * np.sum((points_cam[:2] / points_cam[2] - x.T) ** 2, axis=0)
    return np.sum(in_detected_pixels(focal * (points_cam[:2] / points_cam[2]).T - focal * x, lens_jacobian) ** 2, axis=1)


@dataclass
class TwoViewResult:
    """Relative pose of view 2 (``T21``: view-1 coordinates to view-2) and triangulated points."""

    T21: np.ndarray
    points: np.ndarray  # in view-1 coordinates
    good: np.ndarray  # mask over the matches
    model: str  # "homography" or "fundamental"
    parallax_deg: float


@dataclass
class TwoViewCandidate:
    """The unambiguous motion between two views, before a start decides whether its parallax is
    enough: ``parallax_deg`` is the 51st-largest parallax of the points in front of both views
    (ORB-SLAM's measure), ``wide`` how many have a new point's parallax (~1.1 degrees), the points
    that fix the map's shape."""

    T21: np.ndarray  # unit baseline
    points: np.ndarray
    good: np.ndarray
    cos: np.ndarray  # cosine of each point's parallax angle
    model: str
    parallax_deg: float

    @property
    def wide(self) -> int:
        return int((self.good & (self.cos < NEW_POINT_PARALLAX_COS)).sum())


def _homography_score(H21: np.ndarray, p1: np.ndarray, p2: np.ndarray, sigma: float) -> tuple[float, np.ndarray]:
    """ORB-SLAM's score: sum over both transfer directions of (threshold - chi2) where inlying."""
    H12 = np.linalg.inv(H21)

    def transfer(H, a):
        q = np.c_[a, np.ones(len(a))] @ H.T
        return q[:, :2] / q[:, 2:3]

    inv_s2 = 1.0 / sigma**2
    e2 = np.sum((transfer(H21, p1) - p2) ** 2, axis=1) * inv_s2
    e1 = np.sum((transfer(H12, p2) - p1) ** 2, axis=1) * inv_s2
    inlier = (e1 < CHI2_2DOF) & (e2 < CHI2_2DOF)
    score = np.where(e1 < CHI2_2DOF, CHI2_2DOF - e1, 0) + np.where(e2 < CHI2_2DOF, CHI2_2DOF - e2, 0)
    return float(np.sum(score[inlier])), inlier


def _fundamental_score(F21: np.ndarray, p1: np.ndarray, p2: np.ndarray, sigma: float) -> tuple[float, np.ndarray]:
    inv_s2 = 1.0 / sigma**2
    h1 = np.c_[p1, np.ones(len(p1))]
    h2 = np.c_[p2, np.ones(len(p2))]
    l2 = h1 @ F21.T  # lines in image 2
    l1 = h2 @ F21  # lines in image 1
    e2 = np.sum(l2 * h2, axis=1) ** 2 / (l2[:, 0] ** 2 + l2[:, 1] ** 2) * inv_s2
    e1 = np.sum(l1 * h1, axis=1) ** 2 / (l1[:, 0] ** 2 + l1[:, 1] ** 2) * inv_s2
    inlier = (e1 < CHI2_1DOF) & (e2 < CHI2_1DOF)
    # scored against the 2-dof threshold so that both models compete on the same scale
    score = np.where(e1 < CHI2_1DOF, CHI2_2DOF - e1, 0) + np.where(e2 < CHI2_1DOF, CHI2_2DOF - e2, 0)
    return float(np.sum(score[inlier])), inlier


def _best_motion(
    candidates: list[tuple[np.ndarray, np.ndarray]],
    x1: np.ndarray,
    x2: np.ndarray,
    inlier: np.ndarray,
    focal: float,
    min_triangulated: int,
    ambiguity_ratio: float,
    model: str,
) -> TwoViewCandidate | None:
    """The (R, t) candidate that puts the most inliers in front of both cameras, if it is
    unambiguous (the runner-up reconstructs clearly fewer)."""
    T1 = np.eye(4)
    results = []
    for R, t in candidates:
        T2 = np.eye(4)
        T2[:3, :3], T2[:3, 3] = nearest_rotation(R), np.ravel(t) / max(np.linalg.norm(t), 1e-12)
        points = triangulate(T1, T2, x1, x2)
        good, cos = check_points(points, T1, T2, x1, x2, focal, 4.0, 4.0, min_parallax_cos=1.0)
        good &= inlier
        parallax = float(np.degrees(np.arccos(np.clip(np.sort(cos[good])[min(50, good.sum() - 1)], -1, 1)))) if good.sum() else 0.0
        results.append(TwoViewCandidate(T2, points, good, cos, model, parallax))
    results.sort(key=lambda r: -r.good.sum())
    best = results[0]
    second = results[1].good.sum() if len(results) > 1 else 0
    if best.good.sum() < max(min_triangulated, int(0.9 * inlier.sum())) or second > ambiguity_ratio * best.good.sum():
        return None
    return best


def complete_two_view(candidate: TwoViewCandidate, x1: np.ndarray, x2: np.ndarray, focal: float, min_parallax_deg: float, min_triangulated: int) -> TwoViewResult | None:
    """The initial map from a candidate with parallax enough, or None (wait for a later frame)."""
    if candidate.parallax_deg < min_parallax_deg:
        return None
    # Points are kept down to ORB-SLAM's initial parallax limit (its CheckRT, on the RANSAC model):
    # at first they are all tracking has; lower-parallax points are directions, not positions.
    # Enough of them must have ORB-SLAM's new-point parallax, or initialisation waits (the mapper's
    # own limit, slam.new_point_min_parallax_deg, is 2: a start at 3 degrees has those points anyway).
    if candidate.wide < min_triangulated:
        return None
    T1, points = np.eye(4), candidate.points.copy()
    good = candidate.good & check_points(points, T1, candidate.T21, x1, x2, focal, 4.0, 4.0, INITIAL_POINT_PARALLAX_COS)[0]
    T2, points[good] = _refine(candidate.T21, points[good], x1[good], x2[good], focal)
    return TwoViewResult(T2, points, good, candidate.model, candidate.parallax_deg)


def _refine(T2: np.ndarray, points: np.ndarray, x1: np.ndarray, x2: np.ndarray, focal: float) -> tuple[np.ndarray, np.ndarray]:
    """Two-view bundle adjustment of the second pose and the points (the first view fixed), back
    to a unit baseline: the RANSAC model is fitted on a minimal-ish sample, this uses every inlier."""
    n = len(points)
    K = np.diag([focal, focal, 1.0])
    problem = BundleProblem(
        np.array([np.eye(4), T2]),
        points,
        np.repeat([0, 1], n),
        np.tile(np.arange(n), 2),
        np.vstack([x1, x2]) * focal,
        np.ones(2 * n),
        np.array([True, False]),
        K,
    )
    poses, refined, _ = bundle_adjust(problem, evaluations=10, outlier_rounds=1)
    scale = 1.0 / max(np.linalg.norm(poses[1][:3, 3]), 1e-12)
    T = poses[1].copy()
    T[:3, 3] *= scale
    return T, refined * scale


def two_view_candidate(
    x1: np.ndarray,
    x2: np.ndarray,
    focal: float,
    min_triangulated: int = 50,
    homography_ratio: float = 0.40,
    sigma_px: float = 1.0,
    parallel: Callable[..., list] | None = None,
) -> TwoViewCandidate | None:
    """The motion between two views from matched normalised coordinates (ORB-SLAM's Initializer).

    A homography and a fundamental matrix are estimated with RANSAC (at once when ``parallel``,
    which runs the callables it is given together and returns their results, is given) and scored;
    ``RH = S_H / (S_H + S_F) > homography_ratio`` selects the homography (planar or low-parallax
    scenes), else the fundamental matrix. ``None`` when the motion is ambiguous.
    """
    if len(x1) < min_triangulated:
        return None
    p1, p2 = x1 * focal, x2 * focal  # pixel-scaled normalised coordinates: thresholds in pixels
    threshold = 2.0 * sigma_px

    def fit_h():
        return cv2.findHomography(p1, p2, cv2.RANSAC, threshold, maxIters=200, confidence=0.999)[0]

    def fit_f():
        return cv2.findFundamentalMat(p1, p2, cv2.FM_RANSAC, threshold * 0.75, 0.999, 200)[0]

    H, F = parallel(fit_h, fit_f) if parallel is not None else (fit_h(), fit_f())
    score_h, inlier_h = _homography_score(H, p1, p2, sigma_px) if H is not None and H.shape == (3, 3) else (0.0, None)
    score_f, inlier_f = _fundamental_score(F[:3], p1, p2, sigma_px) if F is not None and F.shape[0] >= 3 else (0.0, None)
    if score_h + score_f <= 0:
        return None
    if score_h / (score_h + score_f) > homography_ratio:
        _, rotations, translations, _ = cv2.decomposeHomographyMat(H, np.diag([focal, focal, 1.0]))
        candidates = list(zip(rotations, translations, strict=True))
        return _best_motion(candidates, x1, x2, inlier_h, focal, min_triangulated, 0.75, "homography")
    E = F[:3].copy()  # p = focal * x, so E = diag(f,f,1) F diag(f,f,1)
    K = np.diag([focal, focal, 1.0])
    E = K.T @ E @ K
    R1, R2, t = cv2.decomposeEssentialMat(E)
    candidates = [(R1, t), (R1, -t), (R2, t), (R2, -t)]
    return _best_motion(candidates, x1, x2, inlier_f, focal, min_triangulated, 0.7, "fundamental")
