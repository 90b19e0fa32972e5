"""A wheel robot among known points, without images: exact bearings of the points in a forward
camera's view and exact wheel inputs, for the EKF-SLAM's tests and seed 001's convergence study
(its features were picked by hand, so the filter saw exact identities)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evp.ekf_slam.filter import yaw_rotation
from evp.fusion.planar_motion import dead_reckoning

FORWARD_CAMERA = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # R_body_cam: looking forward, image x to the right
CAMERA_OFFSET = np.array([0.05, 0.0, 0.2])  # the rendered robot's: 5 cm ahead of the axle, 20 cm up
WHEEL_RATE_HZ = 50.0
HALF_FIELD = 0.6  # |x/z| and |y/z| in view: a 62-degree field of view, a phone's


@dataclass(frozen=True)
class LandmarkDrive:
    """Wheel samples ``times``, ``speeds``, ``yaw_rates`` (exact), the true poses they drive
    (N, 3) from the origin, and the world ``points`` (P, 3)."""

    times: np.ndarray
    speeds: np.ndarray
    yaw_rates: np.ndarray
    poses: np.ndarray
    points: np.ndarray

    def bearings(self, sample: int) -> dict[int, np.ndarray]:
        """Normalised coordinates of the points in view at ``sample``, by point index."""
        pose = self.poses[sample]
        Rz = yaw_rotation(pose[2])
        centre = np.array([pose[0], pose[1], 0.0]) + Rz @ CAMERA_OFFSET
        in_camera = (self.points - centre) @ (Rz @ FORWARD_CAMERA)
        depth = np.maximum(in_camera[:, 2], 1e-9)
        z = in_camera[:, :2] / depth[:, None]
        seen = (in_camera[:, 2] > 0.2) & np.all(np.abs(z) < HALF_FIELD, axis=1)
        return {int(i): z[i] for i in np.flatnonzero(seen)}


def drive(speeds: np.ndarray, yaw_rates: np.ndarray, points: np.ndarray) -> LandmarkDrive:
    times = np.arange(len(speeds)) / WHEEL_RATE_HZ
    return LandmarkDrive(times, speeds, yaw_rates, dead_reckoning((0.0, 0.0, 0.0), times, speeds, yaw_rates), points)


def ring_loop(turns: float = 2.0, points: int = 24) -> LandmarkDrive:
    """Round a 1 m circle at 0.3 m/s inside a ring of points 3 m from its centre (at three
    heights): the camera sweeps the ring, so each lap sees the first lap's points again."""
    angles = np.linspace(0, 2 * np.pi, points, endpoint=False)
    ring = np.column_stack([3.0 * np.cos(angles), 3.0 * np.sin(angles) + 1.0, np.resize([0.1, 0.6, 1.1], points)])
    n = int(turns * 2 * np.pi / 0.3 * WHEEL_RATE_HZ)
    return drive(np.full(n, 0.3), np.full(n, 0.3), ring)
