"""Rotations as numerical work leaves them, brought back onto SO(3)."""

from __future__ import annotations

import numpy as np


def nearest_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation closest to a 3x3 matrix (Frobenius norm): removes the scale and shear that
    numerical decompositions leave, which a chain of poses would otherwise compound."""
    U, _, Vt = np.linalg.svd(R)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt
