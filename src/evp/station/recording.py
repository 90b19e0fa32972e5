"""One MCAP file per session: images, camera info, telemetry, poses and every other message.

Images keep the bytes the phone sent (CompressedImage for JPEG/PNG, Image for raw), so a replay
feeds the estimator exactly what it saw live. Typed topics (Imu, NavSatFix, FluidPressure,
PoseStamped, and each pose as the ``evp_map -> camera`` transform on ``/tf``, where Foxglove's 3-D
panel places the camera and its images) open in Foxglove; messages without a standard type
(wheel, WiFi, config, enable, logs) are kept verbatim as JSON strings on ``/evp/messages``.

While a session is live its file is a journal: unchunked and flushed per message, so a killed
station loses nothing it acknowledged (``repair`` closes such a file). When the session closes,
the journal is rewritten (:func:`compact`) chunked, zstd-compressed and indexed, what Foxglove and
the ``mcap`` library's indexed reader seek in, and swapped in atomically. Files and their folder
are readable by the station's user only.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from evp.io.mcap_writer import McapRecorder
from evp.io.ros_messages import (
    COMPRESSED_IMAGE,
    IMAGE,
    IMU,
    NAVSAT,
    PRESSURE,
    ROS2,
    baro_to_msg,
    camera_info_to_msg,
    gps_to_msg,
    imu_to_msg,
)
from evp.station.protocol import (
    RAW_CHANNELS,
    BaroTelemetry,
    GpsTelemetry,
    ImageMessage,
    ImuBatchTelemetry,
    ImuTelemetry,
    Pose,
    telemetry_record,
    telemetry_records,
)
from evp.types import CameraModel

STRING = "std_msgs/msg/String"
POSE = "geometry_msgs/msg/PoseStamped"
TOPIC_IMAGE_COMPRESSED = "/camera/image/compressed"
TOPIC_IMAGE_RAW = "/camera/image"
TOPIC_CAMERA_INFO = "/camera/camera_info"
TOPIC_POSE = "/evp/pose"
TOPIC_TF = "/tf"
TF = "tf2_msgs/msg/TFMessage"
MAP_FRAME, CAMERA_FRAME = "evp_map", "camera"
TOPIC_MESSAGES = "/evp/messages"
RAW_ROS_ENCODING = {"gray8": "mono8", "bgr8": "bgr8", "rgb8": "rgb8"}


def _header(timestamp: float, frame_id: str):
    sec = int(math.floor(timestamp))
    stamp = ROS2.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=min(int(round((timestamp - sec) * 1e9)), 999_999_999))
    return ROS2.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


class SessionRecording:
    """Appends one session's stream to its MCAP file (continuing an earlier file when resumed)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.path.parent.chmod(0o700)
        earlier = None
        if self.path.exists():
            earlier = self.path.with_suffix(".mcap.old")
            self.path.replace(earlier)
        self._recorder = McapRecorder(self.path, durable=True)
        self.path.chmod(0o600)
        self.carried_over = 0  # messages copied from the earlier file
        if earlier is not None:
            for message in read_messages(earlier):
                self._recorder.write_raw(message)
                self.carried_over += 1
            earlier.unlink()

    def image(self, message: ImageMessage, received_at: float) -> None:
        header = _header(message.timestamp, "camera")
        if message.encoding in RAW_CHANNELS:
            channels = RAW_CHANNELS[message.encoding]
            msg = ROS2.types[IMAGE](
                header=header,
                height=message.height,
                width=message.width,
                encoding=RAW_ROS_ENCODING[message.encoding],
                is_bigendian=0,
                step=message.width * channels,
                data=np.frombuffer(message.payload, dtype=np.uint8),
            )
            self._recorder.write(TOPIC_IMAGE_RAW, IMAGE, msg, received_at)
        else:
            msg = ROS2.types[COMPRESSED_IMAGE](header=header, format=message.encoding, data=np.frombuffer(message.payload, dtype=np.uint8))
            self._recorder.write(TOPIC_IMAGE_COMPRESSED, COMPRESSED_IMAGE, msg, received_at)

    def camera(self, camera: CameraModel, received_at: float) -> None:
        self._recorder.write(TOPIC_CAMERA_INFO, "sensor_msgs/msg/CameraInfo", camera_info_to_msg(ROS2, received_at, camera), received_at)

    def telemetry(self, message, raw_text: str, received_at: float) -> None:
        """Typed topic where ROS has a type; every telemetry message also verbatim on /evp/messages."""
        if isinstance(message, ImuTelemetry | ImuBatchTelemetry):
            for record in telemetry_records(message):  # a batch's samples each on /imu, as a dataset reader reads them
                self._recorder.write("/imu", IMU, imu_to_msg(ROS2, record), received_at)
        elif isinstance(message, GpsTelemetry):
            self._recorder.write("/gps/fix", NAVSAT, gps_to_msg(ROS2, telemetry_record(message)), received_at)
        elif isinstance(message, BaroTelemetry):
            self._recorder.write("/baro", PRESSURE, baro_to_msg(ROS2, telemetry_record(message)), received_at)
        self.text(raw_text, received_at)

    def text(self, raw_text: str, received_at: float) -> None:
        self._recorder.write(TOPIC_MESSAGES, STRING, ROS2.types[STRING](data=raw_text), received_at)

    def pose(self, pose: Pose, sent_at: float) -> None:
        types = ROS2.types
        position = types["geometry_msgs/msg/Point"](x=pose.t[0], y=pose.t[1], z=pose.t[2])
        orientation = types["geometry_msgs/msg/Quaternion"](w=pose.q[0], x=pose.q[1], y=pose.q[2], z=pose.q[3])
        msg = types[POSE](header=_header(pose.timestamp, MAP_FRAME), pose=types["geometry_msgs/msg/Pose"](position=position, orientation=orientation))
        self._recorder.write(TOPIC_POSE, POSE, msg, sent_at)
        translation = types["geometry_msgs/msg/Vector3"](x=pose.t[0], y=pose.t[1], z=pose.t[2])
        transform = types["geometry_msgs/msg/TransformStamped"](
            header=_header(pose.timestamp, MAP_FRAME),
            child_frame_id=CAMERA_FRAME,
            transform=types["geometry_msgs/msg/Transform"](translation=translation, rotation=orientation),
        )
        self._recorder.write(TOPIC_TF, TF, types[TF](transforms=[transform]), sent_at)

    def close(self) -> None:
        """Finish the journal, then compact it (chunked, compressed, indexed)."""
        self._recorder.close()
        compact(self.path)


