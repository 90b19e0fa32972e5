"""Every folder of ../shared/data loads with the right reader and sensible contents."""

import numpy as np
import pytest

from evp.io.registry import detect_reader, open_dataset
from evp.io.summary import describe, summarise
from tests.conftest import shared

EXPECTED = {
    # folder: (format, frames, ground-truth poses, image shape of the first frame)
    "kitti_odom_06_f000-050": ("kitti", 51, 51, (370, 1226)),
    "euroc_v1_01_easy_micro": ("euroc", 30, 2895, (480, 752)),
    "euroc_mh_01_easy_moving_360": ("euroc", 360, 360, (480, 752)),
    "aerial_nadir_odm_toledo_fc350": ("exif-photos", 47, 47, (900, 1200, 3)),
    "comma2k19_example_segment_sensors": ("comma2k19", 0, 1200, None),
    "davis_slider_depth": ("image-folder", 87, 339, (180, 240)),
    "reference_trajectories": ("trajectories", 0, None, None),
    "cmu_plaza1_wheel_odometry": ("cmu-plaza", 0, 9658, None),
    "tuc_labyrinth_wheel_odometry": ("tuc-labyrinth", 0, 233, None),
}


@pytest.mark.parametrize("folder", sorted(EXPECTED))
def test_shared_folder_loads(folder):
    path = shared(folder)
    fmt, frames, gt_poses, shape = EXPECTED[folder]
    assert detect_reader(path).name == fmt
    dataset = open_dataset(path)
    assert dataset.num_frames == frames
    if gt_poses is None:
        assert dataset.ground_truth is None
    else:
        assert len(dataset.ground_truth) == gt_poses
    if shape:
        first = next(dataset.frames())
        assert first.image.shape == shape
        assert first.timestamp == dataset.frame_times[0]
        assert dataset.camera.width == shape[1] and dataset.camera.height == shape[0]
    assert np.all(np.diff(dataset.frame_times) > 0)
    assert describe(summarise(dataset)).startswith(dataset.name)


def test_euroc_calibration_imu_and_ground_truth_frame():
    dataset = open_dataset(shared("euroc_v1_01_easy_micro"))
    assert dataset.camera.fx == pytest.approx(458.654) and dataset.camera.k1 == pytest.approx(-0.28340811)
    assert len(dataset.imu) == 29120
    # at rest the accelerometer reads gravity (~9.8 m/s^2) in the IMU frame
    acc = np.array([s.linear_acceleration_m_s2 for s in dataset.imu[:200]])
    assert np.linalg.norm(acc.mean(axis=0)) == pytest.approx(9.8, abs=0.2)
    stream = list(dataset.stream())
    assert [r.timestamp for r in stream] == sorted(r.timestamp for r in stream)


def test_euroc_camera_imu_extrinsic_is_cam0_in_imu0():
    dataset = open_dataset(shared("euroc_mh_01_easy_moving_360"))
    # imu0's T_BS is the identity in EuRoC, so cam0 in imu0 is cam0's T_BS (its sensor.yaml)
    assert dataset.T_body_cam[:3, 3] == pytest.approx([-0.0216401454975, -0.064676986768, 0.00981073058949])
    assert dataset.T_body_cam[0, 1] == pytest.approx(-0.999880929698)
    assert len(dataset.imu) == 36820


def test_exif_photos_give_gps_in_enu():
    dataset = open_dataset(shared("aerial_nadir_odm_toledo_fc350"))
    assert len(dataset.gps) == 47
    assert dataset.gps[0].latitude_deg == pytest.approx(41.54859617, abs=1e-7)
    assert dataset.ground_truth.path_length == pytest.approx(1541.5, abs=1.0)
    assert dataset.ground_truth.positions[1, 0] == pytest.approx(-21.96, abs=0.05)  # matches gps.csv east_m
    assert dataset.camera.fx == pytest.approx(702, rel=0.03)  # README: nominal fx ~702 px


def test_kitti_ground_truth_is_stamped_with_times():
    dataset = open_dataset(shared("kitti_odom_06_f000-050"))
    assert np.array_equal(dataset.ground_truth.timestamps, dataset.frame_times)
    assert dataset.ground_truth.path_length == pytest.approx(59.86, abs=0.01)
    assert dataset.camera.fx == pytest.approx(707.0912)


def test_comma2k19_telemetry():
    dataset = open_dataset(shared("comma2k19_example_segment_sensors"))
    assert len(dataset.imu) == 6256 and len(dataset.gps) == 579 and len(dataset.wheel) == 4974
    assert dataset.ground_truth.path_length == pytest.approx(1011.8, abs=0.5)
