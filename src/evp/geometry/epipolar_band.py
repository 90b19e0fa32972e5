"""Pairs of points of two views that lie near each other's epipolar line: local mapping compares
the descriptors of these pairs only when it looks for new points to triangulate.

Every epipolar line of view b passes through the epipole e (the image of camera a's centre), so a
line is known by its direction around e, and a point b by the direction of ``b - e``. A point at
distance rho from e lies within ``tol`` of a line only if the two directions differ by at most
``asin(tol / rho)``: with view b's points sorted by direction, each line's candidates are one
window found by binary search, and only those get the exact distance test. Points so near the
epipole that the window would be wide are tested against every line, as is everything when the
epipole is practically at infinity (sideways motion; the lines are then nearly parallel).
"""

from __future__ import annotations

import numpy as np

from evp.geometry.transforms import se3_inverse, skew

FAR_EPIPOLE = 1e6  # normalised units (a million focal lengths): the lines are parallel
WINDOW_FACTOR = 4.0  # the angular window, in typical tolerance-to-distance ratios
MAX_WINDOW = 0.5  # radians; under pi/2, so a window never holds a point twice


def essential(T1_cw: np.ndarray, T2_cw: np.ndarray) -> np.ndarray:
    """Essential matrix mapping normalised points of view 1 to epipolar lines in view 2."""
    T21 = T2_cw @ se3_inverse(T1_cw)
    return skew(T21[:3, 3]) @ T21[:3, :3]


def epipolar_pairs(T1_cw: np.ndarray, T2_cw: np.ndarray, xa: np.ndarray, xb: np.ndarray, tolerance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All pairs (row of ``xa``, row of ``xb``) of normalised points, from views 1 and 2, where b
    lies within ``tolerance[b]`` (normalised units) of a's epipolar line; rows ascending."""
    T21 = T2_cw @ se3_inverse(T1_cw)
    lines = np.c_[xa, np.ones(len(xa))] @ essential(T1_cw, T2_cw).T
    lines /= np.maximum(np.hypot(lines[:, 0], lines[:, 1]), 1e-300)[:, None]
    t = T21[:3, 3]
    if abs(t[2]) * FAR_EPIPOLE <= np.hypot(t[0], t[1]) or len(xb) == 0 or len(xa) == 0:
        residual = lines[:, :2] @ xb.T + lines[:, 2:3]
        return np.nonzero(np.abs(residual) <= tolerance[None, :])
    offset = xb - t[:2] / t[2]
    rho = np.hypot(offset[:, 0], offset[:, 1])
    ratio = tolerance / np.maximum(rho, 1e-300)
    window = float(np.clip(WINDOW_FACTOR * np.median(ratio), 1e-12, MAX_WINDOW))
    near = ratio >= np.sin(window)
    rows, cols = _candidates(lines, np.flatnonzero(near), np.flatnonzero(~near), np.arctan2(offset[:, 1], offset[:, 0]), window)
    residual = lines[rows, 0] * xb[cols, 0] + lines[rows, 1] * xb[cols, 1] + lines[rows, 2]
    keep = np.abs(residual) <= tolerance[cols]
    return rows[keep], cols[keep]


def _candidates(lines: np.ndarray, near: np.ndarray, far: np.ndarray, direction: np.ndarray, window: float) -> tuple[np.ndarray, np.ndarray]:
    """(line, point) pairs, rows ascending: every line with every ``near`` point, and with the
    ``far`` points whose direction from the epipole is within ``window`` of the line's (modulo
    pi); a superset of the pairs within tolerance, by the choice of ``far``."""
    if len(far):
        angle = np.mod(direction[far], np.pi)
        order = np.argsort(angle)
        angle, far = angle[order], far[order]
        wrapped = np.r_[angle - np.pi, angle, angle + np.pi]  # windows that cross 0 or pi
        line_angle = np.mod(np.arctan2(lines[:, 0], -lines[:, 1]), np.pi)
        slack = window * (1 + 1e-9) + 1e-12  # rounding of the angles
        start = np.searchsorted(wrapped, line_angle - slack, "left")
        in_window = np.searchsorted(wrapped, line_angle + slack, "right") - start
    else:
        start = in_window = np.zeros(len(lines), np.int64)
    counts = len(near) + in_window
    rows = np.repeat(np.arange(len(lines)), counts)
    position = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)  # within the row
    from_near = position < len(near)
    cols = np.empty(len(rows), np.int64)
    cols[from_near] = near[position[from_near]]
    if len(far):
        cols[~from_near] = far[(start[rows[~from_near]] + position[~from_near] - len(near)) % len(far)]
    return rows, cols
