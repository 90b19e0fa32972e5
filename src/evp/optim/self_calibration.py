"""Bundle adjustment with the lens among the variables: camera poses, ground points and one shared
focal length and radial distortion (k1, k2), solved together as COLMAP and OpenSfM self-calibrate.

The residuals are reprojection errors in the detected (distorted) pixels, where the detector's
noise is isotropic, so no per-observation weighting is needed. The solver is ``bundle_adjust``'s
method: Levenberg-Marquardt on the Schur complement, the points eliminated; the reduced system
holds the free poses and the three lens variables, whose columns touch every observation (a
dense border of three rows and columns: 279 unknowns for a 47-photo survey). The Jacobian is
written out, so each iteration is one exact linear solve; SciPy's ``least_squares`` on the full
sparse Jacobian (LSMR, inexact) stalled on the focal-height ridge (docs/decisions.md).

The lens variables are the focal length's ratio to the nominal one and k1, k2 in the nominal
camera's normalised coordinates: the distortion, in pixels, then stays put when the focal length
changes, and k1, k2 do not bend along the long valley of focal length against height (a nadir
survey's weak direction, see ``evp.vo.survey_adjustment``). The solver still slides along that
valley in short steps, so each accepted step is stretched while the cost keeps falling (Toledo:
40 iterations instead of 61).

The principal point stays where it is given: over nadir photos of nearly flat ground a shift of it
is a tilt of every camera (it moves all projections alike), so it is not observable; COLMAP keeps
it fixed by default for the same reason.

Robustness follows ``bundle_adjust``: a Huber round over all observations (mosaic poses can be
pixels off), then a plain round over those within the chi-square gate.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
import scipy.linalg
import scipy.sparse.linalg
from scipy.sparse import bsr_matrix

from evp.optim.bundle_adjustment import block_sums
from evp.optim.reprojection import CHI2_2DOF, HUBER_DELTA
from evp.optim.rotation import nearest_rotation
from evp.types import CameraModel

# Priors on the lens, around the nominal camera (focal ratio - 1, k1, k2): wide, so the photos
# decide; they keep the solver off the far end of the focal-height valley. A camera's EXIF focal
# length is its lens's nominal one (a few % off a calibrated value: 0.2 is 20 %); consumer drone
# lenses have |k1| up to ~0.3 at a 1200-px image (DJI FC350: about -0.1).
LENS_PRIOR_SIGMA = np.array([0.2, 0.25, 0.25])
LENS_BOUNDS = np.array([[-0.5, -1.0, -1.0], [1.0, 1.0, 1.0]])  # half to twice the nominal focal length; a step outside is refused
ITERATIONS = (10, 60)  # Levenberg-Marquardt iterations: the Huber round (the mosaic's errors), the inlier round (along the valley: Toledo 29)
MAX_STRETCH = 64.0  # the longest multiple of a step tried along the valley
MIN_REDUCTION = 1e-6  # an iteration that lowers the cost by less than this share ends the round


@dataclass
class _State:
    R: np.ndarray  # (P, 3, 3) world-to-camera rotations
    t: np.ndarray  # (P, 3)
    points: np.ndarray  # (M, 3)
    lens: np.ndarray  # (3,) focal ratio - 1, k1 and k2 in the nominal camera's normalised coordinates


@dataclass
class SelfCalibrationProblem:
    """Observations (photo index, point index, detected pixel) of ground points; photos flagged in
    ``fixed`` hold the gauge. ``camera`` is the nominal lens (focal length and principal point,
    no distortion) the lens variables start from and are held near."""

    poses: np.ndarray  # (P, 4, 4) T_cw
    points: np.ndarray  # (M, 3)
    pose_index: np.ndarray  # (N,)
    point_index: np.ndarray  # (N,)
    pixels: np.ndarray  # (N, 2) as detected (distorted)
    fixed: np.ndarray  # (P,) bool
    camera: CameraModel


def _project(problem: SelfCalibrationProblem, state: _State, active: np.ndarray):
    """Camera-frame points, pinhole coordinates, the nominal camera's coordinates q of the ray at the
    adjusted focal length, its radial factor and errors (n, 2) in detected pixels."""
    i, j = problem.pose_index[active], problem.point_index[active]
    pc = np.einsum("nij,nj->ni", state.R[i], state.points[j]) + state.t[i]
    z = np.where(np.abs(pc[:, 2]) < 1e-9, 1e-9, pc[:, 2])
    xy = pc[:, :2] / z[:, None]
    q = (1.0 + state.lens[0]) * xy
    rho2 = np.sum(q * q, axis=1)
    radial = 1.0 + state.lens[1] * rho2 + state.lens[2] * rho2 * rho2
    errors = _nominal_focal(problem) * radial[:, None] * q + [problem.camera.cx, problem.camera.cy] - problem.pixels[active]
    return pc, z, xy, q, rho2, radial, errors


def _nominal_focal(problem: SelfCalibrationProblem) -> np.ndarray:
    return np.array([problem.camera.fx, problem.camera.fy])


def _prior(lens: np.ndarray) -> np.ndarray:
    return lens / LENS_PRIOR_SIGMA


def _cost(errors: np.ndarray, lens: np.ndarray, robust: bool) -> float:
    e2 = np.sum(errors * errors, axis=1)
    if robust:
        e = np.sqrt(e2)
        e2 = np.where(e <= HUBER_DELTA, e2, 2.0 * HUBER_DELTA * e - HUBER_DELTA**2)
    return float(np.sum(e2) + np.sum(_prior(lens) ** 2))


class _Linearisation:
    """The normal equations at one estimate, in blocks: free poses (6x6 each), the lens (3x3) and
    their coupling, the points' 3x3 blocks, and the pose-point (6x3) and lens-point (3x3)
    couplings; Huber weights as iteratively reweighted least squares."""

    def __init__(self, problem: SelfCalibrationProblem, active: np.ndarray, slot: np.ndarray, state: _State, robust: bool):
        pc, z, xy, q, rho2, radial, errors = _project(problem, state, active)
        self.cost = _cost(errors, state.lens, robust)
        e = np.linalg.norm(errors, axis=1)
        root_weight = np.sqrt(np.where(robust & (e > HUBER_DELTA), HUBER_DELTA / np.maximum(e, 1e-12), 1.0))
        r = errors * root_weight[:, None]
        focal = _nominal_focal(problem)[None, :, None] * root_weight[:, None, None]
        g = 2.0 * (state.lens[1] + 2.0 * state.lens[2] * rho2)
        qx, qy = q[:, 0], q[:, 1]
        a = np.stack([np.stack([radial + g * qx * qx, g * qx * qy], 1), np.stack([g * qx * qy, radial + g * qy * qy], 1)], 1) * focal  # d error / d q
        d_lens = np.stack([np.einsum("nij,nj->ni", a, xy), *(focal[:, :, 0] * (q * (rho2**k)[:, None]) for k in (1, 2))], axis=2)
        a *= ((1.0 + state.lens[0]) / z)[:, None, None]  # d q / d xy, and d xy / d pc's 1/z
        d_pc = np.concatenate([a, -np.einsum("nij,nj->ni", a, xy)[:, :, None]], axis=2)  # (n, 2, 3)
        i, j = problem.pose_index[active], problem.point_index[active]
        d_point = d_pc @ state.R[i]
        d_pose = np.concatenate([np.cross(pc[:, None, :], d_pc), d_pc], axis=2)  # left increments (rotation vector, translation)
        rows = np.concatenate([d_pose, d_lens, d_point], axis=2)  # (n, 2, 12): pose, lens, point columns
        gram, grad = np.swapaxes(rows, 1, 2) @ rows, (np.swapaxes(rows, 1, 2) @ r[:, :, None])[:, :, 0]
        n_points, n_free = len(state.points), int(slot.max()) + 1 if len(slot) else 0
        self.V = block_sums(j, gram[:, 9:, 9:], n_points)
        self.g_point = block_sums(j, grad[:, 9:], n_points)
        self.W_lens = block_sums(j, gram[:, 6:9, 9:], n_points)  # (M, 3 lens, 3 point)
        self.U_lens = gram[:, 6:9, 6:9].sum(axis=0) + np.diag(1.0 / LENS_PRIOR_SIGMA**2)
        self.g_lens = grad[:, 6:9].sum(axis=0) + _prior(state.lens) / LENS_PRIOR_SIGMA
        free = slot[i] >= 0
        s, j, gram, grad = slot[i][free], j[free], gram[free], grad[free]
        self.U_pose = block_sums(s, gram[:, :6, :6], n_free)
        self.U_pose_lens = block_sums(s, gram[:, :6, 6:9], n_free).reshape(-1, 3)
        self.g_pose = block_sums(s, grad[:, :6], n_free).ravel()
        order = np.argsort(s, kind="stable")  # each photo sees a point once: one 6x3 block per observation
        self.W_pose = bsr_matrix((gram[order, :6, 9:], j[order], np.searchsorted(s[order], np.arange(n_free + 1))), shape=(6 * n_free, 3 * n_points))

    def step(self, damping: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Camera increments (free poses' six, then the lens's three) and point increments (M, 3)
        for one Levenberg-Marquardt damping, or None when the reduced system is singular."""
        n_points = len(self.V)
        V_inv = np.linalg.inv(self.V + (damping * np.einsum("nii->ni", self.V) + 1e-9)[:, :, None] * np.eye(3))
        WV_pose = self.W_pose @ bsr_matrix((V_inv, np.arange(n_points), np.arange(n_points + 1)), shape=(3 * n_points, 3 * n_points))
        WV_lens = self.W_lens @ V_inv  # (M, 3, 3)
        U = scipy.linalg.block_diag(*self.U_pose, self.U_lens)
        U[:-3, -3:] = self.U_pose_lens
        U[-3:, :-3] = self.U_pose_lens.T
        coupling = self.W_pose @ WV_lens.transpose(0, 2, 1).reshape(-1, 3)  # pose-lens part of W V^-1 W^T
        S = U + np.diag(damping * np.diag(U) + 1e-9)
        S[:-3, :-3] -= (WV_pose @ self.W_pose.T).toarray()
        S[:-3, -3:] -= coupling
        S[-3:, :-3] -= coupling.T
        S[-3:, -3:] -= np.einsum("mij,mkj->ik", WV_lens, self.W_lens)
        g_point = self.g_point.ravel()
        rhs = np.concatenate([WV_pose @ g_point - self.g_pose, np.einsum("mij,mj->i", WV_lens, self.g_point) - self.g_lens])
        try:  # SuperLU: LAPACK's threaded Cholesky of this size is slowed ~100x by contention on a busy machine
            d_cam = scipy.sparse.linalg.splu(scipy.sparse.csc_matrix(S)).solve(rhs)
        except RuntimeError:  # exactly singular
            return None
        if not np.all(np.isfinite(d_cam)):
            return None
        back = -g_point - self.W_pose.T @ d_cam[:-3] - np.einsum("mij,i->mj", self.W_lens, d_cam[-3:]).ravel()
        return d_cam, (V_inv @ back.reshape(-1, 3, 1))[:, :, 0]


