"""The planar motion model of a wheeled vehicle, shared by every filter that drives a ground
vehicle from its wheels and gyro (the wheel odometry filter, the EKF-SLAM of seed 001, the
wheel dead reckoning of the benches).

Seed 001's state equation moves the robot ``V dt`` along the heading at the start of the step;
here the step goes along the heading at its middle (the exact chord of a constant-rate arc to
second order), which removes the first-order bias in turns at no cost.
"""

from __future__ import annotations

import math

import numpy as np


def unicycle_step(yaw: float, distance: float, turn: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The change ``(dx, dy, dyaw)`` after driving ``distance`` (m) while turning by ``turn`` (rad,
    counter-clockwise) from heading ``yaw``; its derivative with respect to ``yaw`` (3,) and with
    respect to ``(distance, turn)`` (3, 2)."""
    mid = yaw + 0.5 * turn
    c, s = math.cos(mid), math.sin(mid)
    change = np.array([distance * c, distance * s, turn])
    d_yaw = np.array([-distance * s, distance * c, 0.0])
    d_inputs = np.array([[c, -0.5 * distance * s], [s, 0.5 * distance * c], [0.0, 1.0]])
    return change, d_yaw, d_inputs


def dead_reckoning(start: tuple[float, float, float], times: np.ndarray, speeds: np.ndarray, yaw_rates: np.ndarray) -> np.ndarray:
    """(N, 3) poses ``x, y, yaw`` integrating samples that each hold the mean speed and yaw rate
    over the interval since the previous sample (the first sample marks the start)."""
    poses = np.zeros((len(times), 3))
    poses[0] = start
    for k in range(1, len(times)):
        dt = times[k] - times[k - 1]
        change, _, _ = unicycle_step(poses[k - 1, 2], speeds[k] * dt, yaw_rates[k] * dt)
        poses[k] = poses[k - 1] + change
    return poses
