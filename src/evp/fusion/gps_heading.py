"""The heading and origin that turn the navigation filter's levelled world into ENU at the take-off
point: a horizontal rotation and a translation fitted to pairs of (filter position, GPS fix in ENU).

The visual-inertial start knows gravity but not north, so the filter's world is the visual map's
frame levelled. Fitting its horizontal track to GPS gives the heading in one closed-form step (2-D
Kabsch, no scale: the filter's is metric); an EKF started with a heading prior of pi would have to
find it through linearisations that do not hold at such angles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class WorldAlignment:
    """``enu = R @ local + t``; ``pivot`` is the fixes' centroid in ENU (where a heading error
    moves nothing); sigmas are 1-sigma, from the GPS noise over the track's spread."""

    R: np.ndarray
    t: np.ndarray
    pivot: np.ndarray
    yaw_sigma_rad: float
    translation_sigma_m: float
    spread_m: float


def horizontal_spread(points: np.ndarray) -> float:
    """RMS horizontal distance of ``points`` (N, 3) from their centroid: how well they fix a heading."""
    horizontal = np.asarray(points, float)[:, :2]
    return float(np.sqrt(np.mean(np.sum((horizontal - horizontal.mean(axis=0)) ** 2, axis=1))))


def align_to_gps(local: np.ndarray, enu: np.ndarray, gps_sigma_m: float) -> WorldAlignment:
    """The heading (about z) and translation taking ``local`` (N, 3) onto ``enu`` (N, 3).

    GPS errors are correlated over a minute (multipath, atmosphere), so averaging N fixes does not
    shrink them by sqrt(N): the sigmas take one fix's error, ``gps_sigma_m``, as the error of the
    whole set (the heading's from it over the spread)."""
    local, enu = np.asarray(local, float), np.asarray(enu, float)
    local_mean, enu_mean = local.mean(axis=0), enu.mean(axis=0)
    a, b = local[:, :2] - local_mean[:2], enu[:, :2] - enu_mean[:2]
    cross = a.T @ b
    yaw = math.atan2(cross[0, 1] - cross[1, 0], cross[0, 0] + cross[1, 1])
    c, s = math.cos(yaw), math.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    spread = horizontal_spread(local)
    return WorldAlignment(R, enu_mean - R @ local_mean, enu_mean, gps_sigma_m / max(spread, gps_sigma_m), gps_sigma_m, spread)
