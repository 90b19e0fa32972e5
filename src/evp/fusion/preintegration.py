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

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from evp.fusion.nav_state import so3_exp_many
from evp.geometry.transforms import skew
from evp.types import ImuSample


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


def imu_arrays(imu: Sequence[ImuSample]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples' times (N,), gyro rates (N, 3) and specific forces (N, 3) as arrays."""
    times = np.array([sample.timestamp for sample in imu], float)
    gyro = np.array([sample.angular_velocity_rad_s for sample in imu], float).reshape(-1, 3)
    accel = np.array([sample.linear_acceleration_m_s2 for sample in imu], float).reshape(-1, 3)
    return times, gyro, accel


def imu_spans(times: np.ndarray, t0: float, t1: float) -> bool:
    """Whether IMU samples at ``times`` cover [t0, t1], where an end may fall short of the nearest
    sample by up to one sample period: :func:`samples_between` then holds that sample's reading,
    as preintegration holds every reading over its interval. A 30 Hz camera and a 200 Hz IMU
    rarely share a timestamp, so the newest keyframe is usually a few ms after the newest sample;
    refusing it left a live 30 fps flight's visual-inertial start waiting (9 of its first 16
    attempts refused so, and the filter started after 135 s or never) where its 10 fps render,
    whose frames fall on IMU samples, started at once."""
    if len(times) < 2:
        return False
    period = float(np.median(np.diff(times)))
    return times[0] <= t0 + period and times[-1] >= t1 - period


def drop_before(records: list, t: float) -> None:
    """Drop the time-ordered ``records`` (anything with a ``timestamp``) older than ``t``, all but
    the newest of them: an interval starting at ``t`` interpolates from the one at or before it."""
    keep = next((i for i, record in enumerate(records) if record.timestamp >= t), len(records))
    del records[: max(0, keep - 1)]


def samples_between(times: np.ndarray, gyro: np.ndarray, accel: np.ndarray, t0: float, t1: float):
    """The IMU readings in [t0, t1], with readings interpolated linearly at t0 and t1 (the nearest
    reading held outside the samples)."""
    t, readings = readings_between(times, np.hstack([gyro, accel]), t0, t1)
    return t, readings[:, :3], readings[:, 3:]


def readings_between(times: np.ndarray, readings: np.ndarray, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
    """The times and rows of ``readings`` (N, k) in [t0, t1], rows interpolated linearly at t0 and
    t1 (the nearest row held outside the samples)."""
    inside = (times > t0) & (times < t1)
    ends = np.array([[np.interp(t, times, column) for column in readings.T] for t in (t0, t1)])
    return np.concatenate([[t0], times[inside], [t1]]), np.vstack([ends[0], readings[inside], ends[1]])


def rotation_chain(t: np.ndarray, w: np.ndarray, gyro_bias: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The body's rotation from ``t[0]`` to each reading's time (N, 3, 3), each step turned by the
    mean of its two rates less ``gyro_bias``, and the steps themselves (N-1, 3, 3)."""
    steps = so3_exp_many((0.5 * (w[:-1] + w[1:]) - gyro_bias) * np.diff(t)[:, None])
    R = np.empty((len(t), 3, 3))
    R[0] = np.eye(3)
    for j, step in enumerate(steps):
        R[j + 1] = R[j] @ step
    return R, steps


def preintegrate(t: np.ndarray, w: np.ndarray, f: np.ndarray, gyro_bias: np.ndarray, noise_densities: tuple[float, float] | None = None) -> Preintegrated:
    """Preintegrate readings ``w`` (rad/s) and ``f`` (m/s^2) at times ``t`` on ``gyro_bias``;
    ``noise_densities`` (gyro rad/s/sqrt(Hz), accelerometer m/s^2/sqrt(Hz)) adds the covariance.

    Only the rotation chain is a loop (one 3x3 product a sample); the sums are arrays: the
    visual-inertial start preintegrates every interval of up to 60 keyframes per attempt, and the
    loop of small NumPy calls per sample took two thirds of its time."""
    h = np.diff(t)
    R, steps = rotation_chain(t, w, gyro_bias)  # dR at each reading
    a = np.einsum("nij,nj->ni", R, f)  # each reading's force in the start frame
    hv, hm = h[:, None], h[:, None, None]
    dv_steps = 0.5 * (a[:-1] + a[1:]) * hv
    dv_before = np.cumsum(dv_steps, axis=0) - dv_steps  # dv at each step's start
    dp = np.sum(dv_before * hv + hv * hv * (a[:-1] / 3.0 + a[1:] / 6.0), axis=0)
    dv_dba_steps = -0.5 * (R[:-1] + R[1:]) * hm
    dv_dba_before = np.cumsum(dv_dba_steps, axis=0) - dv_dba_steps
    dp_dba = np.sum(dv_dba_before * hm - hm * hm * (R[:-1] / 3.0 + R[1:] / 6.0), axis=0)
    # J' = step^T J - h I from J = 0, summed: -dR^T sum_j h_j R_{j+1} (small-step right Jacobian taken as identity)
    J = -R[-1].T @ np.sum(R[1:] * hm, axis=0)
    P = None
    if noise_densities is not None:
        P = np.zeros((9, 9))
        for A, N in zip(*_noise_steps(R, steps, 0.5 * (f[:-1] + f[1:]), h, noise_densities), strict=True):
            P = A @ P @ A.T + N
    return Preintegrated(t[-1] - t[0], R[-1], dv_steps.sum(axis=0), dp, J, dv_dba_steps.sum(axis=0), dp_dba, P)


def _noise_steps(R: np.ndarray, steps: np.ndarray, force: np.ndarray, h: np.ndarray, densities: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Each sample's step of the (rotation, velocity, position) covariance, ``P' = A P A^T + N``,
    for all samples at once (``R``: dR at each reading; ``force``: each step's mean reading):
    white noise of variance density^2 / h per sample on each reading."""
    m = len(h)
    hm = h[:, None, None]
    rotated_force = R[:-1] @ skew(force)
    A = np.tile(np.eye(9), (m, 1, 1))
    A[:, 0:3, 0:3] = np.transpose(steps, (0, 2, 1))
    A[:, 3:6, 0:3] = -rotated_force * hm
    A[:, 6:9, 0:3] = -0.5 * rotated_force * hm * hm
    A[:, 6:9, 3:6] = np.eye(3) * hm
    B = np.zeros((m, 9, 6))
    B[:, 0:3, 0:3] = np.eye(3) * hm
    B[:, 3:6, 3:6] = R[:-1] * hm
    B[:, 6:9, 3:6] = 0.5 * R[:-1] * hm * hm
    gyro_density, accel_density = densities
    q = np.concatenate([np.full((m, 3), gyro_density**2), np.full((m, 3), accel_density**2)], axis=1) / h[:, None]
    return A, (B * q[:, None, :]) @ np.transpose(B, (0, 2, 1))
