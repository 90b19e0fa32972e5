"""Square fiducial markers in an image: ids, corners and each marker's 6-DoF pose.

OpenCV's ArUco module stands in for the paper's Vuforia frame markers (not available); it reads
ArUco and AprilTag dictionaries alike. Each marker's pose comes from its four corners alone with
SOLVEPNP_IPPE_SQUARE (Collins and Bartoli's planar-square solution), so a marker seen at the edge
of the image still has a pose. Seed 003, Eq. 1: the view-port coordinates are turned by the yaw
of the camera about the marker's normal so that "north" means the same on every frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from evp.config import MarkerSettings
from evp.errors import FrameError, UsageError
from evp.types import CameraModel

DICTIONARIES = (
    "DICT_4X4_50",
    "DICT_4X4_100",
    "DICT_4X4_250",
    "DICT_5X5_100",
    "DICT_6X6_250",
    "DICT_APRILTAG_16h5",
    "DICT_APRILTAG_25h9",
    "DICT_APRILTAG_36h11",
)

REFINEMENTS = {
    "none": cv2.aruco.CORNER_REFINE_NONE,
    "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
    "contour": cv2.aruco.CORNER_REFINE_CONTOUR,
    "apriltag": cv2.aruco.CORNER_REFINE_APRILTAG,
}


@dataclass(frozen=True)
class MarkerObservation:
    """One marker in one image. ``corners`` (4, 2) pixels in ArUco order (the marker's top-left,
    top-right, bottom-right, bottom-left); ``R_cam_marker``/``t_cam_marker`` map marker-frame
    points (x right, y up on the marker, z out of it, origin at its centre) into the camera frame."""

    marker_id: int
    corners: np.ndarray
    R_cam_marker: np.ndarray
    t_cam_marker: np.ndarray

    @property
    def distance_m(self) -> float:
        return float(np.linalg.norm(self.t_cam_marker))

    @property
    def centre_px(self) -> np.ndarray:
        return self.corners.mean(axis=0)

    def camera_in_marker(self) -> np.ndarray:
        """The camera centre in the marker frame (x, y on the marker plane, z its height above it)."""
        return -self.R_cam_marker.T @ self.t_cam_marker


class MarkerDetector:
    """Finds markers of one dictionary and measures their poses with a calibrated camera.

    Holds OpenCV's detector object (built once: building it per frame costs more than detecting).
    """

    def __init__(self, camera: CameraModel, settings: MarkerSettings):
        if settings.dictionary not in DICTIONARIES:
            raise UsageError(f"unknown marker dictionary {settings.dictionary!r}; choose one of {', '.join(DICTIONARIES)}")
        parameters = cv2.aruco.DetectorParameters()
        parameters.cornerRefinementMethod = REFINEMENTS[settings.corner_refinement]
        parameters.adaptiveThreshWinSizeStep = settings.threshold_window_step_px
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, settings.dictionary))
        self._detector = cv2.aruco.ArucoDetector(dictionary, parameters)
        self.camera = camera
        marker_size_m = settings.marker_size_m
        self._K = camera.K
        self._distortion = np.array([camera.k1, camera.k2, camera.p1, camera.p2, camera.k3])
        half = marker_size_m / 2
        self._object_points = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0], [-half, -half, 0]], np.float64)

    def detect(self, image: np.ndarray) -> list[MarkerObservation]:
        """Every decoded marker with its pose; a marker whose pose cannot be solved is left out.
        An image not of the calibrated size is refused (its poses would be wrong, silently)."""
        if image.shape[:2] != (self.camera.height, self.camera.width):
            raise FrameError(f"frame is {image.shape[1]}x{image.shape[0]}, the camera is calibrated for {self.camera.width}x{self.camera.height}")
        corners, ids, _ = self._detector.detectMarkers(image)
        if ids is None:
            return []
        found = []
        for marker_corners, marker_id in zip(corners, ids.ravel()):
            pixels = marker_corners.reshape(4, 2).astype(np.float64)
            ok, rvec, tvec = cv2.solvePnP(self._object_points, pixels, self._K, self._distortion, flags=cv2.SOLVEPNP_IPPE_SQUARE)
            if not ok:
                continue
            found.append(MarkerObservation(int(marker_id), pixels, cv2.Rodrigues(rvec)[0], tvec.ravel()))
        return found


def marker_yaw(observation: MarkerObservation) -> float:
    """phi of Eq. 1: the camera's rotation about the marker's normal, radians, 0 when the image's
    up (camera -y) points along the marker's +y, counter-clockwise positive seen from above."""
    up_in_marker = observation.R_cam_marker.T @ np.array([0.0, -1.0, 0.0])
    return float(np.arctan2(-up_in_marker[0], up_in_marker[1]))


def yaw_compensate(points: np.ndarray, phi: float) -> np.ndarray:
    """Eq. 1: view-port coordinates (N, 3) turned by phi: x' = x cos phi + y sin phi,
    y' = -x sin phi + y cos phi, z' = z."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    c, s = np.cos(phi), np.sin(phi)
    return np.column_stack([points[:, 0] * c + points[:, 1] * s, -points[:, 0] * s + points[:, 1] * c, points[:, 2]])
