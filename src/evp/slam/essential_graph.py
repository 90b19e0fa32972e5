"""Pose-graph optimisation of keyframe similarities (ORB-SLAM's essential-graph optimisation).

After a loop is found, the error it reveals (in pose and, monocular, in scale) is spread over the
keyframes between its two ends. Nodes are keyframe poses ``S_iw`` (world to camera, as
similarities); each edge ``(i, j)`` holds the relative transform ``S_ij = S_iw S_jw^-1`` it
should keep. The residual of an edge is ``log(S_ij^-1 S_iw S_jw^-1)`` (rotation vector,
translation, log scale), all weighted alike as in ORB-SLAM. Solved with SciPy's sparse
trust-region least squares; each edge's Jacobian is a numerical 7x14 block computed for all
edges at once (14 vectorised evaluations, however many edges a keyframe has).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix

from evp.geometry.sim3 import Sim3

_STEP = 1e-6


def optimise_pose_graph(initial: Sim3, fixed: np.ndarray, edge_i: np.ndarray, edge_j: np.ndarray, measured: Sim3, max_iterations: int = 20) -> Sim3:
    """Optimised poses (same order as ``initial``); poses flagged in ``fixed`` stay put."""
    free = np.flatnonzero(~fixed)
    slot = np.full(len(initial), -1)
    slot[free] = np.arange(len(free))
    measured_inverse = measured.inverse()
    S_i, S_j = initial[edge_i], initial[edge_j]

    def increments(x: np.ndarray) -> np.ndarray:
        delta = np.zeros((len(initial), 7))
        delta[free] = x.reshape(-1, 7)
        return delta

    def edge_residuals(delta_i: np.ndarray, delta_j: np.ndarray) -> np.ndarray:
        return (measured_inverse @ (Sim3.exp(delta_i) @ S_i) @ (Sim3.exp(delta_j) @ S_j).inverse()).log()

    def residuals(x: np.ndarray) -> np.ndarray:
        delta = increments(x)
        return edge_residuals(delta[edge_i], delta[edge_j]).ravel()

    rows_per_edge = 7 * np.arange(len(edge_i))[:, None] + np.arange(7)  # (E, 7)

    def jacobian(x: np.ndarray) -> csr_matrix:
        delta = increments(x)
        d_i, d_j = delta[edge_i], delta[edge_j]
        base = edge_residuals(d_i, d_j)
        rows, cols, values = [], [], []
        for end, node in ((0, edge_i), (1, edge_j)):
            movable = slot[node] >= 0
            for k in range(7):
                bumped = [d_i.copy(), d_j.copy()]
                bumped[end][:, k] += _STEP
                column = (edge_residuals(*bumped) - base) / _STEP  # (E, 7)
                rows.append(rows_per_edge[movable].ravel())
                cols.append(np.repeat(7 * slot[node][movable] + k, 7))
                values.append(column[movable].ravel())
        return csr_matrix((np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))), shape=(7 * len(edge_i), 7 * len(free)))

    if len(free) == 0 or len(edge_i) == 0:
        return initial
    result = least_squares(residuals, np.zeros(7 * len(free)), jac=jacobian, method="trf", tr_solver="lsmr", max_nfev=max_iterations, x_scale=1.0)
    return Sim3.exp(increments(result.x)) @ initial
