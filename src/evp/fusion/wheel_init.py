"""Gravity and the visual map's metric scale from wheel odometry: the start of the navigation
filter for a ground vehicle that has not accelerated enough for the visual-inertial
initialisation (a robot driving at constant speed never will).

Between two keyframes the wheels say how far the body went (forward speed integrated along the
body's heading, the heading interpolated between the keyframes' visual rotations), in metres and
in map axes; the visual poses say how far in map units. The scale is the least-squares ratio of
the two, the camera's lever arm taken into account: ``s (c_j - c_i) = d_ij + (R_j - R_i) t_bc``
(``c`` the camera centre in the map, ``R`` the body's rotation in the map, ``d`` the wheel
displacement, ``t_bc`` the camera in the body). The visual steps are regressed on the wheels'
(``1/s`` fitted, not ``s``): over the first metres a keyframe step is a few centimetres, the
visual poses' noise a large share of it and the wheels' small, and noise in the regressor biases
a least-squares ratio towards zero (the rendered robot's seed 2 started 8x too small). Gravity
is the mean specific force over the window turned into map axes: a ground vehicle's
accelerations average out far below gravity (the bias of the mean is the accelerometer bias,
~0.05 m/s^2: 0.3 degree of tilt).

The vehicle frame is the IMU's (x forward, z up), the convention of
:class:`~evp.fusion.measurements.WheelSpeed` with its default ``R_body_vehicle``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from evp.config import NavigationSettings
from evp.fusion.nav_state import so3_exp, so3_log
from evp.fusion.preintegration import imu_arrays, imu_spans
from evp.fusion.visual_inertial_init import InertialAlignment
from evp.types import ImuSample, WheelOdometry

FORWARD = np.array([1.0, 0.0, 0.0])  # the vehicle's forward axis in the IMU frame


def _body_rotation(keyframes: Sequence[tuple[float, np.ndarray]], R_body_cam: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, 3, 3) the body's rotation in the map at times ``t``, interpolated on SO(3) between the
    keyframes around each (held at the ends)."""
    times = np.array([k[0] for k in keyframes])
    rotations = [T[:3, :3] @ R_body_cam.T for _, T in keyframes]
    out = np.empty((len(t), 3, 3))
    for n, ti in enumerate(t):
        i = int(np.clip(np.searchsorted(times, ti, side="right") - 1, 0, len(times) - 2))
        alpha = float(np.clip((ti - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0))
        out[n] = rotations[i] @ so3_exp(alpha * so3_log(rotations[i].T @ rotations[i + 1]))
    return out


def _forward_speed(wheel: Sequence[WheelOdometry]) -> tuple[np.ndarray, np.ndarray]:
    """The wheel stamps and forward speeds (the mean of the wheels where the record gives none)."""
    times = np.array([w.timestamp for w in wheel], float)
    speeds = np.array([w.forward_speed_m_s if np.isfinite(w.forward_speed_m_s) else np.mean(w.wheel_speeds_m_s) for w in wheel], float)
    good = np.isfinite(times) & np.isfinite(speeds)
    return times[good], speeds[good]


def initialise_from_wheels(
    keyframes: Sequence[tuple[float, np.ndarray]],
    wheel: Sequence[WheelOdometry],
    imu: Sequence[ImuSample],
    T_body_cam: np.ndarray,
    settings: NavigationSettings | None = None,
) -> InertialAlignment:
    """Scale, gravity and the body velocities at the ``keyframes`` (time, ``T_map_cam``, in time
    order) from the ``wheel`` records and ``imu`` samples spanning them; not observable (with the
    reason) while the wheels cover too little distance or the samples do not span the window.
    The gyro bias is left at zero (the filter's yaw-rate and visual updates estimate it)."""
    s = settings or NavigationSettings()
    if len(keyframes) < 2:
        return InertialAlignment(False, f"too few keyframes for the wheel odometry: {len(keyframes)} < 2")
    t0, t1 = keyframes[0][0], keyframes[-1][0]
    wheel_t, speed = _forward_speed(wheel)
    if len(wheel_t) < 2 or wheel_t[0] > t0 or wheel_t[-1] < t1:
        return InertialAlignment(False, "the wheel records do not span the keyframes")
    imu_t, _, force = imu_arrays(imu)
    if not imu_spans(imu_t, t0, t1):
        return InertialAlignment(False, "the IMU samples do not span the keyframes")
    R_bc, t_bc = T_body_cam[:3, :3], T_body_cam[:3, 3]

    # the wheel path in map axes, metres, at the wheel stamps inside the window (trapezoids)
    inside = (wheel_t >= t0) & (wheel_t <= t1)
    t = np.concatenate([[t0], wheel_t[inside], [t1]])
    v = np.interp(t, wheel_t, speed)
    heading = _body_rotation(keyframes, R_bc, t) @ FORWARD
    step = 0.5 * (v[1:, None] * heading[1:] + v[:-1, None] * heading[:-1]) * np.diff(t)[:, None]
    path = np.concatenate([np.zeros((1, 3)), np.cumsum(step, axis=0)])
    distance = float(np.sum(np.linalg.norm(step, axis=1)))
    if distance < s.wheel_init_min_distance_m:
        return InertialAlignment(False, f"the wheels moved {distance:.2f} m < {s.wheel_init_min_distance_m} m")

    key_t = np.array([k[0] for k in keyframes])
    wheel_position = np.column_stack([np.interp(key_t, t, path[:, axis]) for axis in range(3)])
    centres = np.array([T[:3, 3] for _, T in keyframes])
    R_map_body = np.array([T[:3, :3] @ R_bc.T for _, T in keyframes])
    visual = np.diff(centres, axis=0)
    metric = np.diff(wheel_position, axis=0) + np.diff(R_map_body @ t_bc, axis=0)
    denominator = float(np.sum(visual * metric))
    scale = float(np.sum(metric * metric) / denominator) if denominator > 0 else float("nan")
    if not np.isfinite(scale) or scale <= 0:
        return InertialAlignment(False, "the visual poses did not move while the wheels did")

    window = (imu_t >= t0) & (imu_t <= t1)
    up = np.mean(_body_rotation(keyframes, R_bc, imu_t[window]) @ force[window][:, :, None], axis=0)[:, 0]
    gravity_map = -s.gravity_m_s2 * up / np.linalg.norm(up)
    velocities = np.interp(key_t, wheel_t, speed)[:, None] * (R_map_body @ FORWARD)
    return InertialAlignment(True, "", scale, gravity_map, velocities, np.zeros(3))
