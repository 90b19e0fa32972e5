"""ROS 1 bags, ROS 2 bags (sqlite3 and MCAP storage), standalone MCAP and video files round-trip."""

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer

from evp.errors import DatasetError
from evp.io import ros_messages as rm
from evp.io.mcap_writer import McapRecorder
from evp.io.registry import open_dataset
from evp.io.telemetry_csv import write_telemetry_csv
from evp.types import BaroSample, CameraModel, GpsFix, ImuSample
from tests.io import builders

CAMERA = CameraModel(64, 48, 50.0, 51.0, 31.5, 23.5, -0.1, 0.01, 0.001, 0.0, 0.0, name="camera")
IMAGES = [builders.noise_image(i) for i in range(4)]
IMU = [ImuSample(10.0 + 0.005 * i, (0.1, 0.2, 0.3), (0.0, 0.0, 9.81)) for i in range(20)]
GPS = [GpsFix(10.0 + 0.2 * i, 41.5 + 1e-5 * i, -83.7, 120.0, 2.5, 4.0) for i in range(3)]
BARO = [BaroSample(10.0 + 0.1 * i, 101325.0 - i) for i in range(5)]


def _messages(store, compressed: bool):
    """(topic, msgtype, message, time) for a small recording."""
    out = [("/camera/camera_info", rm.CAMERA_INFO, rm.camera_info_to_msg(store, 10.0, CAMERA), 10.0)]
    for i, image in enumerate(IMAGES):
        t = 10.0 + 0.1 * i
        if compressed:
            ok, jpeg = cv2.imencode(".png", image)  # lossless, so pixels can be compared exactly
            out.append(("/camera/image/compressed", rm.COMPRESSED_IMAGE, rm.jpeg_to_msg(store, t, jpeg.tobytes()), t))
        else:
            out.append(("/camera/image_raw", rm.IMAGE, rm.image_to_msg(store, t, image), t))
    out += [("/imu", rm.IMU, rm.imu_to_msg(store, s), s.timestamp) for s in IMU]
    out += [("/fix", rm.NAVSAT, rm.gps_to_msg(store, f), f.timestamp) for f in GPS]
    out += [("/pressure", rm.PRESSURE, rm.baro_to_msg(store, b), b.timestamp) for b in BARO]
    return sorted(out, key=lambda m: m[3])


def _check(dataset):
    assert dataset.format == "rosbag"
    assert dataset.num_frames == len(IMAGES)
    assert np.allclose(dataset.frame_times, [10.0, 10.1, 10.2, 10.3])
    for frame, image in zip(dataset.frames(), IMAGES):
        assert np.array_equal(frame.image, image)
    assert dataset.camera.fx == CAMERA.fx and dataset.camera.k1 == CAMERA.k1 and dataset.camera.width == 64
    assert [s.angular_velocity_rad_s for s in dataset.imu] == [s.angular_velocity_rad_s for s in IMU]
    assert dataset.gps[1].latitude_deg == GPS[1].latitude_deg and dataset.gps[0].horizontal_accuracy_m == pytest.approx(2.5)
    assert [b.pressure_pa for b in dataset.baro] == [b.pressure_pa for b in BARO]


@pytest.mark.parametrize("compressed", [False, True])
def test_standalone_mcap(tmp_path, compressed):
    path = tmp_path / "rec.mcap"
    with McapRecorder(path) as recorder:
        for topic, msgtype, msg, t in _messages(rm.ROS2, compressed):
            recorder.write(topic, msgtype, msg, t)
    _check(open_dataset(path))


def _write_bag(writer, store, serialize, compressed: bool) -> None:
    connections = {}
    for topic, msgtype, msg, t in _messages(store, compressed):
        if topic not in connections:
            connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
        writer.write(connections[topic], int(t * 1e9), serialize(msg, msgtype))


def test_ros1_bag(tmp_path):
    path = tmp_path / "rec.bag"
    with Ros1Writer(path) as writer:
        _write_bag(writer, rm.ROS1, rm.ROS1.serialize_ros1, compressed=False)
    _check(open_dataset(path))


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_ros2_bag_folder(tmp_path, storage):
    path = tmp_path / "rec_bag"
    with Ros2Writer(path, version=9, storage_plugin=storage) as writer:
        _write_bag(writer, rm.ROS2, rm.ROS2.serialize_cdr, compressed=True)
    _check(open_dataset(path))


def test_gps_without_fix_is_skipped_and_undecodable_image_is_named(tmp_path):
    path = tmp_path / "rec.mcap"
    no_fix = rm.gps_to_msg(rm.ROS2, GPS[0])
    no_fix.status.status = -1
    bad = rm.image_to_msg(rm.ROS2, 10.0, IMAGES[0])
    bad.encoding = "yuv422_weird"
    with McapRecorder(path) as recorder:
        recorder.write("/fix", rm.NAVSAT, no_fix, 10.0)
        recorder.write("/camera/image_raw", rm.IMAGE, bad, 10.0)
    dataset = open_dataset(path)
    assert dataset.gps == []
    with pytest.raises(DatasetError, match="cannot be decoded") as info:
        next(dataset.frames())
    assert info.value.record == "0"


def test_video_with_telemetry_calibration_and_ground_truth(tmp_path):
    video = builders.make_video(tmp_path / "v", count=12, fps=10.0)
    (tmp_path / "v" / "camera.yaml").write_text(
        "image_width: 480\nimage_height: 360\ncamera_matrix: {rows: 3, cols: 3, data: [670.8, 0, 259.85, 0, 670.7, 198.37, 0, 0, 1]}\n"
    )
    write_telemetry_csv(tmp_path / "v" / "flight.csv", IMU[:5] + GPS + BARO)
    (tmp_path / "v" / "groundtruth.txt").write_text("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n")
    dataset = open_dataset(video)
    assert dataset.format == "video" and dataset.num_frames == 12
    assert np.allclose(dataset.frame_times, np.arange(12) / 10.0)
    assert dataset.camera.width == 240 and dataset.camera.fx == pytest.approx(670.8 / 2)  # scaled to the video
    assert len(dataset.imu) == 5 and len(dataset.gps) == 3 and len(dataset.baro) == 5
    assert dataset.gps[2].horizontal_accuracy_m == 2.5
    frames = list(dataset.frames())
    assert len(frames) == 12 and frames[0].image.shape == (180, 240, 3)
    assert len(dataset.ground_truth) == 2
