"""Pose-graph optimisation of keyframe similarities (ORB-SLAM's essential-graph optimisation).

After a loop is found, the error it reveals (in pose and, monocular, in scale) is spread over the
keyframes between its two ends. Nodes are keyframe poses ``S_iw`` (world to camera, as
similarities); each edge ``(i, j)`` holds the relative transform ``S_ij = S_iw S_jw^-1`` it
should keep. The residual of an edge is ``log(S_ij^-1 S_iw S_jw^-1)`` (rotation vector,
translation, log scale), all weighted alike as in ORB-SLAM. Solved by Levenberg-Marquardt
(ORB-SLAM runs g2o's, 20 iterations) with each step a direct sparse solve of the damped normal
equations (7x7 blocks, `evp.optim.sparse_solve`); each edge's Jacobian is a numerical 7x14 block
computed for all edges at once (14 vectorised evaluations, however many edges a keyframe has).
SciPy's trust-region least squares with its iterative LSMR step took 5.6 s on the 300 s drone
flight's loop (392 keyframes, 3530 edges), most of it in LSMR (docs/decisions.md).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cached_property

import numpy as np
from scipy.sparse import csr_matrix, diags

from evp.geometry.sim3 import Sim3
from evp.optim.levenberg_marquardt import levenberg_marquardt
from evp.optim.sparse_solve import solve_positive_definite

_STEP = 1e-6
MIN_REDUCTION = 1e-10  # relative cost reduction below which the solve has converged


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
    def estimate(x: np.ndarray) -> _Estimate:
        return _Estimate(x, residuals(x), jacobian)

    def step(current: _Estimate, damping: float) -> _Estimate | None:
        H, g = current.normal_equations
        dx = solve_positive_definite(H + diags(damping * H.diagonal() + 1e-12), -g)
        return None if dx is None else estimate(current.x + dx)

    solved = levenberg_marquardt(estimate(np.zeros(7 * len(free))), step, lambda current: current.cost, max_iterations, MIN_REDUCTION)
    return Sim3.exp(increments(solved.x)) @ initial


class _Estimate:
    """The increments ``x``, their residuals, and the normal equations at them (``J^T J``,
    ``J^T r``), built when a step is first asked of them: a trial the cost refuses never needs them."""

    def __init__(self, x: np.ndarray, r: np.ndarray, jacobian: Callable[[np.ndarray], csr_matrix]):
        self.x, self.r, self.cost, self._jacobian = x, r, float(r @ r), jacobian

    @cached_property
    def normal_equations(self) -> tuple[csr_matrix, np.ndarray]:
        J = self._jacobian(self.x)
        return (J.T @ J).tocsc(), J.T @ self.r