def compact(path: Path) -> None:
    """Rewrite a recording chunked, zstd-compressed and indexed, replacing it atomically: a station
    killed meanwhile leaves the journal whole (and a ``.mcap.tmp`` that start-up removes)."""
    path = Path(path)
    temporary = path.with_suffix(".mcap.tmp")
    with McapRecorder(temporary) as recorder:  # the mcap writer's defaults: 1 MiB zstd chunks, every index
        temporary.chmod(0o600)
        for message in read_messages(path):
            recorder.write_raw(message)
    with temporary.open("rb") as handle:
        os.fsync(handle.fileno())
    temporary.replace(path)


def read_messages(path: Path) -> Iterator[tuple[Schema, Channel, Message]]:
    """Every complete message of a recording, also of one cut off by a killed station."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    with Path(path).open("rb") as handle:
        try:
            for record in StreamReader(handle).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message) and record.channel_id in channels:
                    channel = channels[record.channel_id]
                    yield schemas[channel.schema_id], channel, record
        except (McapError, EOFError, ValueError):
            return  # a truncated last record: everything before it was yielded


def decoded_messages(path: Path, topics: set[str] | None = None) -> Iterator[tuple[str, int, object]]:
    """(topic, log time in nanoseconds, deserialised ROS 2 message), in file order."""
    for schema, channel, message in read_messages(path):
        if topics is None or channel.topic in topics:
            yield channel.topic, message.log_time, ROS2.deserialize_cdr(message.data, schema.name)


def has_summary(path: Path) -> bool:
    with Path(path).open("rb") as handle:
        try:
            make_reader(handle).get_summary()
        except (McapError, EOFError, ValueError, OSError):
            return False
    return True


def repair(path: Path) -> int:
    """Rewrite a recording that lacks its summary (station killed); returns the messages kept."""
    recording = SessionRecording(path)
    recording.close()
    return recording.carried_over
