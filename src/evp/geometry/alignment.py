"""Least-squares similarity / rigid alignment of point sets (Umeyama, IEEE PAMI 1991)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evp.errors import EvaluationError


@dataclass(frozen=True)
class Similarity:
    """``y = scale * rotation @ x + translation``."""

    rotation: np.ndarray
    translation: np.ndarray
    scale: float = 1.0
    degenerate: bool = False  # points (nearly) collinear: the rotation about their line is arbitrary

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform an (N, d) array of points."""
        return self.scale * points @ self.rotation.T + self.translation

    def apply_to_poses(self, poses: np.ndarray) -> np.ndarray:
        """Transform a stack of 4x4 poses: rotations are rotated, positions fully transformed."""
        out = poses.copy()
        out[:, :3, :3] = self.rotation @ poses[:, :3, :3]
        out[:, :3, 3] = self.apply(poses[:, :3, 3])
        return out

    @staticmethod
    def identity(dim: int = 3) -> Similarity:
        return Similarity(np.eye(dim), np.zeros(dim), 1.0)


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool) -> Similarity:
    """Similarity (or rigid when ``with_scale`` is False) that best maps ``source`` onto ``target``.

    Both are (N, d) arrays of corresponding points. Points on one line (a slider, a straight
    drive) leave the rotation about that line free: evo refuses them, we return one of the equally
    good least-squares solutions and flag it ``degenerate``. Raises :class:`EvaluationError` when
    the points are too few or all coincide.
    """
    source = np.asarray(source, dtype=float)
    target = np.asarray(target, dtype=float)
    if source.shape != target.shape or source.ndim != 2:
        raise EvaluationError(f"alignment needs two (N, d) arrays of equal shape, got {source.shape} and {target.shape}")
    n, dim = source.shape
    if not (np.isfinite(source).all() and np.isfinite(target).all()):
        raise EvaluationError("alignment needs finite positions (NaN or infinite values found)")
    if n < 2:
        raise EvaluationError(f"alignment needs at least 2 corresponding points, got {n}")
    mean_s = source.mean(axis=0)
    mean_t = target.mean(axis=0)
    centred_s = source - mean_s
    centred_t = target - mean_t
    variance_s = np.sum(centred_s**2) / n
    covariance = centred_t.T @ centred_s / n
    u, d, vt = np.linalg.svd(covariance)
    rank = np.count_nonzero(d > np.finfo(d.dtype).eps)
    if rank == 0 or variance_s == 0.0:
        raise EvaluationError("alignment is impossible: the estimated positions all coincide")
    s = np.eye(dim)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        s[-1, -1] = -1.0
    rotation = u @ s @ vt
    scale = float(np.trace(np.diag(d) @ s) / variance_s) if with_scale else 1.0
    translation = mean_t - scale * rotation @ mean_s
    return Similarity(rotation, translation, scale, degenerate=bool(rank < dim - 1))
