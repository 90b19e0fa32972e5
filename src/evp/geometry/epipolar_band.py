"""Pairs of points of two views that lie near each other's epipolar line: local mapping compares
the descriptors of these pairs only when it looks for new points to triangulate."""

from __future__ import annotations

import numpy as np

from evp.geometry.transforms import se3_inverse, skew


def essential(T1_cw: np.ndarray, T2_cw: np.ndarray) -> np.ndarray:
    """Essential matrix mapping normalised points of view 1 to epipolar lines in view 2."""
    T21 = T2_cw @ se3_inverse(T1_cw)
    return skew(T21[:3, 3]) @ T21[:3, :3]


def epipolar_pairs(T1_cw: np.ndarray, T2_cw: np.ndarray, xa: np.ndarray, xb: np.ndarray, tolerance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All pairs (row of ``xa``, row of ``xb``) of normalised points, from views 1 and 2, where b
    lies within ``tolerance[b]`` (normalised units) of a's epipolar line; rows ascending.

    Every pair is tested (float32: one matrix product), and the few percent kept are read from
    the flat mask: ``np.nonzero`` of the 2-D mask cost four times the product and the test.
    Sorting view b's points by direction around the epipole, so that each line meets only a
    window of them, was tried: enumerating the windows cost as much as this."""
    lines = (np.c_[xa, np.ones(len(xa))] @ essential(T1_cw, T2_cw).T).astype(np.float32)
    lines /= np.maximum(np.hypot(lines[:, 0], lines[:, 1]), 1e-12)[:, None]
    residual = lines @ np.c_[xb, np.ones(len(xb))].astype(np.float32).T
    np.abs(residual, out=residual)
    return np.divmod(np.flatnonzero(residual <= tolerance.astype(np.float32)[None, :]), len(xb))
