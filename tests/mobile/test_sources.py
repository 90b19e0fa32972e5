"""What ``evp stream`` sends: datasets and videos as time-ordered frames and telemetry with their
camera, a missing calibration or camera as a clear error, and telemetry as protocol messages."""

import math

import pytest

from evp.calib.profiles import load_profile
from evp.errors import EvpError
from evp.mobile.sources import open_source, telemetry_message
from evp.station.protocol import BaroTelemetry, GpsTelemetry, ImuTelemetry
from evp.types import BaroSample, Frame, GpsFix, ImuSample, RangeSample, WifiScan
from tests.conftest import SAMPLE
from tests.io import builders


def test_a_dataset_streams_its_frames_with_its_camera_and_rate():
    source = open_source(str(SAMPLE), max_frames=5)
    items = list(source.items)
    assert (source.name, source.camera.width, source.camera.height) == ("davis_slider_depth", 240, 180)
    assert source.fps == pytest.approx(25.8, abs=0.1) and not source.live and source.lossless
    assert [f.index for f in items] == list(range(5)) and all(isinstance(f, Frame) for f in items)
    assert source.skipped == []


def test_telemetry_is_merged_with_the_frames_in_time_order_up_to_the_last_frame(tmp_path):
    root = builders.make_euroc(tmp_path / "euroc", count=5)  # frames every 50 ms, IMU every 5 ms
    items = list(open_source(str(root), max_frames=3).items)
    stamps = [item.timestamp for item in items]
    frames = [item for item in items if isinstance(item, Frame)]
    assert stamps == sorted(stamps) and len(frames) == 3
    assert sum(isinstance(item, ImuSample) for item in items) == 21  # 0 to 100 ms inclusive, the third frame's time
    assert stamps[-1] == frames[-1].timestamp


def test_a_video_needs_a_camera_and_a_profile_is_scaled_to_its_size(tmp_path):
    video = builders.make_video(tmp_path / "video", count=4)
    with pytest.raises(EvpError, match="no calibration in the dataset; give --camera"):
        open_source(str(video))
    source = open_source(str(video), camera_spec="nexus5x_640x380")
    nexus = load_profile("nexus5x_640x380")
    assert (source.camera.width, source.camera.height) == (240, 180) and not source.lossless
    assert source.camera.fx == pytest.approx(nexus.fx * 240 / 640)
    assert len(list(source.items)) == 4


def test_a_camera_that_cannot_be_opened_is_a_clear_error():
    with pytest.raises(EvpError, match="camera:97: cannot open"):
        open_source("camera:97")


def test_telemetry_becomes_protocol_messages_and_unknown_values_are_left_out():
    imu = telemetry_message(ImuSample(1.5, (0.1, 0.2, 0.3), (0.0, 0.0, 9.81)))
    assert isinstance(imu, ImuTelemetry) and imu.gyro_rad_s == [0.1, 0.2, 0.3] and imu.accel_m_s2 == [0.0, 0.0, 9.81]
    gps = telemetry_message(GpsFix(2.0, 3.3745, -76.5331, 980.0, math.nan, math.nan))
    assert isinstance(gps, GpsTelemetry) and (gps.latitude_deg, gps.altitude_m) == (3.3745, 980.0)
    assert gps.horizontal_accuracy_m is None
    baro = telemetry_message(BaroSample(2.5, 90_000.0))
    assert isinstance(baro, BaroTelemetry) and baro.pressure_pa == 90_000.0
    assert baro.altitude_m is None
    assert telemetry_message(WifiScan(3.0, {"aa:bb": -60.0})).rssi_dbm == {"aa:bb": -60.0}
    assert telemetry_message(RangeSample(3.5, 2.0)).distance_m == 2.0  # the marker autopilot's sonar
    assert telemetry_message(RangeSample(3.6, math.nan)) is None  # out of range: no reading to send
