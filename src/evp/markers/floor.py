"""Every marker in a frame at once: the camera's pose over the floor from all the mapped markers'
corners together, and each marker's place on the floor from where its corner rays meet it.

One square's own pose (IPPE) is ambiguous in its tilt when it is small and seen nearly face on:
the two solutions differ by a few degrees, which at half a metre moves the camera by centimetres,
and a marker at the image edge can move by ten. All markers lie on one floor and are seen by one
camera, so the camera pose is solved from all mapped corners together (planar PnP) and a new
marker is placed where its corners' rays meet the floor: the relative places of markers in one
frame then agree to millimetres.
"""

from __future__ import annotations

import cv2
import numpy as np

from evp.markers.detection import MarkerObservation, planar_pose

# a marker's corners in its own frame (ArUco order: top-left, top-right, bottom-right, bottom-left), per unit side
UNIT_CORNERS = np.array([[-0.5, 0.5], [0.5, 0.5], [0.5, -0.5], [-0.5, -0.5]])


def corners_on_floor(pose: np.ndarray, size_m: float) -> np.ndarray:
    """(4, 2) floor coordinates of the corners of a marker with floor pose (x, y, theta)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    local = UNIT_CORNERS * size_m
    return np.column_stack([pose[0] + c * local[:, 0] - s * local[:, 1], pose[1] + s * local[:, 0] + c * local[:, 1]])


def camera_over_floor(observations: list[MarkerObservation], poses: dict[int, np.ndarray], size_m: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(R_cam_floor, t_cam_floor) from the corners of every observed marker in ``poses`` (planar PnP
    on the undistorted rays), refined by Levenberg-Marquardt over all of them (IPPE's closed form
    is taken as good when it fits to a pixel: the refinement finishes it); None without a mapped
    marker."""
    mapped = [o for o in observations if o.marker_id in poses]
    if not mapped:
        return None
    floor = np.concatenate([corners_on_floor(poses[o.marker_id], size_m) for o in mapped])
    points = np.column_stack([floor, np.zeros(len(floor))])
    rays = np.concatenate([o.rays for o in mapped])
    solved = planar_pose(points, rays, cv2.SOLVEPNP_IPPE)
    if solved is not None:
        rvec, tvec = cv2.solvePnPRefineLM(points, rays, np.eye(3), None, cv2.Rodrigues(solved[0])[0], solved[1].reshape(3, 1))
        solved = cv2.Rodrigues(rvec)[0], tvec.ravel()
    if solved is None or not np.all(np.isfinite(solved[1])) or (-solved[0].T @ solved[1])[2] <= 0:
        return None  # no pose, or the mirror image under the floor
    return solved


def floor_points(R_cam_floor: np.ndarray, t_cam_floor: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Where the rays (N, 2 normalised image coordinates) meet the floor (z = 0), floor (x, y)."""
    centre = -R_cam_floor.T @ t_cam_floor
    directions = np.column_stack([rays, np.ones(len(rays))]) @ R_cam_floor  # R^T d for each ray
    scale = -centre[2] / directions[:, 2]
    return centre[:2] + scale[:, None] * directions[:, :2]


def marker_pose_from_corners(corners: np.ndarray) -> np.ndarray:
    """Floor pose (x, y, theta) of a marker from its four corners on the floor: centre, and the
    direction of its +x axis (top edge, left to right, and bottom edge) as theta."""
    x_axis = (corners[1] - corners[0]) + (corners[2] - corners[3])
    return np.array([*corners.mean(axis=0), np.arctan2(x_axis[1], x_axis[0])])


def camera_pose_2d(R_cam_floor: np.ndarray, t_cam_floor: np.ndarray) -> tuple[np.ndarray, float]:
    """(x, y, yaw of the image's up direction, the body's forward axis) on the floor and the height."""
    centre = -R_cam_floor.T @ t_cam_floor
    up = R_cam_floor.T @ np.array([0.0, -1.0, 0.0])
    return np.array([centre[0], centre[1], np.arctan2(up[1], up[0])]), float(centre[2])
