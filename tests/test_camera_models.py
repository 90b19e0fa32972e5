"""Each lens model projects and unprojects as OpenCV does: the 8-coefficient rational
radial-tangential model against cv2.projectPoints, the equidistant fisheye against cv2.fisheye."""

import cv2
import numpy as np
import pytest

from evp.types import CameraModel, LensModel

RATIONAL = CameraModel(640, 480, 400.0, 410.0, 320.0, 240.0, -0.3, 0.1, 0.001, -0.002, 0.01, k4=0.05, k5=0.01, k6=0.002)
# TUM VI cam0's Kannala-Brandt coefficients on a 640x480 sensor
FISHEYE = CameraModel(640, 480, 190.0, 191.0, 319.5, 239.5, 0.00348, 0.000715, k3=-0.00205, k4=0.000203, lens=LensModel.EQUIDISTANT)


def _rays(count: int, max_angle_deg: float, seed: int = 0) -> np.ndarray:
    """Unit rays spread up to ``max_angle_deg`` off the optical axis."""
    rng = np.random.default_rng(seed)
    theta = np.radians(max_angle_deg) * np.sqrt(rng.uniform(0, 1, count))
    phi = rng.uniform(0, 2 * np.pi, count)
    return np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def test_rational_model_matches_opencv_and_round_trips():
    assert RATIONAL.distortion.shape == (8,) and RATIONAL.coefficients["k6"] == 0.002
    points = _rays(500, 50) * np.random.default_rng(1).uniform(1, 5, (500, 1))
    ours = RATIONAL.project(points)
    theirs, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), RATIONAL.K, RATIONAL.distortion)
    assert np.allclose(ours, theirs.reshape(-1, 2), atol=1e-9)
    assert np.allclose(RATIONAL.unproject(ours, points[:, 2]), points, atol=1e-9)


def test_plain_radtan_keeps_its_five_coefficients():
    camera = CameraModel(640, 480, 500, 500, 320, 240, 0.1, -0.2, 0.001, 0.002, 0.03, name="c")
    assert camera.distortion.tolist() == [0.1, -0.2, 0.001, 0.002, 0.03] and camera.lens is LensModel.RADTAN


def test_fisheye_matches_opencv_fisheye_and_round_trips_to_90_degrees():
    rays = _rays(500, 89.5)
    ours = FISHEYE.project(rays * 3.0)
    theirs, _ = cv2.fisheye.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), FISHEYE.K, FISHEYE.distortion)
    assert np.allclose(ours, theirs.reshape(-1, 2), atol=1e-9)
    assert np.allclose(FISHEYE.bearings(ours), rays, atol=1e-12)
    assert np.allclose(FISHEYE.undistort_points(ours), rays[:, :2] / rays[:, 2:], rtol=1e-9, atol=1e-9)
    opencv = cv2.fisheye.undistortPoints(ours.reshape(-1, 1, 2), FISHEYE.K, FISHEYE.distortion).reshape(-1, 2)
    near = rays[:, 2] > np.cos(np.radians(60))  # OpenCV's own inversion loses accuracy further out
    assert np.allclose(FISHEYE.undistort_points(ours[near]), opencv[near], atol=1e-8)


def test_fisheye_rays_beyond_90_degrees_have_bearings_but_no_pinhole_coordinates():
    behind = np.array([[1.0, 0.2, -0.1]])
    pixel = FISHEYE.project(behind)
    assert np.allclose(FISHEYE.bearings(pixel), behind / np.linalg.norm(behind), atol=1e-12)
    assert np.isnan(FISHEYE.undistort_points(pixel)).all()


def test_fisheye_scaling_undistortion_and_parameters():
    small = FISHEYE.scaled(320, 240)
    assert small.lens is LensModel.EQUIDISTANT and small.k4 == FISHEYE.k4
    assert np.allclose((FISHEYE.project(_rays(5, 80)) + 0.5) / 2, small.project(_rays(5, 80)) + 0.5, atol=1e-9)
    assert FISHEYE.has_distortion and FISHEYE.distortion.shape == (4,)
    assert not CameraModel(64, 48, 50, 50, 32, 24, lens=LensModel.RADTAN).has_distortion
    image = np.random.default_rng(0).integers(0, 255, (480, 640), dtype=np.uint8)
    assert FISHEYE.undistort_image(image).shape == image.shape
    with pytest.raises(ValueError, match="k1..k4"):
        CameraModel(640, 480, 200, 200, 320, 240, p1=0.01, lens=LensModel.EQUIDISTANT)
    assert CameraModel(640, 480, 200, 200, 320, 240, lens="equidistant").lens is LensModel.EQUIDISTANT


@pytest.mark.parametrize("camera", [RATIONAL, FISHEYE], ids=["rational", "fisheye"])
def test_pixel_jacobian_is_the_derivative_of_the_detected_pixel(camera):
    xy = _rays(50, 70)[:, :2] / _rays(50, 70)[:, 2:]
    step = 1e-4

    def detected(undistorted_px):
        return camera.project(np.column_stack([(undistorted_px - [camera.cx, camera.cy]) / [camera.fx, camera.fy], np.ones(len(undistorted_px))]))

    px = xy * [camera.fx, camera.fy] + [camera.cx, camera.cy]
    numeric = np.stack([(detected(px + d) - detected(px - d)) / (2 * step) for d in np.eye(2) * step], axis=-1)
    assert np.allclose(camera.pixel_jacobian(xy), numeric, atol=1e-6)


def test_a_peripheral_fisheye_feature_carries_less_information_radially_and_a_pinhole_the_same():
    """The detector's isotropic pixel noise seen in undistorted pixels: information J^T J, along
    the ray's radial direction cos^4(theta), tangentially (theta / tan(theta))^2."""
    fisheye = CameraModel(640, 480, 200.0, 200.0, 319.5, 239.5, lens=LensModel.EQUIDISTANT)
    theta = np.radians(60)
    radial = np.array([np.cos(0.3), np.sin(0.3)])
    J = fisheye.pixel_jacobian(np.tan(theta) * radial[None])[0]
    information = J.T @ J
    tangential = np.array([-radial[1], radial[0]])
    assert radial @ information @ radial == pytest.approx(np.cos(theta) ** 4)
    assert tangential @ information @ tangential == pytest.approx((theta / np.tan(theta)) ** 2)
    assert np.allclose(fisheye.pixel_jacobian(np.zeros((1, 2))), np.eye(2))
    pinhole = CameraModel(640, 480, 500.0, 500.0, 320.0, 240.0)
    assert np.array_equal(pinhole.pixel_jacobian(np.array([[0.4, -0.3]])), np.eye(2)[None])
