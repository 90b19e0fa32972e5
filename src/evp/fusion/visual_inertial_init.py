"""Visual-inertial initialisation: gravity in the visual map, the map's metric scale, the body
velocities and the gyro bias, from a few seconds of keyframe poses (arbitrary frame and scale) and
the IMU samples between them.

The inertial-only step of VINS-Mono (Qin et al. 2018, section V) and ORB-SLAM3: first the gyro
bias from the keyframes' relative rotations against the preintegrated gyro (linear least
squares), then, with the IMU preintegrated again on that bias, one linear least-squares system in
the velocities, gravity (map axes, metric) and the scale, with gravity's magnitude then imposed
by re-solving on its 2-D tangent (VINS-Mono's RefineGravity). When the keyframes cannot determine
them (too few, the IMU does not cover them, too little acceleration: at constant velocity gravity
and scale cannot be told apart) the answer is a record saying why, never a scale.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from evp.config import NavigationSettings
from evp.fusion.nav_state import NavState, so3_exp, so3_log
from evp.fusion.preintegration import imu_arrays, imu_spans, preintegrate, samples_between
from evp.types import ImuSample

GRAVITY_REFINEMENTS = 4  # VINS-Mono iterates its tangent-plane refinement 4 times


@dataclass(frozen=True)
class InertialAlignment:
    """The initialisation's answer. ``observable`` False: ``reason`` says why and the numbers are
    not set. Otherwise ``scale`` is metres per map unit, ``gravity_map`` the gravity vector in
    map axes (m/s^2, magnitude the settings' gravity), ``velocities_map`` the body velocity at
    each keyframe (metric, map axes), ``gyro_bias`` rad/s."""

    observable: bool
    reason: str = ""
    scale: float = float("nan")
    gravity_map: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    velocities_map: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    gyro_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    acceleration_std_m_s2: float = float("nan")  # the excitation that was measured
    scale_sigma: float = float("nan")  # the scale's 1-sigma, as a share of it
    accel_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))  # m/s^2, body axes; zero unless refined

    @property
    def R_world_map(self) -> np.ndarray:
        """The map's rotation into a gravity-aligned world (gravity to -z); heading about z is
        left as the map's (the rotation is the smallest that levels the map)."""
        down = self.gravity_map / np.linalg.norm(self.gravity_map)
        axis = np.cross(down, [0.0, 0.0, -1.0])
        angle = np.arctan2(np.linalg.norm(axis), down @ [0.0, 0.0, -1.0])
        norm = np.linalg.norm(axis)
        return so3_exp(axis / norm * angle) if norm > 1e-12 else (np.eye(3) if angle < 1.0 else np.diag([1.0, -1.0, -1.0]))

    def nav_state(self, timestamp: float, T_map_cam: np.ndarray, T_body_cam: np.ndarray, velocity_map: np.ndarray) -> NavState:
        """A navigation filter's start at a keyframe: world origin at the map origin, world axes
        :attr:`R_world_map`, the map anchored with the estimated scale."""
        R_wm = self.R_world_map
        R_world_body = R_wm @ T_map_cam[:3, :3] @ T_body_cam[:3, :3].T
        position = self.scale * R_wm @ T_map_cam[:3, 3] - R_world_body @ T_body_cam[:3, 3]
        return NavState(
            timestamp,
            position,
            R_wm @ velocity_map,
            R_world_body,
            gyro_bias=self.gyro_bias.copy(),
            accel_bias=self.accel_bias.copy(),
            log_scale=float(np.log(self.scale)),
            R_world_map=R_wm,
            map_anchored=True,
        )


def initialise_visual_inertial(
    keyframes: Sequence[tuple[float, np.ndarray]], imu: Sequence[ImuSample], T_body_cam: np.ndarray, settings: NavigationSettings | None = None
) -> InertialAlignment:
    """Gravity, scale, velocities and gyro bias from ``keyframes`` ((timestamp, T_map_cam) in
    time order) and the ``imu`` samples spanning them (``T_body_cam``: the camera in the IMU
    frame). Accelerometer bias is not estimated (it is not separable from gravity in a few
    seconds; VINS-Mono neglects it too): the navigation filter takes it over."""
    s = settings or NavigationSettings()
    n = len(keyframes)
    if n < s.vi_init_min_keyframes:
        return InertialAlignment(False, f"too few keyframes: {n} < {s.vi_init_min_keyframes}")
    times, gyro, accel = imu_arrays(imu)
    if not imu_spans(times, keyframes[0][0], keyframes[-1][0]):
        return InertialAlignment(False, "the IMU samples do not span the keyframes")
    gaps = np.diff(times)
    if np.any(gaps <= 0) or gaps.max() > s.max_imu_gap_s:
        return InertialAlignment(False, f"the IMU samples are not in time order or have a gap over {s.max_imu_gap_s} s")
    R_bc, t_bc = T_body_cam[:3, :3], T_body_cam[:3, 3]
    stamps = [k[0] for k in keyframes]
    R_body = [T[:3, :3] @ R_bc.T for _, T in keyframes]  # R_map_body
    centres = np.array([T[:3, 3] for _, T in keyframes])  # camera positions, map units
    readings = [samples_between(times, gyro, accel, stamps[k], stamps[k + 1]) for k in range(n - 1)]

    gyro_bias = np.zeros(3)
    for _ in range(2):  # Gauss-Newton: the Jacobian is taken at the current bias
        pre = [preintegrate(*r, gyro_bias) for r in readings]
        JtJ, Jte = np.zeros((3, 3)), np.zeros(3)
        for k, p in enumerate(pre):
            error = so3_log(p.dR.T @ R_body[k].T @ R_body[k + 1])
            JtJ += p.dR_dbg.T @ p.dR_dbg
            Jte += p.dR_dbg.T @ error
        gyro_bias = gyro_bias + np.linalg.solve(JtJ, Jte)
    pre = [preintegrate(*r, gyro_bias) for r in readings]

    mean_force = np.array([R_body[k] @ p.dv / p.dt for k, p in enumerate(pre)])  # specific force, map axes
    excitation = float(np.sqrt(np.mean(np.sum((mean_force - mean_force.mean(axis=0)) ** 2, axis=1))))
    if excitation < s.vi_init_min_acceleration_std_m_s2:
        return InertialAlignment(
            False,
            f"too little acceleration: specific force varies by {excitation:.3f} m/s^2 < {s.vi_init_min_acceleration_std_m_s2} "
            "(at constant velocity gravity and scale cannot be told apart)",
            acceleration_std_m_s2=excitation,
        )

    lever = np.array([R @ t_bc for R in R_body])  # camera offset from the body, metric, map axes
    # unknowns: v_0..v_{n-1} (3n), gravity (3), scale (1); rows: position then velocity per interval
    A = np.zeros((6 * (n - 1), 3 * n + 4))
    b = np.zeros(6 * (n - 1))
    for k, p in enumerate(pre):
        rows = slice(6 * k, 6 * k + 3)
        A[rows, 3 * k : 3 * k + 3] = -p.dt * np.eye(3)
        A[rows, 3 * n : 3 * n + 3] = -0.5 * p.dt**2 * np.eye(3)
        A[rows, 3 * n + 3] = centres[k + 1] - centres[k]
        b[rows] = R_body[k] @ p.dp + lever[k + 1] - lever[k]
        rows = slice(6 * k + 3, 6 * k + 6)
        A[rows, 3 * k : 3 * k + 3] = -np.eye(3)
        A[rows, 3 * k + 3 : 3 * k + 6] = np.eye(3)
        A[rows, 3 * n : 3 * n + 3] = -p.dt * np.eye(3)
        b[rows] = R_body[k] @ p.dv
    solution = np.linalg.lstsq(A, b, rcond=None)[0]
    gravity, scale = solution[3 * n : 3 * n + 3], solution[3 * n + 3]
    magnitude = float(np.linalg.norm(gravity))
    if scale <= 0 or abs(magnitude - s.gravity_m_s2) > s.vi_init_max_gravity_error_m_s2:
        return InertialAlignment(
            False,
            f"inconsistent solution: gravity {magnitude:.2f} m/s^2 (expected {s.gravity_m_s2}), scale {scale:.3g}",
            acceleration_std_m_s2=excitation,
        )
    for _ in range(GRAVITY_REFINEMENTS):
        gravity = gravity / np.linalg.norm(gravity) * s.gravity_m_s2
        tangent = np.linalg.svd(gravity[None, :])[2][1:].T  # (3, 2): an orthonormal basis of gravity's tangent plane
        A_t = np.hstack([A[:, : 3 * n], A[:, 3 * n : 3 * n + 3] @ tangent, A[:, 3 * n + 3 :]])
        x = np.linalg.lstsq(A_t, b - A[:, 3 * n : 3 * n + 3] @ gravity, rcond=None)[0]
        gravity = gravity + tangent @ x[3 * n : 3 * n + 2]
        solution = x
        scale = x[3 * n + 2]
    gravity = gravity / np.linalg.norm(gravity) * s.gravity_m_s2
    if not scale > 0:  # gravity's magnitude imposed can turn it: its relative sigma would then pass any bound
        return InertialAlignment(False, f"inconsistent solution: scale {scale:.3g} once gravity's magnitude is imposed", acceleration_std_m_s2=excitation)
    noise_sigma = _scale_sigma(A_t, b - A[:, 3 * n : 3 * n + 3] @ gravity, solution)
    bias_sigma = _scale_sigma_from_bias(A_t, R_body, pre, s.vi_init_accel_bias_sigma)
    relative_sigma = float(np.hypot(noise_sigma, bias_sigma)) / scale
    if not relative_sigma <= s.vi_init_max_scale_sigma:
        return InertialAlignment(
            False,
            f"scale not yet determined: {scale:.3g} +- {100 * relative_sigma:.0f} % (> {100 * s.vi_init_max_scale_sigma:.0f} %): too little motion in the map for the IMU's",
            acceleration_std_m_s2=excitation,
        )
    return InertialAlignment(True, "", float(scale), gravity, solution[: 3 * n].reshape(n, 3), gyro_bias, excitation, float(relative_sigma))


def _scale_sigma_from_bias(A: np.ndarray, R_body: Sequence[np.ndarray], pre: Sequence, bias_sigma: float) -> float:
    """1-sigma of the scale that an accelerometer bias of ``bias_sigma`` per axis (constant, body
    axes), left out of the solve, brings into it: a consider analysis (Schmidt). The bias moves
    each interval's preintegrated position and velocity by their bias Jacobians; the solve maps
    that to a scale shift. While the motion is small (a standing start, a slow walk's first
    steps) a plausible bias explains as much of the IMU's displacements as the scale does, and
    the residual alone cannot tell: the rendered circle's standing sway gave +45 %, with a
    least-squares sigma under 10 %."""
    rows = []
    for k, p in enumerate(pre):
        rows.append(R_body[k] @ p.dp_dba)
        rows.append(R_body[k] @ p.dv_dba)
    shift = np.linalg.lstsq(A, np.vstack(rows), rcond=None)[0][-1]  # d scale / d bias, (3,)
    return float(bias_sigma * np.linalg.norm(shift))


def _scale_sigma(A: np.ndarray, b: np.ndarray, x: np.ndarray) -> float:
    """1-sigma of the last unknown (the scale) of the least-squares solution ``x`` of ``A x = b``,
    the rows' noise taken from the residual (unweighted: positions and velocities share one
    variance, enough to tell a scale the motion fixes from one it does not)."""
    dof = A.shape[0] - A.shape[1]
    if dof <= 0:
        return float("inf")
    residual = A @ x - b
    variance = float(residual @ residual) / dof
    try:
        covariance = variance * np.linalg.inv(A.T @ A)
    except np.linalg.LinAlgError:
        return float("inf")
    return float(np.sqrt(max(covariance[-1, -1], 0.0)))
