"""Strapdown inertial navigation: one IMU step of the nominal state, and of its error state.

The world is gravity-aligned ENU (gravity ``(0, 0, -g)``); the accelerometer measures the specific
force ``f = R_world_body^T (a - gravity)`` (so ``+g`` up at rest). Between two samples the rates
are taken as linear in time: the rotation vector is the mean rate times ``dt`` plus the coning
term ``dt^2 / 12 (w0 x w1)`` (Bortz), velocity integrates the world acceleration by the trapezoid
and position by the exact double integral of a linear acceleration. The error-state transition is
the second-order series of the continuous model of Sola, "Quaternion kinematics for the
error-state Kalman filter" (2017), section 5.3 (local attitude error); the discrete process noise
comes from the continuous noise densities times ``dt``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from evp.fusion.nav_state import NavState, skew3, so3_exp
from evp.types import ImuSample

IMU_DIM = 15  # position, velocity, attitude, gyro bias, accelerometer bias: what the IMU step moves


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time IMU noise densities (Kalibr's convention, as in EuRoC's sensor.yaml)."""

    gyro_noise_density: float  # rad/s/sqrt(Hz)
    accel_noise_density: float  # m/s^2/sqrt(Hz)
    gyro_bias_random_walk: float  # rad/s^2/sqrt(Hz)
    accel_bias_random_walk: float  # m/s^3/sqrt(Hz)

    def variances_per_second(self) -> np.ndarray:
        """Diagonal of the discrete process noise of the 15 IMU error states per second of step
        (a step of ``dt`` adds ``dt`` times it: velocity random walk from the accelerometer's
        white noise, angle random walk from the gyro's, the biases' random walks)."""
        return np.repeat([0.0, self.accel_noise_density**2, self.gyro_noise_density**2, self.gyro_bias_random_walk**2, self.accel_bias_random_walk**2], 3)


def imu_vectors(sample: ImuSample) -> tuple[np.ndarray, np.ndarray]:
    """(angular velocity, specific force) as arrays."""
    return np.array(sample.angular_velocity_rad_s, float), np.array(sample.linear_acceleration_m_s2, float)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of two 3-vectors at a tenth of its overhead (it runs per IMU sample)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


_I3 = np.eye(3)
_I15 = np.eye(IMU_DIM)


def strapdown_step(state: NavState, previous: ImuSample, current: ImuSample, gravity: float) -> tuple[NavState, np.ndarray]:
    """The nominal state at ``current.timestamp`` from the state at ``previous.timestamp``, and the
    15x15 transition of the IMU part of the error state over the step, ``I + A dt + (A dt)^2 / 2``
    with the continuous model linearised at the step's start and mean rates:
    ``dp' = dv``, ``dv' = -R [a]x dtheta - R dba``, ``dtheta' = -[w]x dtheta - dbg``."""
    dt = current.timestamp - previous.timestamp
    w0, f0 = imu_vectors(previous)
    w1, f1 = imu_vectors(current)
    w0 -= state.gyro_bias
    w1 -= state.gyro_bias
    f0 -= state.accel_bias
    f1 -= state.accel_bias
    R0 = state.R_world_body
    R1 = R0 @ so3_exp(0.5 * (w0 + w1) * dt + (dt * dt / 12.0) * _cross(w0, w1))
    a0 = R0 @ f0
    a1 = R1 @ f1
    a0[2] -= gravity
    a1[2] -= gravity
    velocity = state.velocity + 0.5 * (a0 + a1) * dt
    position = state.position + state.velocity * dt + (dt * dt) * (a0 / 3.0 + a1 / 6.0)
    A = np.zeros((IMU_DIM, IMU_DIM))
    A[0:3, 3:6] = _I3
    A[3:6, 6:9] = -R0 @ skew3(0.5 * (f0 + f1))
    A[3:6, 12:15] = -R0
    A[6:9, 6:9] = -skew3(0.5 * (w0 + w1))
    A[6:9, 9:12] = -_I3
    A *= dt
    transition = _I15 + A + 0.5 * (A @ A)
    return replace(state, timestamp=current.timestamp, position=position, velocity=velocity, R_world_body=R1), transition
