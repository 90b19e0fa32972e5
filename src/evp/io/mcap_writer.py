"""Write ROS 2 (CDR) messages into a standalone MCAP file that Foxglove and rosbags open."""

from __future__ import annotations

from pathlib import Path

from mcap.writer import Writer

from evp.io.ros_messages import ROS2


class McapRecorder:
    """Append-only MCAP writer: ``write(topic, msgtype, msg, log_time_s)``; ``close()`` finishes."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._file = self.path.open("wb")
        self._writer = Writer(self._file)
        self._writer.start(profile="ros2", library="evp")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence = 0

    def _channel(self, topic: str, msgtype: str) -> int:
        if topic not in self._channels:
            if msgtype not in self._schemas:
                definition, _ = ROS2.generate_msgdef(msgtype, ros_version=2)
                self._schemas[msgtype] = self._writer.register_schema(name=msgtype, encoding="ros2msg", data=definition.encode())
            self._channels[topic] = self._writer.register_channel(topic=topic, message_encoding="cdr", schema_id=self._schemas[msgtype])
        return self._channels[topic]

    def write(self, topic: str, msgtype: str, msg, log_time_s: float) -> None:
        channel = self._channel(topic, msgtype)
        stamp = int(round(log_time_s * 1e9))
        self._writer.add_message(channel_id=channel, log_time=stamp, publish_time=stamp, sequence=self._sequence, data=ROS2.serialize_cdr(msg, msgtype))
        self._sequence += 1

    def close(self) -> None:
        self._writer.finish()
        self._file.close()

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
