"""SE(3) and quaternion helpers.

Quaternions are Hamilton, stored **x, y, z, w** (scalar last) inside EVP, as in TUM files and
SciPy; conversion to the wire order (w, x, y, z) happens at the adapters that need it.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def se3(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """4x4 homogeneous transform from a 3x3 rotation and a 3-vector."""
    T = np.eye(4)
    T[:3, :3] = rotation
    T[:3, 3] = translation
    return T


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]x`` of a 3-vector (3, 3) or a stack of them (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def scale_motion(T: np.ndarray, factor: float) -> np.ndarray:
    """A rigid motion stretched over ``factor`` times its time step: rotation angle and translation
    both times ``factor`` (rotation and translation scaled apart, which for inter-frame motions
    differs from the screw motion only at second order)."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(factor * Rotation.from_matrix(T[:3, :3]).as_rotvec()).as_matrix()
    out[:3, 3] = factor * T[:3, 3]
    return out


def se3_inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (or a stack of them, shape (..., 4, 4))."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def poses_from_xyz_quat(positions: np.ndarray, quats_xyzw: np.ndarray) -> np.ndarray:
    """Stack of 4x4 poses from N positions and N quaternions (x, y, z, w; normalised here)."""
    n = len(positions)
    poses = np.tile(np.eye(4), (n, 1, 1))
    if n:
        poses[:, :3, :3] = Rotation.from_quat(quats_xyzw).as_matrix()
        poses[:, :3, 3] = positions
    return poses


def quat_xyzw_from_matrices(rotations: np.ndarray) -> np.ndarray:
    """Quaternions (x, y, z, w) with w >= 0 from a stack of 3x3 rotation matrices."""
    if len(rotations) == 0:
        return np.zeros((0, 4))
    q = Rotation.from_matrix(rotations).as_quat()
    q[q[:, 3] < 0] *= -1.0
    return q


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle in radians of a 3x3 rotation (or a stack), robust near 0 and pi."""
    return np.linalg.norm(Rotation.from_matrix(R).as_rotvec(), axis=-1)
