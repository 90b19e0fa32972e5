"""Write ROS 2 (CDR) messages into a standalone MCAP file that Foxglove and rosbags open."""

from __future__ import annotations

from pathlib import Path

from mcap.records import Channel, Message, Schema
from mcap.writer import Writer

from evp.io.ros_messages import ROS2


class McapRecorder:
    """Append-only MCAP writer: ``write(topic, msgtype, msg, log_time_s)``; ``close()`` finishes.

    ``durable``: no chunks, each message handed to the OS when written, so a killed process loses
    nothing already written (the file then lacks its summary; ``evp.station.recording`` repairs it).
    """

    def __init__(self, path: str | Path, durable: bool = False):
        self.path = Path(path)
        self.durable = durable
        self._file = self.path.open("wb")
        self._writer = Writer(self._file, use_chunking=not durable)
        self._writer.start(profile="ros2", library="evp")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence = 0

    def _channel(self, topic: str, msgtype: str, definition: bytes | None = None) -> int:
        if topic not in self._channels:
            if msgtype not in self._schemas:
                if definition is None:
                    definition = ROS2.generate_msgdef(msgtype, ros_version=2)[0].encode()
                self._schemas[msgtype] = self._writer.register_schema(name=msgtype, encoding="ros2msg", data=definition)
            self._channels[topic] = self._writer.register_channel(topic=topic, message_encoding="cdr", schema_id=self._schemas[msgtype])
        return self._channels[topic]

    def write(self, topic: str, msgtype: str, msg, log_time_s: float) -> None:
        stamp = int(round(log_time_s * 1e9))
        self._add(self._channel(topic, msgtype), stamp, stamp, ROS2.serialize_cdr(msg, msgtype))

    def write_raw(self, record: tuple[Schema, Channel, Message]) -> None:
        """Copy a message read from another file of ours (schema, channel, message records)."""
        schema, channel, message = record
        self._add(self._channel(channel.topic, schema.name, schema.data), message.log_time, message.publish_time, message.data)

    def _add(self, channel: int, log_time: int, publish_time: int, data: bytes) -> None:
        self._writer.add_message(channel_id=channel, log_time=log_time, publish_time=publish_time, sequence=self._sequence, data=data)
        self._sequence += 1
        if self.durable:
            self._file.flush()

    def close(self) -> None:
        self._writer.finish()
        self._file.close()

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
