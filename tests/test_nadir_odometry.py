"""Nadir mosaic odometry on a textured ground plane rendered exactly: position and height of
each view, tilted views included."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.types import CameraModel, Frame, TrackingState
from evp.vo.nadir_homography import NadirHomographyOdometry

CAMERA = CameraModel(width=800, height=600, fx=600.0, fy=600.0, cx=400.0, cy=300.0)
HEIGHT = 600.0  # ground units; with fx = 600 the first image's pixels are ground units


@pytest.fixture(scope="module")
def ground() -> np.ndarray:
    rng = np.random.default_rng(5)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (3000, 3000)).astype(np.float32), (0, 0), 3.0)
    return cv2.normalize(texture, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def _view(ground: np.ndarray, centre: np.ndarray, tilt_deg: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The image of a camera at ``centre`` (ground x, y and height), looking down, tilted about
    its x and y axes: plane point (X, Y, 0) in a frame whose z points into the ground."""
    R = Rotation.from_euler("xy", tilt_deg, degrees=True).as_matrix()
    C = np.array([centre[0], centre[1], -centre[2]])
    H = CAMERA.K @ R @ np.column_stack([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], -C])
    return cv2.warpPerspective(ground, H / H[2, 2], (CAMERA.width, CAMERA.height), flags=cv2.INTER_LINEAR)


def test_positions_and_heights_of_nadir_and_slightly_tilted_views(ground):
    start = np.array([1200.0, 1500.0, HEIGHT])
    views = [
        (start, (0.0, 0.0)),
        (start + [150.0, 0.0, 0.0], (0.0, 0.0)),
        (start + [300.0, 40.0, 150.0], (0.0, 0.0)),  # climbed a quarter
        (start + [300.0, 40.0, 150.0], (3.0, -2.0)),  # same place, the gimbal off by a few degrees
    ]
    odometry = NadirHomographyOdometry(CAMERA)
    estimates = [odometry.feed(Frame(float(k), _view(ground, centre, tilt), k)) for k, (centre, tilt) in enumerate(views)]
    assert all(e.tracking_state == TrackingState.OK for e in estimates)
    origin = estimates[0].T_world_cam[:3, 3]
    for estimate, (centre, tilt) in zip(estimates, views, strict=True):
        moved = estimate.T_world_cam[:3, 3] - origin
        truth = np.array([centre[0] - start[0], -(centre[1] - start[1]), centre[2] - start[2]])  # world y is up the image
        # a tilt moves the centre ray's ground point by h tan(tilt) (3.6 degrees: 0.063 h), which this odometry reports
        tolerance = 1.0 if tilt == (0.0, 0.0) else 0.07 * centre[2]
        assert np.linalg.norm(moved[:2] - truth[:2]) < tolerance
        assert abs(moved[2] - truth[2]) < 0.02 * HEIGHT
