"""IMU preintegration between two keyframes (Forster et al. 2017, "On-manifold preintegration
for real-time visual-inertial odometry"): the rotation, velocity and position change the IMU
measured in the body frame at the interval's start, without gravity and without the start
velocity, so that keyframe states can be solved for without integrating the IMU again.

The step is the one of :mod:`evp.fusion.strapdown` (mean rate, trapezoidal velocity, exact
double integral of a linear acceleration). For a fixed gyro bias the velocity and position
changes are exactly linear in the accelerometer bias (the rotations do not depend on it), so
their Jacobians with respect to it are exact; the gyro bias enters the rotation to first order.
With noise densities given, the covariance of the (rotation, velocity, position) change is
propagated too (Forster's discrete noise propagation, the right Jacobian taken as identity).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evp.fusion.nav_state import skew3, so3_exp


@dataclass(frozen=True)
class Preintegrated:
    dt: float
    dR: np.ndarray  # rotation from the body at the interval's start to its end
    dv: np.ndarray  # velocity change minus gravity's, in the start body frame
    dp: np.ndarray  # position change minus velocity's and gravity's, in the start body frame
    dR_dbg: np.ndarray  # right-perturbation Jacobian of dR with respect to the gyro bias
    dv_dba: np.ndarray  # exact Jacobian of dv with respect to the accelerometer bias
    dp_dba: np.ndarray  # exact Jacobian of dp with respect to the accelerometer bias
    covariance: np.ndarray | None = None  # (9, 9) of (rotation, velocity, position) change, when noise was given


def samples_between(times: np.ndarray, gyro: np.ndarray, accel: np.ndarray, t0: float, t1: float):
    """The IMU readings in [t0, t1], with readings interpolated linearly at t0 and t1."""
    inside = (times > t0) & (times < t1)
    ends = [np.interp(t, times, column) for t in (t0, t1) for column in (*gyro.T, *accel.T)]
    start, end = np.reshape(ends[:6], 6), np.reshape(ends[6:], 6)
    t = np.concatenate([[t0], times[inside], [t1]])
    w = np.vstack([start[:3], gyro[inside], end[:3]])
    f = np.vstack([start[3:], accel[inside], end[3:]])
    return t, w, f


def preintegrate(t: np.ndarray, w: np.ndarray, f: np.ndarray, gyro_bias: np.ndarray, noise_densities: tuple[float, float] | None = None) -> Preintegrated:
    """Preintegrate readings ``w`` (rad/s) and ``f`` (m/s^2) at times ``t`` on ``gyro_bias``;
    ``noise_densities`` (gyro rad/s/sqrt(Hz), accelerometer m/s^2/sqrt(Hz)) adds the covariance."""
    dR, dv, dp, J = np.eye(3), np.zeros(3), np.zeros(3), np.zeros((3, 3))
    dv_dba, dp_dba = np.zeros((3, 3)), np.zeros((3, 3))
    P = np.zeros((9, 9)) if noise_densities is not None else None
    for j in range(len(t) - 1):
        h = t[j + 1] - t[j]
        step = so3_exp((0.5 * (w[j] + w[j + 1]) - gyro_bias) * h)
        a0 = dR @ f[j]
        dR_next = dR @ step
        a1 = dR_next @ f[j + 1]
        if P is not None:
            P = _propagated(P, dR, step, 0.5 * (f[j] + f[j + 1]), h, noise_densities)
        dp = dp + dv * h + h * h * (a0 / 3.0 + a1 / 6.0)
        dp_dba = dp_dba + dv_dba * h - h * h * (dR / 3.0 + dR_next / 6.0)
        dv = dv + 0.5 * (a0 + a1) * h
        dv_dba = dv_dba - 0.5 * (dR + dR_next) * h
        J = step.T @ J - h * np.eye(3)  # small-step right Jacobian taken as identity
        dR = dR_next
    return Preintegrated(t[-1] - t[0], dR, dv, dp, J, dv_dba, dp_dba, P)


def _propagated(P: np.ndarray, dR: np.ndarray, step: np.ndarray, force: np.ndarray, h: float, densities: tuple[float, float]) -> np.ndarray:
    """One sample's step of the (rotation, velocity, position) covariance: white noise of
    variance density^2 / h per sample on each reading."""
    rotated_force = dR @ skew3(force)
    A = np.eye(9)
    A[0:3, 0:3] = step.T
    A[3:6, 0:3] = -rotated_force * h
    A[6:9, 0:3] = -0.5 * rotated_force * h * h
    A[6:9, 3:6] = np.eye(3) * h
    B = np.zeros((9, 6))
    B[0:3, 0:3] = np.eye(3) * h
    B[3:6, 3:6] = dR * h
    B[6:9, 3:6] = 0.5 * dR * h * h
    gyro_density, accel_density = densities
    Q = np.diag([gyro_density**2 / h] * 3 + [accel_density**2 / h] * 3)
    return A @ P @ A.T + B @ Q @ B.T
