"""What ``evp stream`` can send: a dataset or recording, a video file, a local camera, an MJPEG URL.

Every source gives the camera model and a time-ordered stream of frames and telemetry. Live
sources (camera, URL) are stamped with the local monotonic clock as frames arrive.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from evp.config import RobotSettings
from evp.errors import CalibrationError, DataError, DatasetError
from evp.io.dataset import TelemetryRecord
from evp.types import BaroSample, CameraModel, EncoderCounts, Frame, GpsFix, ImuSample, RangeSample, WheelOdometry, WifiScan


@dataclass
class StreamSource:
    name: str
    camera: CameraModel
    fps: float
    items: Iterator[Frame | TelemetryRecord]
    live: bool  # frames arrive in real time (camera, URL): no pacing needed
    lossless: bool  # the frames are exact (image files): stream them losslessly by default
    skipped: list[DatasetError]  # undecodable frames, skipped and reported at the end
    T_body_cam: np.ndarray | None = None  # the camera in the IMU frame, when the source calibrates it (the station then fuses the IMU)


def _camera_model(spec: str | None, width: int, height: int) -> CameraModel:
    """A calibration file or shipped profile (seed 000's phone by default), scaled to the source's resolution."""
    from evp.calib.profiles import camera_from

    camera = camera_from(spec or "nexus5x_640x380")
    return camera if (camera.width, camera.height) == (width, height) else camera.scaled(width, height)


def _capture_frames(capture: cv2.VideoCapture, max_frames: int | None) -> Iterator[Frame]:
    index = 0
    start = time.monotonic()
    try:
        while max_frames is None or index < max_frames:
            ok, image = capture.read()
            if not ok:
                return
            yield Frame(time.monotonic() - start, image, index=index, source="capture")
            index += 1
    finally:
        capture.release()


def _open_capture(spec: str, camera_spec: str | None, max_frames: int | None) -> StreamSource:
    target: int | str = int(spec.split(":", 1)[1]) if spec.startswith("camera:") else spec
    capture = cv2.VideoCapture(target)
    if not capture.isOpened():
        raise DataError(f"{spec}: cannot open (no such camera, or the URL does not serve a video/MJPEG stream)")
    width, height = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
    fps = capture.get(cv2.CAP_PROP_FPS) or 30.0
    camera = _camera_model(camera_spec, width, height)
    return StreamSource(spec, camera, float(fps), _capture_frames(capture, max_frames), live=True, lossless=False, skipped=[])


def _dataset_items(dataset, max_frames: int | None, errors: list[DatasetError], robot: RobotSettings | None = None) -> Iterator[Frame | TelemetryRecord]:
    """Frames (decoded one at a time) and telemetry merged in time order, up to ``max_frames``;
    with ``robot``, the wheel records go as the encoder counts that robot would send."""
    import heapq
    import itertools
    from dataclasses import replace

    frames = dataset.frames(errors)
    telemetry = dataset.telemetry()
    if robot is not None:
        from evp.mobile.robot import encoder_readings

        telemetry = heapq.merge(replace(dataset, wheel=[]).telemetry(), encoder_readings(dataset.wheel, robot), key=lambda record: record.timestamp)
    if max_frames is not None and max_frames < dataset.num_frames:
        frames = itertools.islice(frames, max_frames)
        end = dataset.frame_times[max_frames - 1]
        telemetry = (t for t in telemetry if t.timestamp <= end)
    return heapq.merge(frames, telemetry, key=lambda record: record.timestamp)


def _first_frame_size(dataset, spec: str) -> tuple[int, int]:
    first = next(iter(dataset.frames()), None)
    if first is None:
        raise DataError(f"{spec}: no frame could be read")
    return first.image.shape[1], first.image.shape[0]


def open_source(
    spec: str, camera_spec: str | None = None, max_frames: int | None = None, fmt: str | None = None, encoder_robot: RobotSettings | None = None
) -> StreamSource:
    """``camera:N`` (local camera N), an http(s)/rtsp URL (MJPEG, e.g. IP Webcam), else a dataset,
    recording or video file (format auto-detected as for ``evp run``). ``encoder_robot``: a
    dataset's wheel records are sent as that robot's encoder counts (a wheel robot's simulator)."""
    if spec.startswith("camera:") or spec.startswith(("http://", "https://", "rtsp://")):
        return _open_capture(spec, camera_spec, max_frames)
    from evp.io.registry import open_dataset

    dataset = open_dataset(Path(spec), fmt)
    if camera_spec:
        # scaled to the images' size: the dataset's calibration's, else the first frame's (a video)
        size = (dataset.camera.width, dataset.camera.height) if dataset.camera else _first_frame_size(dataset, spec)
        camera = _camera_model(camera_spec, *size)
    elif dataset.camera is None:
        raise CalibrationError(spec, "no calibration in the dataset; give --camera FILE or a profile name")
    else:
        camera = dataset.camera
    errors: list[DatasetError] = []
    fps = 30.0
    if dataset.num_frames > 1:
        fps = float(1.0 / np.median(np.diff(dataset.frame_times)))
    lossless = dataset.format != "video"
    # ``errors`` fills as frames are read: undecodable ones are skipped and reported
    items = _dataset_items(dataset, max_frames, errors, encoder_robot)
    return StreamSource(dataset.name, camera, fps, items, live=False, lossless=lossless, skipped=errors, T_body_cam=dataset.T_body_cam)


def telemetry_message(record: TelemetryRecord):
    """The protocol message for a telemetry record, or None for kinds the protocol does not carry."""
    import math

    from evp.station.protocol import BaroTelemetry, EncoderTelemetry, GpsTelemetry, ImuTelemetry, RangeTelemetry, WheelTelemetry, WifiTelemetry

    def optional(value: float) -> float | None:
        return value if math.isfinite(value) else None

    if isinstance(record, ImuSample):
        return ImuTelemetry(timestamp=record.timestamp, gyro_rad_s=list(record.angular_velocity_rad_s), accel_m_s2=list(record.linear_acceleration_m_s2))
    if isinstance(record, GpsFix):
        return GpsTelemetry(
            timestamp=record.timestamp, latitude_deg=record.latitude_deg, longitude_deg=record.longitude_deg, altitude_m=record.altitude_m,
            horizontal_accuracy_m=optional(record.horizontal_accuracy_m), vertical_accuracy_m=optional(record.vertical_accuracy_m),
        )  # fmt: skip
    if isinstance(record, BaroSample):
        return BaroTelemetry(timestamp=record.timestamp, pressure_pa=record.pressure_pa, altitude_m=optional(record.altitude_m))
    if isinstance(record, WheelOdometry):
        return WheelTelemetry(
            timestamp=record.timestamp, wheel_speeds_m_s=list(record.wheel_speeds_m_s),
            forward_speed_m_s=optional(record.forward_speed_m_s), yaw_rate_rad_s=optional(record.yaw_rate_rad_s),
        )  # fmt: skip
    if isinstance(record, EncoderCounts):
        return EncoderTelemetry(timestamp=record.timestamp, counts=list(record.counts), yaw_rate_rad_s=optional(record.yaw_rate_rad_s))
    if isinstance(record, WifiScan):
        return WifiTelemetry(timestamp=record.timestamp, rssi_dbm=dict(record.rssi_dbm))
    if isinstance(record, RangeSample):  # out of range (NaN) is no reading: nothing to send
        return RangeTelemetry(timestamp=record.timestamp, distance_m=record.distance_m) if record.distance_m > 0 else None
    return None
