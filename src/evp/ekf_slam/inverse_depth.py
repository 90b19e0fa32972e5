"""Civera's inverse-depth point and its conversion to a Euclidean one.

An inverse-depth feature is ``(a_x, a_y, a_z, azimuth, elevation, rho)``: the camera centre ``a``
it was first seen from, the world direction of its ray and the inverse of its depth along it, so
that a point first seen with no parallax (depth anywhere up to infinity) is a Gaussian in the
state (rho near 0 is as well-behaved as any other value). Once its depth is well determined the
linearity index is small and three Euclidean coordinates describe it as well with half the states.
"""

from __future__ import annotations

import numpy as np

INVERSE_DEPTH_SIZE = 6
EUCLIDEAN_SIZE = 3


def ray_direction(azimuth: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    """(..., 3) unit world direction ``m(azimuth, elevation)`` (seed 001's equation: azimuth
    about world z from x, elevation above the xy plane)."""
    ca, sa, ce, se = np.cos(azimuth), np.sin(azimuth), np.cos(elevation), np.sin(elevation)
    return np.stack([ca * ce, sa * ce, se], axis=-1)


def ray_direction_derivatives(azimuth: np.ndarray, elevation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d m / d azimuth and d m / d elevation, each (..., 3)."""
    ca, sa, ce, se = np.cos(azimuth), np.sin(azimuth), np.cos(elevation), np.sin(elevation)
    d_azimuth = np.stack([-sa * ce, ca * ce, np.zeros_like(ca)], axis=-1)
    d_elevation = np.stack([-ca * se, -sa * se, ce], axis=-1)
    return d_azimuth, d_elevation


def ray_angles(direction: np.ndarray) -> tuple[float, float, np.ndarray]:
    """Azimuth and elevation of a world direction (any length), and their derivative (2, 3) with
    respect to it."""
    dx, dy, dz = direction
    horizontal2 = dx * dx + dy * dy
    horizontal = np.sqrt(horizontal2)
    norm2 = horizontal2 + dz * dz
    jacobian = np.array([[-dy / horizontal2, dx / horizontal2, 0.0], [-dx * dz / (norm2 * horizontal), -dy * dz / (norm2 * horizontal), horizontal / norm2]])
    return float(np.arctan2(dy, dx)), float(np.arctan2(dz, horizontal)), jacobian


def euclidean(feature: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The point ``a + m / rho`` of an inverse-depth feature and its derivative (3, 6)."""
    anchor, azimuth, elevation, rho = feature[:3], feature[3], feature[4], feature[5]
    m = ray_direction(azimuth, elevation)
    d_azimuth, d_elevation = ray_direction_derivatives(azimuth, elevation)
    jacobian = np.column_stack([np.eye(3), d_azimuth / rho, d_elevation / rho, -m / rho**2])
    return anchor + m / rho, jacobian


def linearity_index(features: np.ndarray, rho_sigma: np.ndarray, camera_position: np.ndarray) -> np.ndarray:
    """Civera et al.'s linearity index of inverse-depth features (N, 6) seen from
    ``camera_position``: ``4 sigma_d / d1 |cos alpha|`` with ``sigma_d = sigma_rho / rho^2`` the
    depth's uncertainty, ``d1`` the point's distance from the camera and ``alpha`` the angle
    between that line and the first ray. Below ~0.1 the Euclidean form is as linear as the
    inverse-depth one (their Fig. 5)."""
    anchor, m, rho = features[:, :3], ray_direction(features[:, 3], features[:, 4]), features[:, 5]
    sight = anchor + m / rho[:, None] - camera_position
    distance = np.maximum(np.linalg.norm(sight, axis=1), 1e-12)
    cos_alpha = np.einsum("na,na->n", m, sight) / distance
    return 4.0 * rho_sigma / rho**2 / distance * np.abs(cos_alpha)
