"""The metric marker map refined from every observation: a 2-D pose graph solved by least squares.

Each node is a marker's pose (x, y, theta) on the floor; each edge is the mean relative pose of
two markers seen in the same frames, weighted by its distance-based quality summed over those
frames. The first marker is held fixed (the gauge). Beyond seed 003's grid, this keeps the map
right for markers in any layout and spreads the small errors of chained frames over a loop
instead of leaving them at its end.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix

from evp.markers.planar import wrap

ANGLE_WEIGHT_M = 0.1  # one radian of relative heading counts like 0.1 m of relative position


def relative_residuals(poses: np.ndarray, edges_ij: np.ndarray, measured: np.ndarray, sqrt_weights: np.ndarray) -> np.ndarray:
    """Residuals (3 per edge) of measured relative poses b = a^-1 o b against the poses' own."""
    a, b = poses[edges_ij[:, 0]], poses[edges_ij[:, 1]]
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    predicted = np.column_stack([c * dx + s * dy, -s * dx + c * dy, wrap(b[:, 2] - a[:, 2])])
    error = predicted - measured
    error[:, 2] = wrap(error[:, 2]) * ANGLE_WEIGHT_M
    return (error * sqrt_weights[:, None]).ravel()


def relative_jacobian(poses: np.ndarray, edges_ij: np.ndarray, sqrt_weights: np.ndarray, column: np.ndarray) -> csr_matrix:
    """Sparse Jacobian of :func:`relative_residuals` over the free poses (``column``: a node's
    block of three columns, -1 when it is held fixed). With R(-theta_a) = [[c, s], [-s, c]], the
    position error R(-theta_a)(p_b - p_a) has derivative -R, R and [[-s, c], [-c, -s]](p_b - p_a)
    in p_a, p_b and theta_a; the heading error has -1 and +1 (times the angle weight)."""
    a, b = poses[edges_ij[:, 0]], poses[edges_ij[:, 1]]
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    n = len(edges_ij)
    block_b = np.zeros((n, 3, 3))
    block_b[:, 0, 0], block_b[:, 0, 1], block_b[:, 1, 0], block_b[:, 1, 1] = c, s, -s, c
    block_b[:, 2, 2] = ANGLE_WEIGHT_M
    block_a = -block_b
    block_a[:, 0, 2] = -s * dx + c * dy
    block_a[:, 1, 2] = -c * dx - s * dy
    rows, cols, values = [], [], []
    base_rows = 3 * np.arange(n)[:, None, None] + np.arange(3)[None, :, None]
    for node, block in ((edges_ij[:, 0], block_a), (edges_ij[:, 1], block_b)):
        keep = column[node] >= 0
        cols_here = 3 * column[node][keep][:, None, None] + np.arange(3)[None, None, :]
        rows.append(np.broadcast_to(base_rows[keep], (keep.sum(), 3, 3)).ravel())
        cols.append(np.broadcast_to(cols_here, (keep.sum(), 3, 3)).ravel())
        values.append((block[keep] * sqrt_weights[keep, None, None]).ravel())
    free_count = int(column.max()) + 1
    return csr_matrix((np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * free_count))


def refine_poses(initial: dict[int, np.ndarray], edges: dict[tuple[int, int], tuple[np.ndarray, float]], fixed: int) -> dict[int, np.ndarray]:
    """Poses that best agree with the edges ((i, j) -> (relative pose of j in i, weight)); the
    ``fixed`` marker keeps its pose. Markers without an edge keep theirs."""
    ids = sorted(initial)
    index = {marker_id: k for k, marker_id in enumerate(ids)}
    usable = [(i, j) for (i, j) in edges if i in index and j in index]
    if not usable or len(ids) < 2:
        return dict(initial)
    pairs = np.array([[index[i], index[j]] for i, j in usable])
    measured = np.array([edges[key][0] for key in usable])
    sqrt_weights = np.sqrt(np.array([max(edges[key][1], 1e-6) for key in usable]))
    free = [k for k in range(len(ids)) if ids[k] != fixed]
    start = np.array([initial[marker_id] for marker_id in ids], dtype=float)

    def unpack(x: np.ndarray) -> np.ndarray:
        poses = start.copy()
        poses[free] = x.reshape(-1, 3)
        return poses

    column = np.full(len(ids), -1)
    column[free] = np.arange(len(free))

    def jacobian(x: np.ndarray) -> csr_matrix:
        return relative_jacobian(unpack(x), pairs, sqrt_weights, column)

    result = least_squares(lambda x: relative_residuals(unpack(x), pairs, measured, sqrt_weights), start[free].ravel(), jac=jacobian, method="trf", max_nfev=20)
    solved = unpack(result.x)
    solved[:, 2] = wrap(solved[:, 2])
    return {marker_id: solved[index[marker_id]] for marker_id in ids}
