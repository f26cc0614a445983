"""ROS 2 bags as MCAP files (what rosbag2 writes since Iron; ``ros2 bag play``, Foxglove and PlotJuggler open them).

An MCAP file with the ``ros2`` profile; one schema per message type (encoding ``ros2msg``, the full definition with
its nested types: :data:`drivers.ros2.messages.DEFINITIONS`, named ``pkg/msg/Type``); one channel per topic
(message encoding ``cdr``, the bytes a ROS 2 publisher sends: :mod:`drivers.ros2.cdr`); metadata records for what is
not a message. Written through ``mcap``'s writer (zstd-compressed chunks, indexed, with a summary), into a temporary
file renamed into place by :meth:`BagWriter.close`: a run stopped by a fault leaves no half-written bag.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from mcap.writer import CompressionType, Writer

from drivers.ros2.messages import DEFINITIONS

ROS_DISTRIBUTION = "jazzy"
"""The ``ROS_DISTRO`` rosbag2 records in a bag's header (the message definitions are the same in Humble)."""


class BagWriter:
    """Writes ROS 2 messages to ``path`` (an MCAP file); see the module docstring. Not thread-safe: one writer
    thread."""

    def __init__(self, path: str | os.PathLike, compression: CompressionType = CompressionType.ZSTD) -> None:
        self.path = Path(path)
        fd, temporary = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".part", dir=self.path.parent or ".")
        self._temporary = Path(temporary)
        self._handle = os.fdopen(fd, "wb")
        self._writer = Writer(self._handle, compression=compression)
        self._writer.start(profile="ros2", library=f"ftacq ({ROS_DISTRIBUTION} message definitions)")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        self.messages = 0
        self._closed = False

    def channel(self, topic: str, ros_type: str) -> int:
        """The channel id of ``topic`` (registered with its type's schema on first use)."""
        channel_id = self._channels.get(topic)
        if channel_id is None:
            schema_id = self._schemas.get(ros_type)
            if schema_id is None:
                schema_id = self._schemas[ros_type] = self._writer.register_schema(
                    name=ros_type, encoding="ros2msg", data=DEFINITIONS[ros_type].encode("utf-8"))
            channel_id = self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schema_id)
            self._sequence[channel_id] = 0
        return channel_id

    def write(self, topic: str, ros_type: str, data: list[bytes], stamp_ns: list[int]) -> None:
        """Add serialized messages (CDR with its encapsulation header) with their stamps (UNIX ns: the messages'
        log and publish times)."""
        channel_id = self.channel(topic, ros_type)
        sequence = self._sequence[channel_id]
        add = self._writer.add_message
        for message, time_ns in zip(data, stamp_ns):
            sequence += 1
            add(channel_id=channel_id, log_time=time_ns, data=message, publish_time=time_ns, sequence=sequence)
        self._sequence[channel_id] = sequence
        self.messages += len(data)

    def metadata(self, name: str, data: dict[str, str]) -> None:
        """Add a metadata record (name → string pairs)."""
        self._writer.add_metadata(name, data)

    def close(self) -> None:
        """Finish the file (summary, index) and rename it into place (safe twice)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
            self._handle.close()
            os.chmod(self._temporary, 0o644 & ~_umask())
            os.replace(self._temporary, self.path)
        except BaseException:
            self.discard()
            raise

    def discard(self) -> None:
        """Close and remove the temporary file without finishing it (a run that failed)."""
        self._closed = True
        if not self._handle.closed:
            self._handle.close()
        self._temporary.unlink(missing_ok=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


__all__ = ["BagWriter", "ROS_DISTRIBUTION"]