def _moved(state: _State, free: np.ndarray, d_cam: np.ndarray, d_point: np.ndarray) -> _State:
    R, t = state.R.copy(), state.t.copy()
    for k, increment in zip(free, d_cam[:-3].reshape(-1, 6), strict=True):
        dR = cv2.Rodrigues(increment[:3].reshape(3, 1))[0]
        R[k] = dR @ R[k]
        t[k] = dR @ t[k] + increment[3:]
    return _State(R, t, state.points + d_point, state.lens + d_cam[-3:])


def _trial_cost(problem: SelfCalibrationProblem, active: np.ndarray, trial: _State, robust: bool) -> float:
    inside = np.all((LENS_BOUNDS[0] <= trial.lens) & (trial.lens <= LENS_BOUNDS[1]))
    return _cost(_project(problem, trial, active)[-1], trial.lens, robust) if inside else np.inf


def _longest(problem: SelfCalibrationProblem, active: np.ndarray, state: _State, free: np.ndarray, step, robust: bool) -> _State:
    """The step, or the longest of it doubled while the cost keeps falling: the focal length slides
    along a long, nearly flat valley (focal length against height), where each linearised step
    sees only a short way ahead."""
    best, cost, factor = _moved(state, free, *step), _trial_cost(problem, active, _moved(state, free, *step), robust), 2.0
    while factor <= MAX_STRETCH:
        longer = _moved(state, free, factor * step[0], factor * step[1])
        longer_cost = _trial_cost(problem, active, longer, robust)
        if longer_cost >= cost:
            break
        best, cost, factor = longer, longer_cost, 2.0 * factor
    return best


