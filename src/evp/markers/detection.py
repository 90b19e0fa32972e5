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

GOOD_FIT = 2e-3  # reprojection error (normalised units: about a pixel at fx 500) that needs no second solver
REFINEMENTS = {
    "none": cv2.aruco.CORNER_REFINE_NONE,
    "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
    "contour": cv2.aruco.CORNER_REFINE_CONTOUR,
    "apriltag": cv2.aruco.CORNER_REFINE_APRILTAG,
}


@dataclass(frozen=True)
class MarkerObservation:
    """One marker in one image. ``corners`` (4, 2) pixels in ArUco order (the marker's top-left,
    top-right, bottom-right, bottom-left), ``rays`` the same corners undistorted and normalised;
    ``R_cam_marker``/``t_cam_marker`` map marker-frame
    points (x right, y up on the marker, z out of it, origin at its centre) into the camera frame."""

    marker_id: int
    corners: np.ndarray
    R_cam_marker: np.ndarray
    t_cam_marker: np.ndarray
    rays: np.ndarray  # (4, 2) the corners undistorted to normalised image coordinates (x / z, y / z)

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
        parameters.adaptiveThreshWinSizeMin = settings.threshold_window_min_px
        parameters.adaptiveThreshWinSizeMax = max(settings.threshold_window_max_px, settings.threshold_window_min_px)
        parameters.adaptiveThreshWinSizeStep = settings.threshold_window_step_px
        parameters.useAruco3Detection = settings.fast_detection
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
        pixels = np.concatenate(corners).reshape(-1, 4, 2).astype(np.float64)
        rays = cv2.undistortPoints(pixels.reshape(-1, 1, 2), self._K, self._distortion).reshape(-1, 4, 2)
        for marker_pixels, marker_rays, marker_id in zip(pixels, rays, ids.ravel()):
            solved = planar_pose(self._object_points, marker_rays, cv2.SOLVEPNP_IPPE_SQUARE)
            if solved is None:
                continue
            found.append(MarkerObservation(int(marker_id), marker_pixels, solved[0], solved[1], marker_rays))
        return found


def planar_pose(object_points: np.ndarray, rays: np.ndarray, method: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(R, t) of planar points (z = 0) seen along undistorted rays (K = I): ``method`` (an IPPE
    variant), and OpenCV's iterative solver when that reprojects worse than ``GOOD_FIT``. IPPE can
    return a wrong, tilted pose (or none) for a square seen exactly face on, its degenerate case:
    a camera straight above a floor marker; the iterative solver is right there."""
    best = None
    for flags in (method, cv2.SOLVEPNP_ITERATIVE):
        try:
            ok, rvec, tvec = cv2.solvePnP(object_points, rays, np.eye(3), None, flags=flags)
        except cv2.error:  # the iterative solver's planar test can fail on four points (it then wants six)
            continue
        if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
            continue
        projected, _ = cv2.projectPoints(object_points, rvec, tvec, np.eye(3), None)
        error = float(np.abs(projected.reshape(-1, 2) - rays).max())
        if best is None or error < best[0]:
            best = (error, rvec, tvec)
        if best[0] < GOOD_FIT:
            break
    return None if best is None else (cv2.Rodrigues(best[1])[0], best[2].ravel())


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
