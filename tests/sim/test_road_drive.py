"""The road-drive scenario: a car camera 1.5 m up looking along a town road, at 10 and 30 Hz."""

import numpy as np
import pytest

from evp.io.registry import open_dataset
from evp.sim.camera_effects import render_frame
from evp.sim.generate import generate
from evp.sim.scenarios import SimOptions, build_scenario
from evp.sim.world import Renderer, ray_distance


@pytest.fixture(scope="module")
def drive():
    return build_scenario("road-drive", SimOptions(duration_s=3.0, seed=2))


def test_the_camera_looks_along_the_road_from_1_5_m(drive):
    times = np.linspace(0.0, 3.0, 7)
    poses = drive.camera_poses(times)
    velocity = drive.motion.state(times).velocity
    speed = np.linalg.norm(velocity, axis=1)
    assert np.all((speed > 17.0) & (speed < 23.0))  # 20 m/s +- 10 %, from the first frame on
    np.testing.assert_allclose(poses[:, 2, 3], 1.5, atol=1e-9)
    along = np.einsum("ij,ij->i", poses[:, :3, 2], velocity / speed[:, None])
    assert np.all(along > np.cos(np.radians(2.0)))  # the optical axis follows the road heading
    assert np.all(np.abs(poses[:, 2, 2]) < np.sin(np.radians(1.0)))  # level: a car, not a multirotor


def test_the_road_fills_the_lower_half_and_the_sky_the_top(drive):
    camera = drive.camera
    image = render_frame(Renderer(camera, drive.scene), drive, 1.0, SimOptions(noise_sigma=0.0, gain_variation=0.0), 0)
    pose = drive.camera_poses(np.array([1.0]))[0]
    for row in (camera.cy + 20, camera.height - 1):  # rays through the lower half meet the road surface
        ray = pose[:3, :3] @ np.array([0.0, (row - camera.cy) / camera.fy, 1.0])
        ray /= np.linalg.norm(ray)
        assert ray_distance(drive.scene, pose[:3, 3], ray) * -ray[2] == pytest.approx(1.5, abs=0.01)
    asphalt = image[-30:, int(camera.cx) - 40 : int(camera.cx) + 40]
    assert 40 < np.median(asphalt) < 130 and asphalt.std() > 3  # dark, textured asphalt (no sensor noise here)
    assert (image[:5] == drive.scene.background).mean() > 0.05  # sky above


@pytest.mark.parametrize("fps", [10.0, 30.0])
def test_10_and_30_hz_give_their_frame_stamps(tmp_path, fps):
    result = generate("road-drive", SimOptions(duration_s=0.2, fps=fps, seed=1), tmp_path, workers=1)
    dataset = open_dataset(tmp_path)
    stamps = np.array([frame.timestamp for frame in dataset.frames()])
    assert result.frames == len(stamps) == int(round(0.2 * fps)) + 1
    np.testing.assert_allclose(np.diff(stamps), 1.0 / fps, atol=1e-6)
    assert {"imu", "gps", "wheel"} == set(result.scenario.sensors) and dataset.gps and dataset.wheel