def _round(problem: SelfCalibrationProblem, active: np.ndarray, state: _State, iterations: int, robust: bool) -> _State:
    """Levenberg-Marquardt over one set of observations (the damping as ``bundle_adjust``'s)."""
    free = np.flatnonzero(~problem.fixed)
    slot = np.full(len(problem.poses), -1)
    slot[free] = np.arange(len(free))
    damping = 1e-4
    current = _Linearisation(problem, active, slot, state, robust)
    for _ in range(iterations):
        accepted = None
        while accepted is None and damping < 1e8:
            step = current.step(damping)
            if step is not None and _trial_cost(problem, active, _moved(state, free, *step), robust) < current.cost:
                accepted = _longest(problem, active, state, free, step, robust)
                damping = max(damping / 3.0, 1e-9)
                break
            damping *= 4.0
        if accepted is None:
            break
        previous, state = current.cost, accepted
        current = _Linearisation(problem, active, slot, state, robust)
        if previous - current.cost < MIN_REDUCTION * previous:
            break
    return state


def self_calibrating_adjust(problem: SelfCalibrationProblem) -> tuple[np.ndarray, CameraModel, np.ndarray]:
    """Adjusted poses (P, 4, 4) ``T_cw``, the camera with the lens found (focal lengths scaled,
    k1, k2 in its own normalised coordinates) and each observation's squared reprojection error
    in detected pixels."""
    state = _State(problem.poses[:, :3, :3].copy(), problem.poses[:, :3, 3].copy(), problem.points.copy(), np.zeros(3))
    everything = np.ones(len(problem.pixels), dtype=bool)
    state = _round(problem, everything, state, ITERATIONS[0], robust=True)
    chi2 = np.sum(_project(problem, state, everything)[-1] ** 2, axis=1)
    state = _round(problem, chi2 < CHI2_2DOF, state, ITERATIONS[1], robust=False)
    chi2 = np.sum(_project(problem, state, everything)[-1] ** 2, axis=1)
    poses = np.repeat(np.eye(4)[None], len(state.R), axis=0)
    poses[:, :3, :3] = [nearest_rotation(r) for r in state.R]
    poses[:, :3, 3] = state.t
    scale = 1.0 + float(state.lens[0])
    camera = problem.camera
    lens = replace(camera, fx=camera.fx * scale, fy=camera.fy * scale, k1=float(state.lens[1]) * scale**2, k2=float(state.lens[2]) * scale**4)
    return poses, lens, chi2
