"""2-D poses (x, y, theta) on the marker floor: composition, inverse, and a camera's pose over a
marker from that marker's 6-DoF observation."""

from __future__ import annotations

import numpy as np

from evp.markers.detection import MarkerObservation, marker_yaw


def wrap(angle):
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a o b: pose b (given in a's frame) in the frame a is given in."""
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], float(wrap(a[2] + b[2]))])


def inverse(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([-c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]])


def camera_over_marker(observation: MarkerObservation) -> np.ndarray:
    """(x, y, phi): the camera centre on the marker's plane in the marker's frame, and its yaw
    (Eq. 1's phi: the image's up direction from the marker's +y, counter-clockwise)."""
    centre = observation.camera_in_marker()
    return np.array([centre[0], centre[1], marker_yaw(observation)])
