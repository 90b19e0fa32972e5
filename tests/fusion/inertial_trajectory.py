"""A smooth 3-D trajectory known in closed form, and the exact IMU readings, GPS fixes and visual
poses it gives: position a sum of sinusoids, attitude yaw-pitch-roll sinusoids (body rates from
the exact Euler-rate formula), the world ENU with gravity (0, 0, -g)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from evp.fusion.nav_state import NavState
from evp.types import ImuSample

GRAVITY = 9.80665


@dataclass(frozen=True)
class SinusoidTrajectory:
    """``position = cruise * t + amplitude * sin(frequency * t + phase)`` per axis; yaw, pitch and
    roll likewise (``yaw_rate * t`` plus a sinusoid)."""

    amplitude: tuple = (3.0, 2.0, 0.5)
    frequency: tuple = (0.5, 0.7, 0.9)
    phase: tuple = (0.0, 1.0, 2.0)
    cruise: tuple = (1.0, 0.5, 0.0)
    yaw_rate: float = 0.1
    euler_amplitude: tuple = (0.3, 0.2, 0.25)  # yaw, pitch, roll
    euler_frequency: tuple = (0.6, 0.8, 1.1)

    def _sin(self, t, amplitude, frequency, phase, order):
        t = np.asarray(t, float)[..., None]
        a, w, ph = np.asarray(amplitude), np.asarray(frequency), np.asarray(phase)
        x = w * t + ph
        return [a * np.sin(x), a * w * np.cos(x), -a * w * w * np.sin(x)][order]

    def position(self, t):
        return np.asarray(self.cruise) * np.asarray(t, float)[..., None] + self._sin(t, self.amplitude, self.frequency, self.phase, 0)

    def velocity(self, t):
        return np.asarray(self.cruise) + self._sin(t, self.amplitude, self.frequency, self.phase, 1)

    def acceleration(self, t):
        return self._sin(t, self.amplitude, self.frequency, self.phase, 2)

    def _euler(self, t, order):
        e = self._sin(t, self.euler_amplitude, self.euler_frequency, (0.0, 0.0, 0.0), order)
        if order == 0:
            e[..., 0] += self.yaw_rate * np.asarray(t, float)
        elif order == 1:
            e[..., 0] += self.yaw_rate
        return e

    def rotation(self, t) -> np.ndarray:
        """R_world_body (..., 3, 3) = Rz(yaw) Ry(pitch) Rx(roll)."""
        return Rotation.from_euler("ZYX", self._euler(t, 0)).as_matrix()

    def angular_velocity(self, t) -> np.ndarray:
        """Body rates of ZYX Euler angles: p = roll' - yaw' sin(pitch), q = pitch' cos(roll) +
        yaw' cos(pitch) sin(roll), r = -pitch' sin(roll) + yaw' cos(pitch) cos(roll)."""
        (_, pitch, roll), (dyaw, dpitch, droll) = np.moveaxis(self._euler(t, 0), -1, 0), np.moveaxis(self._euler(t, 1), -1, 0)
        return np.stack(
            [
                droll - dyaw * np.sin(pitch),
                dpitch * np.cos(roll) + dyaw * np.cos(pitch) * np.sin(roll),
                -dpitch * np.sin(roll) + dyaw * np.cos(pitch) * np.cos(roll),
            ],
            axis=-1,
        )

    def specific_force(self, t) -> np.ndarray:
        R = self.rotation(t)
        a = self.acceleration(t) + np.array([0.0, 0.0, GRAVITY])
        return np.einsum("...ji,...j->...i", R, a)

    def imu(self, times, gyro_bias=(0, 0, 0), accel_bias=(0, 0, 0), gyro_sigma=0.0, accel_sigma=0.0, seed=0) -> list[ImuSample]:
        """IMU samples at ``times``; ``*_sigma`` the per-sample white-noise sigma."""
        rng = np.random.default_rng(seed)
        w = self.angular_velocity(times) + np.asarray(gyro_bias) + gyro_sigma * rng.standard_normal((len(times), 3))
        f = self.specific_force(times) + np.asarray(accel_bias) + accel_sigma * rng.standard_normal((len(times), 3))
        return [ImuSample(float(t), tuple(wi), tuple(fi)) for t, wi, fi in zip(times, w, f, strict=True)]

    def state(self, t: float, **fields) -> NavState:
        """The true nominal state at ``t`` (biases and map states from ``fields``)."""
        return NavState(t, self.position(t), self.velocity(t), self.rotation(t), **fields)

    def pose(self, t) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.rotation(t), self.position(t)
        return T


def imu_times(duration_s: float, rate_hz: float = 200.0) -> np.ndarray:
    return np.arange(round(duration_s * rate_hz) + 1) / rate_hz
