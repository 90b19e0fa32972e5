"""The renderer is exact: points land where the camera model projects them, and two views obey
the two-view geometry of their ground-truth poses."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evp.calib.profiles import load_profile
from evp.sim.calibration_target import TEXTURE_PX_PER_SQUARE, chessboard_texture
from evp.sim.scenarios import SimOptions, build_scenario
from evp.sim.world import Renderer, Scene, TexturedQuad, ray_distance

NEXUS = load_profile("nexus5x_640x380")
EUROC = load_profile("global_shutter_752x480")
SQUARE = 0.05


def _board_scene() -> tuple[Scene, np.ndarray]:
    """A 9x7 chessboard lying on z = 0; returns the scene and its inner corners (world, metres)."""
    texture, origin_px = chessboard_texture(9, 7)
    # a band-limited board: sampling it does not alias, so corner positions measure geometry only
    # (blurring is symmetric about each corner, which therefore stays where it is)
    texture = cv2.GaussianBlur(texture, (0, 0), 4.0)
    mpt = SQUARE / TEXTURE_PX_PER_SQUARE
    quad = TexturedQuad([0, 0, 0], [1, 0, 0], [0, 1, 0], texture.shape[1] * mpt, texture.shape[0] * mpt, texture, mpt, "board")
    first = (origin_px + 0.5) * mpt  # texel edge convention of the quad: texel k spans [k, k+1) * mpt
    corners = np.array([[first + i * SQUARE, first + j * SQUARE, 0.0] for j in range(6) for i in range(8)])
    return Scene([quad], background=128), corners


def _look_at(eye, target, up=(0, 0, 1)) -> np.ndarray:
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = eye
    return T


@pytest.mark.parametrize("camera", [NEXUS, EUROC], ids=["nexus", "euroc-strong-distortion"])
def test_known_points_project_where_the_renderer_draws_them(camera):
    scene, corners = _board_scene()
    centre = corners.mean(axis=0)
    T_world_cam = _look_at(centre + np.array([0.12, -0.45, 0.38]), centre)
    image = Renderer(camera, scene).render(T_world_cam)
    found, detected = cv2.findChessboardCornersSB(image, (8, 6), flags=cv2.CALIB_CB_ACCURACY)
    assert found
    # saddle-point refinement (unbiased under perspective, unlike the detector's own estimate)
    detected = cv2.cornerSubPix(image, detected, (5, 5), (-1, -1), (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)).reshape(-1, 2)
    in_cam = (corners - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]
    expected = camera.project(in_cam)
    # OpenCV may order the grid from either end: match each expected corner to its nearest detection
    distances = np.linalg.norm(expected[:, None, :] - detected[None, :, :], axis=2)
    errors = distances.min(axis=1)
    assert np.median(errors) < 0.05 and errors.max() < 0.15, errors


def _matches(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    points = cv2.goodFeaturesToTrack(a, 400, 0.01, 8)
    moved, status, _ = cv2.calcOpticalFlowPyrLK(a, b, points, None, winSize=(21, 21), maxLevel=3)
    good = status.ravel() == 1
    return points.reshape(-1, 2)[good], moved.reshape(-1, 2)[good]


def _two_views(name: str, times: tuple[float, float], **options):
    """Ground-truth poses and KLT matches (normalised, undistorted) between two noise-free renders."""
    scenario = build_scenario(name, SimOptions(noise_sigma=0.0, exposure_s=0.0, gain_variation=0.0, **options))
    renderer = Renderer(scenario.camera, scenario.scene)
    poses = scenario.camera_poses(np.array(times))
    p0, p1 = _matches(*(renderer.render(T) for T in poses))
    return scenario, poses, scenario.camera.undistort_points(p0), scenario.camera.undistort_points(p1)


def test_two_views_of_a_3d_room_obey_the_epipolar_geometry_of_their_poses():
    scenario, poses, x0, x1 = _two_views("wheel-robot-room", (10.0, 10.4))
    T_10 = np.linalg.inv(poses[1]) @ poses[0]  # camera 0 -> camera 1
    t = T_10[:3, 3]
    E = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ T_10[:3, :3]
    h0 = np.column_stack([x0, np.ones(len(x0))])
    h1 = np.column_stack([x1, np.ones(len(x1))])
    Ex0 = h0 @ E.T
    Etx1 = h1 @ E
    sampson = (np.sum(h1 * Ex0, axis=1) ** 2) / (Ex0[:, 0] ** 2 + Ex0[:, 1] ** 2 + Etx1[:, 0] ** 2 + Etx1[:, 1] ** 2)
    residual_px = np.sqrt(sampson) * scenario.camera.fx
    assert len(residual_px) > 100
    # KLT on noise-free renders is good to ~0.1-0.2 px; a wrong pose or lens model gives pixels
    assert np.median(residual_px) < 0.25, np.median(residual_px)
    assert np.percentile(residual_px, 90) < 1.0


def test_two_views_of_the_ground_obey_the_plane_homography():
    scenario, poses, x0, x1 = _two_views("drone-flight", (40.0, 40.5), relief=False, duration_s=60.0)
    # plane z = 0 seen from camera 0: n^T X = d in camera-0 coordinates
    R0, c0 = poses[0][:3, :3], poses[0][:3, 3]
    n = R0.T @ np.array([0.0, 0.0, 1.0])
    d = -c0[2]
    T_10 = np.linalg.inv(poses[1]) @ poses[0]
    H = T_10[:3, :3] + np.outer(T_10[:3, 3], n) / d
    mapped = np.column_stack([x0, np.ones(len(x0))]) @ H.T
    residual_px = np.linalg.norm(mapped[:, :2] / mapped[:, 2:] - x1, axis=1) * scenario.camera.fx
    assert len(residual_px) > 100
    assert np.median(residual_px) < 0.15, np.median(residual_px)


def test_rolling_shutter_and_motion_blur_change_the_image_as_motion_dictates():
    from evp.sim.camera_effects import render_frame

    still = SimOptions(noise_sigma=0.0, exposure_s=0.0, gain_variation=0.0, relief=False, duration_s=60.0)
    scenario = build_scenario("drone-flight", still)
    renderer = Renderer(scenario.camera, scenario.scene)
    t = 45.0
    sharp = render_frame(renderer, scenario, t, still, 0).astype(float)
    blurred = render_frame(renderer, scenario, t, still.model_copy(update={"exposure_s": 0.05}), 0).astype(float)
    rolling = render_frame(renderer, scenario, t, still.model_copy(update={"rolling_shutter_s": 0.03}), 0).astype(float)
    laplacian = lambda image: np.var(cv2.Laplacian(image, cv2.CV_64F))  # noqa: E731
    assert laplacian(blurred) < 0.8 * laplacian(sharp)
    # each row is exposed at its own time: the first row 15 ms early, the last 15 ms late
    early = render_frame(renderer, scenario, t - 0.015, still, 0).astype(float)
    late = render_frame(renderer, scenario, t + 0.015, still, 0).astype(float)
    assert np.abs(rolling[0] - early[0]).max() <= 1.0
    assert np.abs(rolling[-1] - late[-1]).max() <= 1.0
    assert np.abs(rolling - sharp).mean() > 0.5


def test_ray_distance_to_the_ground_and_to_a_roof():
    scenario = build_scenario("marker-field", SimOptions())
    assert ray_distance(scenario.scene, np.array([0.0, 0.0, 0.5]), np.array([0.0, 0.0, -1.0])) == pytest.approx(0.499)
    tilted = Rotation.from_euler("x", 30, degrees=True).apply([0.0, 0.0, -1.0])
    assert ray_distance(scenario.scene, np.array([0.0, 0.0, 0.5]), tilted) == pytest.approx(0.499 / np.cos(np.radians(30)))


FISHEYE = build_scenario("circle-indoor", SimOptions(lens="fisheye", fisheye_fov_deg=180.0, duration_s=1.0)).camera.scaled(320, 190)


def test_fisheye_renders_the_board_where_its_model_projects_it():
    test_known_points_project_where_the_renderer_draws_them(FISHEYE.scaled(640, 380))


@pytest.mark.parametrize("angle_deg", [0.0, 45.0, 75.0, 85.0])
def test_fisheye_renders_a_point_far_off_axis_where_its_model_projects_it(angle_deg):
    """A small blob facing the camera, ``angle_deg`` off the axis towards the image corner: the
    centroid of its image is where the camera projects its centre (to a fraction of a pixel)."""
    azimuth = np.arctan2(FISHEYE.cy, FISHEYE.cx)
    theta = np.radians(angle_deg)
    direction = np.array([np.sin(theta) * np.cos(azimuth), np.sin(theta) * np.sin(azimuth), np.cos(theta)])
    u = np.cross(direction, [0.0, 0.0, 1.0] if angle_deg > 10 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(direction, u)
    size = 0.06
    texel = np.arange(64) - 31.5
    texture = (255 * np.exp(-(texel[:, None] ** 2 + texel[None, :] ** 2) / (2 * 8.0**2))).astype(np.uint8)
    quad = TexturedQuad(direction - size / 2 * (u + v), u, v, size, size, texture, size / 64, "blob")
    image = Renderer(FISHEYE, Scene([quad], background=0)).render(np.eye(4)).astype(float)
    v_grid, u_grid = np.mgrid[: image.shape[0], : image.shape[1]]
    centroid = np.array([np.sum(u_grid * image), np.sum(v_grid * image)]) / image.sum()
    assert np.linalg.norm(centroid - FISHEYE.project(direction[None])[0]) < 0.1


def test_fisheye_rolling_shutter_render_matches_the_global_one_when_still():
    scenario = build_scenario("circle-indoor", SimOptions(lens="fisheye", duration_s=1.0))
    camera = scenario.camera.scaled(160, 95)
    renderer = Renderer(camera, scenario.scene)
    T = scenario.camera_poses(np.array([0.5]))[0]
    still = renderer.render(T).astype(float)
    rolling = renderer.render(np.eye(4), row_poses=np.repeat(T[None], camera.height, axis=0)).astype(float)
    assert still.std() > 5
    assert np.abs(rolling - still).mean() < 0.05, np.abs(rolling - still).mean()
