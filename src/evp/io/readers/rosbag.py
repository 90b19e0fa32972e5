"""ROS 1 bags, ROS 2 bag folders (sqlite3 or MCAP storage) and standalone MCAP files.

Read through ``rosbags`` (no ROS installation needed). Topics are picked by message type:
Image / CompressedImage (the topic with most messages), CameraInfo (calibration), Imu,
NavSatFix, FluidPressure. Times are the message header stamps (sensor clock).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError

from evp.errors import DatasetError
from evp.io.dataset import Dataset
from evp.io.ros_messages import (
    CAMERA_INFO,
    COMPRESSED_IMAGE,
    IMAGE,
    IMU,
    NAVSAT,
    PRESSURE,
    ROS2,
    msg_to_baro,
    msg_to_camera,
    msg_to_gps,
    msg_to_image,
    msg_to_imu,
    stamp_seconds,
)
from evp.types import Frame

IMAGE_TYPES = {IMAGE, COMPRESSED_IMAGE}


# what each file kind starts with: rosbags reads past a wrong one into a UnicodeDecodeError
MAGIC = {".bag": b"#ROSBAG V2.0\n", ".mcap": b"\x89MCAP0\r\n"}


def _open(path: Path) -> AnyReader:
    magic = MAGIC.get(path.suffix.lower()) if path.is_file() else None
    if magic is not None:
        with path.open("rb") as handle:
            start = handle.read(len(magic))
        if start != magic:
            kind = "ROS 1 bag" if path.suffix.lower() == ".bag" else "MCAP file"
            raise AnyReaderError(f"not a {kind} (it starts with {start[:8]!r}, not {magic!r})")
    return AnyReader([path], default_typestore=ROS2)


def _messages(path: Path, types: set[str], topic: str | None = None):
    """(connection, deserialised message) for every message of the given types (or topic)."""
    try:
        with _open(path) as reader:
            connections = [c for c in reader.connections if c.msgtype in types and (topic is None or c.topic == topic)]
            for connection, _, raw in reader.messages(connections=connections):
                try:
                    yield connection, reader.deserialize(raw, connection.msgtype)
                except Exception as exc:  # rosbags raises assorted errors on bad payloads
                    raise DatasetError(path, f"cannot decode {connection.msgtype} message: {exc}", record=connection.topic) from exc
    except AnyReaderError as exc:
        raise DatasetError(path, f"cannot read bag: {exc}") from exc


class RosbagReader:
    name = "rosbag"
    description = "ROS 1 .bag, ROS 2 bag folder (metadata.yaml) or .mcap file (Image, CompressedImage, CameraInfo, Imu, NavSatFix, FluidPressure)"
    looks_for = "a .bag or .mcap file, or a folder with metadata.yaml (ROS 2 bag)"

    def detect(self, path: Path) -> bool:
        if path.is_file():
            return path.suffix.lower() in (".bag", ".mcap")
        return path.is_dir() and (path / "metadata.yaml").is_file()

    def read(self, path: Path) -> Dataset:
        try:
            with _open(path) as reader:
                counts = Counter({c.topic: c.msgcount for c in reader.connections if c.msgtype in IMAGE_TYPES})
        except AnyReaderError as exc:
            raise DatasetError(path, f"cannot read bag: {exc}") from exc
        dataset = Dataset(path.stem, self.name, path)
        image_topic = counts.most_common(1)[0][0] if counts else None
        if len(counts) > 1:
            dataset.notes.append(f"image topic {image_topic} chosen among {sorted(counts)}")
        times = []
        for connection, msg in _messages(path, IMAGE_TYPES | {CAMERA_INFO, IMU, NAVSAT, PRESSURE}):
            kind = connection.msgtype
            if kind in IMAGE_TYPES and connection.topic == image_topic:
                times.append(stamp_seconds(msg.header))
            elif kind == CAMERA_INFO and dataset.camera is None:
                dataset.camera = msg_to_camera(msg, path)
            elif kind == IMU:
                dataset.imu.append(msg_to_imu(msg))
            elif kind == NAVSAT:
                fix = msg_to_gps(msg)
                if fix is not None:
                    dataset.gps.append(fix)
            elif kind == PRESSURE:
                dataset.baro.append(msg_to_baro(msg))
        for records in (dataset.imu, dataset.gps, dataset.baro):
            records.sort(key=lambda r: r.timestamp)
        dataset.frame_times = np.array(times)
        if image_topic:
            dataset.load_frames = lambda errors=None: self._frames(path, image_topic, errors)
            dataset.notes.append(f"images from {image_topic}")
        if image_topic and dataset.camera is None:
            dataset.notes.append("no CameraInfo topic: no calibration in the bag")
        return dataset

    @staticmethod
    def _frames(path: Path, topic: str, errors: list[DatasetError] | None) -> Iterator[Frame]:
        for index, (connection, msg) in enumerate(_messages(path, IMAGE_TYPES, topic)):
            image = msg_to_image(msg, connection.msgtype)
            if image is None:
                error = DatasetError(path, f"image message {index} on {topic} cannot be decoded", record=str(index))
                if errors is None:
                    raise error
                errors.append(error)
                continue
            yield Frame(stamp_seconds(msg.header), image, index, f"{path}:{topic}#{index}")
