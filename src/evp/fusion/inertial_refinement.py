"""Inertial-only maximum-likelihood refinement of a visual-inertial initialisation: the scale,
gravity, the keyframe velocities and the accelerometer bias, with the visual poses fixed
(ORB-SLAM3's inertial-only optimisation, Campos et al. 2020, "Inertial-only optimization for
visual-inertial initialization"), seeded by VINS-Mono's linear alignment
(:func:`~evp.fusion.visual_inertial_init.initialise_visual_inertial`).

Why: on a walker's circle (centripetal 0.11 m/s^2, always along the body's y axis) an
accelerometer bias along y reads as a different scale; the linear alignment, which neglects the
bias and weighs every row alike, returns +24 % on the truth's poses. Here:

- the accelerometer bias is an unknown per keyframe interval, with the IMU model's prior and its
  random walk between intervals (a constant bias over 30 s put the truth's poses +9 % off: the
  simulator's 3e-3 m/s^3/sqrt(Hz) walk moves it 0.016 m/s^2, 15 % of the centripetal);
- each interval's preintegrated velocity and position change is weighted by its covariance;
- the keyframe positions' errors are unknowns too, with their prior
  (``vi_refine_position_sigma_m``): the scale multiplies the observed positions, so noise there
  is errors in variables, and leaving it in the residuals' covariance only biased the scale by
  -8 % (the truth's poses plus 7 mm white noise) where this is within 1-2 %;
- the body attitudes are the gyro's chain fitted to all the visual attitudes at once
  (:func:`gyro_attitudes`): SLAM's attitudes scatter ~0.4 degree frame to frame, which leaks
  0.07 m/s^2 of gravity into every interval.

The gyro bias is the alignment's corrected by that fit; for it the preintegrated changes are
exactly linear in the accelerometer bias, and the likelihood is linear in the velocities and the
biases, bilinear in the scale and the position errors, non-linear in gravity's direction:
Gauss-Newton on gravity's tangent plane. Pure: arrays in, an
:class:`~evp.fusion.visual_inertial_init.InertialAlignment` out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from evp.config import NavigationSettings
from evp.fusion.nav_state import so3_exp, so3_log
from evp.fusion.preintegration import Preintegrated, imu_arrays, preintegrate, samples_between
from evp.fusion.visual_inertial_init import InertialAlignment
from evp.types import ImuSample

GAUSS_NEWTON_ITERATIONS = 8  # from the linear alignment's scale (tens of % off) and gravity
ATTITUDE_ITERATIONS = 2  # the gyro bias fitted to the attitudes, then preintegrated again on it


def gyro_attitudes(R_visual: Sequence[np.ndarray], pre: Sequence[Preintegrated]) -> tuple[list[np.ndarray], np.ndarray]:
    """The keyframes' body attitudes as the gyro chains them (``pre``: consecutive
    preintegrations), anchored to and with the gyro-bias correction fitted to all the visual
    attitudes ``R_visual`` at once (Gauss-Newton on the rotation residuals, 6 unknowns); returns
    the chained attitudes at the corrected bias (to first order) and the correction."""
    chain, jacobian = [np.eye(3)], [np.zeros((3, 3))]
    for p in pre:
        chain.append(chain[-1] @ p.dR)
        jacobian.append(p.dR.T @ jacobian[-1] + p.dR_dbg)
    R0, bias = R_visual[0].copy(), np.zeros(3)
    for _ in range(3):
        JtJ, Jte = np.zeros((6, 6)), np.zeros(6)
        for R, C, J in zip(R_visual, chain, jacobian, strict=True):
            predicted = R0 @ C @ so3_exp(J @ bias)
            error = so3_log(predicted.T @ R)
            Jk = np.hstack([predicted.T @ R0, J])  # left perturbation of R0 seen in the body; the bias's right Jacobian
            JtJ += Jk.T @ Jk
            Jte += Jk.T @ error
        step = np.linalg.solve(JtJ, Jte)
        R0 = R0 @ so3_exp(step[:3])
        bias = bias + step[3:]
    return [R0 @ C @ so3_exp(J @ bias) for C, J in zip(chain, jacobian, strict=True)], bias


def white_position_noise(times: np.ndarray, positions: np.ndarray) -> np.ndarray | None:
    """The white noise of a track's positions (1 sigma per axis, the positions' units)
    from their second differences over consecutive poses, which cancel the motion to within its
    acceleration times dt^2 (1e-4 m at 30 fps and 0.1 m/s^2): each is sqrt(1 + (1 + r)^2 + r^2)
    sigma for steps in the ratio r. Median absolute deviations: a turn's samples do not count.
    None for fewer than 8 poses or times not increasing."""
    t, p = np.asarray(times, float), np.asarray(positions, float)
    dt = np.diff(t)
    if len(t) < 8 or not np.all(dt > 0):
        return None
    r = (dt[1:] / dt[:-1])[:, None]
    second = (p[2:] - p[1:-1] - r * (p[1:-1] - p[:-2])) / np.sqrt(1.0 + (1.0 + r) ** 2 + r**2)
    mad = 1.4826 * np.median(np.abs(second - np.median(second, axis=0)), axis=0)
    return mad


def refine_inertial(
    keyframes: Sequence[tuple[float, np.ndarray]],
    imu: Sequence[ImuSample],
    T_body_cam: np.ndarray,
    start: InertialAlignment,
    settings: NavigationSettings | None = None,
    visual_position_sigma_m: float | None = None,
    position_sigma_map: np.ndarray | None = None,
) -> InertialAlignment:
    """``start`` (an observable alignment over the same ``keyframes`` and ``imu``) refined by
    maximum likelihood. The keyframe positions' noise is ``visual_position_sigma_m`` in metres
    (default ``vi_refine_position_sigma_m``: SLAM's refined poses on the rendered circle, drift
    between keyframes included), or ``position_sigma_map`` per axis in map units where that is
    larger (the white noise measured on the poses, :func:`white_position_noise`: a downward camera
    at 60 m scatters ~5 cm, which a 7 mm prior took for exact and started the filter 27 % off). The answer carries the accelerometer bias and the scale's
    1-sigma from the weighted system (relative)."""
    s = settings or NavigationSettings()
    sigma_visual = s.vi_refine_position_sigma_m if visual_position_sigma_m is None else visual_position_sigma_m
    n = len(keyframes)
    times, gyro, accel = imu_arrays(imu)
    R_bc, t_bc = T_body_cam[:3, :3], T_body_cam[:3, 3]
    R_visual = [T[:3, :3] @ R_bc.T for _, T in keyframes]
    centres = np.array([T[:3, 3] for _, T in keyframes])
    densities = (s.gyro_noise_density, s.accel_noise_density)
    readings = [samples_between(times, gyro, accel, keyframes[k][0], keyframes[k + 1][0]) for k in range(n - 1)]
    gyro_bias = start.gyro_bias
    for _ in range(ATTITUDE_ITERATIONS):  # the attitudes need no covariance
        pre = [preintegrate(*r, gyro_bias) for r in readings]
        _, correction = gyro_attitudes(R_visual, pre)
        gyro_bias = gyro_bias + correction
    pre = [preintegrate(*r, gyro_bias, densities) for r in readings]
    R_body, _ = gyro_attitudes(R_visual, pre)
    lever = np.array([R @ t_bc for R in R_body])

    # unknowns: v_0..v_{n-1} (3n), gravity (3), scale (1), the accelerometer bias over each interval (3(n-1)),
    # the keyframes' visual position errors (3n, map units); rows per interval: position, velocity; then the
    # bias's prior and its random walk between intervals, then the position errors' prior
    V, G, S, BA = slice(0, 3 * n), slice(3 * n, 3 * n + 3), 3 * n + 3, 3 * n + 4
    DC = slice(BA + 3 * (n - 1), BA + 3 * (n - 1) + 3 * n)
    rows, bias_rows = 6 * (n - 1), 3 * (n - 1)
    A = np.zeros((rows + bias_rows + 3 * n, DC.stop))
    b = np.zeros(len(A))
    whiten = np.zeros((rows, rows))  # block diagonal: each interval's (position, velocity) rows
    difference = np.zeros((rows, 3 * n))  # the position rows' change of camera position
    for k, p in enumerate(pre):
        position, velocity, bias = slice(6 * k, 6 * k + 3), slice(6 * k + 3, 6 * k + 6), slice(BA + 3 * k, BA + 3 * k + 3)
        difference[position, 3 * k : 3 * k + 3] = -np.eye(3)
        difference[position, 3 * k + 3 : 3 * k + 6] = np.eye(3)
        A[position, 3 * k : 3 * k + 3] = -p.dt * np.eye(3)
        A[position, G] = -0.5 * p.dt**2 * np.eye(3)
        A[position, bias] = -R_body[k] @ p.dp_dba
        b[position] = R_body[k] @ p.dp + lever[k + 1] - lever[k]
        A[velocity, 3 * k : 3 * k + 3] = -np.eye(3)
        A[velocity, 3 * k + 3 : 3 * k + 6] = np.eye(3)
        A[velocity, G] = -p.dt * np.eye(3)
        A[velocity, bias] = -R_body[k] @ p.dv_dba
        b[velocity] = R_body[k] @ p.dv
        rotate = np.kron(np.eye(2), R_body[k])  # the preintegration's (velocity, position) covariance into map axes
        covariance = rotate @ p.covariance[np.r_[6:9, 3:6]][:, np.r_[6:9, 3:6]] @ rotate.T
        whiten[6 * k : 6 * k + 6, 6 * k : 6 * k + 6] = np.linalg.inv(np.linalg.cholesky(covariance))
    A[:rows], b[:rows] = whiten @ A[:rows], whiten @ b[:rows]
    measured = b[:rows].copy()
    whitened_difference = whiten @ difference
    A[rows : rows + 3, BA : BA + 3] = np.eye(3) / s.initial_accel_bias_sigma  # the bias prior: zero, the IMU model's sigma
    for k in range(n - 2):  # the random walk from one interval's bias to the next, over the time between their middles
        walk = s.accel_bias_random_walk * np.sqrt(0.5 * (pre[k].dt + pre[k + 1].dt))
        row = slice(rows + 3 + 3 * k, rows + 6 + 3 * k)
        A[row, BA + 3 * k : BA + 3 * k + 3] = -np.eye(3) / walk
        A[row, BA + 3 * k + 3 : BA + 3 * k + 6] = np.eye(3) / walk

    # Gauss-Newton: scale times the corrected positions is bilinear, gravity's direction non-linear
    gravity, scale, errors = start.gravity_map.copy(), start.scale, np.zeros(3 * n)
    for _ in range(GAUSS_NEWTON_ITERATIONS):
        gravity = gravity / np.linalg.norm(gravity) * s.gravity_m_s2
        tangent = np.linalg.svd(gravity[None, :])[2][1:].T
        A[:rows, S] = whitened_difference @ (centres.ravel() + errors)
        A[:rows, DC] = scale * whitened_difference
        b[:rows] = measured + scale * whitened_difference @ errors
        sigma = np.full(3, sigma_visual / scale) if position_sigma_map is None else np.maximum(position_sigma_map, sigma_visual / scale)
        A[rows + bias_rows :, DC] = np.diag(np.tile(1.0 / sigma, n))
        A_t = scipy.sparse.csr_matrix(np.hstack([A[:, V], A[:, G] @ tangent, A[:, S:]]))
        # the normal equations: well conditioned once whitened; sparse (each interval touches its own
        # velocities, biases and positions): 60 keyframes solve in ~2 ms where a dense solve took 26
        normal = scipy.sparse.csc_matrix(A_t.T @ A_t)
        try:
            factor = scipy.sparse.linalg.splu(normal)
        except RuntimeError:  # SuperLU: "Factor is exactly singular"
            return replace(start, observable=False, reason="the inertial refinement's system is singular: the keyframes do not determine it")
        x = factor.solve(A_t.T @ (b - A[:, G] @ gravity))
        gravity = gravity + tangent @ x[3 * n : 3 * n + 2]
        scale, errors = float(x[3 * n + 2]), x[3 * n + 3 + bias_rows :]
        if not scale > 0:
            return replace(start, observable=False, reason=f"the inertial refinement found scale {scale:.3g}")
    gravity = gravity / np.linalg.norm(gravity) * s.gravity_m_s2
    unit = np.zeros(normal.shape[0])
    unit[3 * n + 2] = 1.0
    scale_variance = float(factor.solve(unit)[3 * n + 2])  # the scale's entry of the inverse normal matrix
    return replace(
        start,
        scale=scale,
        gravity_map=gravity,
        velocities_map=x[: 3 * n].reshape(n, 3),
        accel_bias=x[3 * n + 3 + bias_rows - 3 : 3 * n + 3 + bias_rows].copy(),  # over the last interval: the filter starts at the last keyframe
        scale_sigma=float(np.sqrt(max(scale_variance, 0.0))) / scale,
    )
