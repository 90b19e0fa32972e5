"""Exact renderings of a chessboard seen by a pinhole camera (for calibration tests and demos)."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from evp.types import CameraModel

TEXTURE_PX_PER_SQUARE = 64


def chessboard_texture(cols: int, rows: int, margin_squares: float = 1.0) -> tuple[np.ndarray, float]:
    """Board image (``cols`` x ``rows`` squares, top-left black, white margin) and the texture
    x/y coordinate of the first inner corner (OpenCV's origin for chessboard object points)."""
    s = TEXTURE_PX_PER_SQUARE
    margin = int(margin_squares * s)
    texture = np.full((rows * s + 2 * margin, cols * s + 2 * margin), 255, np.uint8)
    for r in range(rows):
        for c in range(cols):
            if (r + c) % 2 == 0:
                texture[margin + r * s : margin + (r + 1) * s, margin + c * s : margin + (c + 1) * s] = 0
    return texture, margin + s - 0.5


def charuco_texture(board: cv2.aruco.CharucoBoard, margin_squares: float = 1.0) -> tuple[np.ndarray, float]:
    """ChArUco board image with a white margin, and the texture coordinate of the board's outer
    top-left corner (OpenCV's origin for ChArUco object points)."""
    cols, rows = board.getChessboardSize()
    s = TEXTURE_PX_PER_SQUARE
    margin = int(margin_squares * s)
    image = board.generateImage((cols * s, rows * s), marginSize=0, borderBits=1)
    return cv2.copyMakeBorder(image, margin, margin, margin, margin, cv2.BORDER_CONSTANT, value=255), margin - 0.5


def render_board(
    camera: CameraModel, texture: np.ndarray, origin_px: float, square_m: float, rvec: np.ndarray, tvec: np.ndarray, supersample: int = 3
) -> np.ndarray:
    """Grey image of a planar board texture (``TEXTURE_PX_PER_SQUARE`` pixels per square, board
    origin at texture coordinate ``origin_px`` on both axes, z = 0) seen under pose (rvec, tvec).

    Rendered through the exact plane-to-image homography at ``supersample`` times the resolution,
    then area-averaged; lens distortion is applied by remapping through the camera model.
    """
    scale = square_m / TEXTURE_PX_PER_SQUARE
    tex_to_board = np.array([[scale, 0, -origin_px * scale], [0, scale, -origin_px * scale], [0, 0, 1]])
    R = Rotation.from_rotvec(np.ravel(rvec)).as_matrix()
    board_to_cam = np.column_stack([R[:, 0], R[:, 1], np.ravel(tvec)])
    k = supersample
    K_big = np.array([[camera.fx * k, 0, (camera.cx + 0.5) * k - 0.5], [0, camera.fy * k, (camera.cy + 0.5) * k - 0.5], [0, 0, 1]])
    H = K_big @ board_to_cam @ tex_to_board
    ideal = cv2.warpPerspective(texture, H, (camera.width * k, camera.height * k), flags=cv2.INTER_LINEAR, borderValue=255)
    ideal = cv2.resize(ideal, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    if not camera.has_distortion:
        return ideal
    # Each distorted output pixel samples the ideal image where its undistorted ray lands.
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    ideal_px = camera.undistort_pixels(np.column_stack([u.ravel(), v.ravel()]))
    map_x = ideal_px[:, 0].reshape(u.shape).astype(np.float32)
    map_y = ideal_px[:, 1].reshape(u.shape).astype(np.float32)
    return cv2.remap(ideal, map_x, map_y, cv2.INTER_LINEAR, borderValue=255)


def random_board_poses(
    camera: CameraModel, count: int, cols: int, rows: int, square_m: float, seed: int = 0, origin_offset_m: float = 0.0
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Varied board poses (tilts up to ~35 degrees) spread over the image, the board filling much of it.

    A calibration needs views where the board is large and tilted to separate focal length from
    distortion; poses whose outer squares would leave the image (with a 5 % margin) are redrawn.
    Board frame as OpenCV's object points: the outer corner is at ``-origin_offset_m`` on both
    axes (one square for a chessboard, whose origin is the first inner corner; 0 for ChArUco).
    """
    rng = np.random.default_rng(seed)
    centre = np.array([cols * square_m / 2, rows * square_m / 2, 0.0])
    outline = np.array([[0, 0, 0], [cols, 0, 0], [cols, rows, 0], [0, rows, 0]], dtype=float) * square_m
    fov_width = camera.width / camera.fx
    margin = 0.05 * np.array([camera.width, camera.height])
    poses = []
    while len(poses) < count:
        angles = rng.uniform(-0.6, 0.6, 3) * np.array([1.0, 1.0, 0.5])
        R = Rotation.from_rotvec(angles).as_matrix()
        distance = cols * square_m / fov_width * rng.uniform(1.1, 1.7)
        offset = rng.uniform(-0.25, 0.25, 2) * distance * fov_width
        t = np.array([offset[0], offset[1], distance]) - R @ (centre - origin_offset_m * np.array([1.0, 1.0, 0.0]))
        corners_cam = (outline - origin_offset_m * np.array([1.0, 1.0, 0.0])) @ R.T + t
        if np.any(corners_cam[:, 2] <= 0):
            continue
        pixels = camera.project(corners_cam)
        if np.all(pixels >= margin) and np.all(pixels <= np.array([camera.width, camera.height]) - margin):
            poses.append((Rotation.from_matrix(R).as_rotvec(), t))
    return poses
