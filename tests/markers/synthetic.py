"""Marker observations made from known poses, without images: for map and autopilot tests."""

import numpy as np
from scipy.spatial.transform import Rotation

from evp.markers.detection import MarkerObservation
from evp.markers.floor import UNIT_CORNERS
from evp.sim.scenarios import DOWNWARD

PITCH = 0.196
SIZE = 0.098


def grid_positions(cols: int = 5, rows: int = 5) -> dict[int, np.ndarray]:
    return {r * cols + c: np.array([c * PITCH, r * PITCH]) for r in range(rows) for c in range(cols)}


def observe(camera_xy, height: float, markers: dict[int, np.ndarray], yaw: float = np.pi / 2, reach: float = 0.3) -> list[MarkerObservation]:
    """The markers within ``reach`` of the camera, as a camera at ``height`` (body yaw ``yaw``) sees them."""
    R_world_cam = Rotation.from_euler("z", yaw - np.pi / 2).as_matrix() @ Rotation.from_euler("z", np.pi / 2).as_matrix() @ DOWNWARD
    centre = np.array([camera_xy[0], camera_xy[1], height])
    seen = []
    for marker_id, xy in markers.items():
        if np.linalg.norm(np.asarray(xy) - camera_xy) > reach:
            continue
        t = R_world_cam.T @ (np.array([xy[0], xy[1], 0.0]) - centre)
        corners = (np.column_stack([UNIT_CORNERS * SIZE, np.zeros(4)]) @ R_world_cam) + t  # marker axes = world axes
        seen.append(MarkerObservation(marker_id, np.zeros((4, 2)), R_world_cam.T.copy(), t, corners[:, :2] / corners[:, 2:3]))
    return seen
