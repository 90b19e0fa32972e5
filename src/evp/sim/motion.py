"""Smooth vehicle motion with exact derivatives: position, attitude, velocity, acceleration, body rates.

A motion is defined by dense samples of position and attitude (``R_world_body``, body frame
x forward, y left, z up; world ENU, z up) and interpolated with C2 splines, so the IMU can be
synthesised from exact derivatives of the same curve the camera poses come from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline

GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class MotionState:
    """Kinematics at N times (arrays lead with N)."""

    time: np.ndarray
    position: np.ndarray  # world, m
    rotation: Rotation  # R_world_body
    velocity: np.ndarray  # world, m/s
    acceleration: np.ndarray  # world, m/s^2
    body_rate: np.ndarray  # body frame, rad/s

    def poses(self) -> np.ndarray:
        """(N, 4, 4) T_world_body."""
        T = np.tile(np.eye(4), (len(self.time), 1, 1))
        T[:, :3, :3] = self.rotation.as_matrix()
        T[:, :3, 3] = self.position
        return T

    def specific_force_body(self) -> np.ndarray:
        """What an ideal accelerometer reads: R^T (a - g), with g = (0, 0, -9.81) in ENU."""
        return self.rotation.inv().apply(self.acceleration + np.array([0.0, 0.0, GRAVITY_M_S2]))


class SplineMotion:
    """Motion through sampled positions and attitudes, differentiable twice.

    ``ends``: "clamped" starts and stops at rest (a take-off, a landing); "natural" passes through
    the first and last samples at speed, without acceleration there (a car already driving).
    """

    def __init__(self, times: np.ndarray, positions: np.ndarray, rotations: Rotation, ends: str = "clamped"):
        if len(times) < 4 or np.any(np.diff(times) <= 0):
            raise ValueError("a motion needs at least 4 samples with increasing times")
        self.start = float(times[0])
        self.end = float(times[-1])
        self._position = CubicSpline(times, positions, axis=0, bc_type=ends)
        self._rotation = RotationSpline(times, rotations)

    @property
    def duration(self) -> float:
        return self.end - self.start

    def state(self, times: np.ndarray) -> MotionState:
        times = np.clip(np.atleast_1d(np.asarray(times, dtype=float)), self.start, self.end)
        return MotionState(
            time=times,
            position=self._position(times),
            rotation=self._rotation(times),
            velocity=self._position(times, 1),
            acceleration=self._position(times, 2),
            body_rate=self._rotation(times, 1),
        )


def multirotor_attitude(acceleration: np.ndarray, yaw: np.ndarray, max_tilt_rad: float = 0.6) -> Rotation:
    """Attitude of a multirotor whose thrust produces ``acceleration`` (world) with heading ``yaw``.

    Thrust points along body z, so body z is parallel to a + g; the tilt is limited, as a flight
    controller would.
    """
    thrust = acceleration + np.array([0.0, 0.0, GRAVITY_M_S2])
    z_axis = thrust / np.linalg.norm(thrust, axis=1, keepdims=True)
    tilt = np.arccos(np.clip(z_axis[:, 2], -1.0, 1.0))
    too_much = tilt > max_tilt_rad
    if np.any(too_much):
        horizontal = z_axis[too_much, :2] / np.maximum(np.linalg.norm(z_axis[too_much, :2], axis=1, keepdims=True), 1e-12)
        z_axis[too_much] = np.column_stack([horizontal * np.sin(max_tilt_rad), np.full(too_much.sum(), np.cos(max_tilt_rad))])
    heading = np.column_stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)])
    y_axis = np.cross(z_axis, heading)
    y_axis /= np.linalg.norm(y_axis, axis=1, keepdims=True)
    x_axis = np.cross(y_axis, z_axis)
    return Rotation.from_matrix(np.stack([x_axis, y_axis, z_axis], axis=2))


ROLL_PER_LATERAL_ACCEL = np.radians(0.4)  # rad per m/s^2: a car body leans out ~4 degrees per g
PITCH_PER_LONGITUDINAL_ACCEL = np.radians(0.15)  # rad per m/s^2: dives ~1.5 degrees per g of braking


def car_attitude(acceleration: np.ndarray, yaw: np.ndarray, road_shake: np.ndarray) -> Rotation:
    """Attitude of a car heading ``yaw`` on a level road: its body leans out of a turn and dives
    when braking (suspension), plus ``road_shake`` (N, 2) pitch and roll from the surface (rad);
    nothing like a multirotor's tilt."""
    forward = np.column_stack([np.cos(yaw), np.sin(yaw)])
    left = np.column_stack([-np.sin(yaw), np.cos(yaw)])
    longitudinal = np.einsum("ij,ij->i", acceleration[:, :2], forward)
    lateral = np.einsum("ij,ij->i", acceleration[:, :2], left)
    pitch = -PITCH_PER_LONGITUDINAL_ACCEL * longitudinal + road_shake[:, 0]  # positive pitch: nose down
    roll = ROLL_PER_LATERAL_ACCEL * lateral + road_shake[:, 1]  # positive roll: right side down (out of a left turn)
    return Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]))


def smooth_path(times: np.ndarray, waypoints_t: np.ndarray, waypoints: np.ndarray) -> np.ndarray:
    """Positions at ``times`` along a C2 spline through timed waypoints (zero velocity at the ends)."""
    return CubicSpline(waypoints_t, waypoints, axis=0, bc_type="clamped")(times)


def heading_from_velocity(velocity: np.ndarray, fallback: float = 0.0, min_speed: float = 0.3) -> np.ndarray:
    """Yaw following the horizontal velocity, held while the vehicle is (nearly) still, unwrapped."""
    yaw = np.empty(len(velocity))
    current = fallback
    for i, (vx, vy) in enumerate(velocity[:, :2]):
        if np.hypot(vx, vy) > min_speed:
            current = np.arctan2(vy, vx)
        yaw[i] = current
    return np.unwrap(yaw)
