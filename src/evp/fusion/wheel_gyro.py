"""Planar odometry for a car whose wheels give the speed and whose gyro gives the turn rate: each
wheel sample gets the gyro's rate about the vertical, averaged over the sample's interval."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from evp.types import ImuSample, WheelOdometry


def up_axis(imu: list[ImuSample]) -> np.ndarray:
    """The vertical (up) unit vector in the IMU frame: the mean specific force. Driving adds
    accelerations along and across the road that average out far below gravity (1 m/s^2 over a
    minute tilts it by under 0.1 degree); the mount's tilt is what this captures."""
    force = np.array([s.linear_acceleration_m_s2 for s in imu]).mean(axis=0)
    return force / np.linalg.norm(force)


def with_gyro_yaw_rate(wheel: list[WheelOdometry], imu: list[ImuSample]) -> list[WheelOdometry]:
    """The wheel samples with ``yaw_rate_rad_s`` replaced by the gyro's rate about ``up_axis``
    (counter-clockwise seen from above), averaged over the interval since the previous wheel sample
    (the first: since the first IMU sample), as :class:`OdometryFilter` takes it. Samples outside
    the IMU's time span get NaN, which the filter skips with a warning."""
    times = np.array([s.timestamp for s in imu])
    rates = np.array([s.angular_velocity_rad_s for s in imu]) @ up_axis(imu)
    # the integral of the rate, so that a mean over any interval is a difference
    angle = np.concatenate([[0.0], np.cumsum(0.5 * (rates[1:] + rates[:-1]) * np.diff(times))])
    ends = np.array([w.timestamp for w in wheel], dtype=float)
    starts = np.concatenate([[times[0]], ends[:-1]])
    inside = (starts >= times[0]) & (ends <= times[-1]) & (ends > starts)
    means = np.full(len(wheel), np.nan)
    means[inside] = (np.interp(ends[inside], times, angle) - np.interp(starts[inside], times, angle)) / (ends[inside] - starts[inside])
    return [replace(w, timestamp=float(w.timestamp), yaw_rate_rad_s=float(m)) for w, m in zip(wheel, means)]
