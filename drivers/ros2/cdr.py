"""Batches of ``geometry_msgs/msg/WrenchStamped`` as ROS 2 CDR bytes, one numpy record per message.

At 7 kHz one Python object per message costs more than the rest of the monitor (Cyclone DDS's Python serializer:
tens of µs each), so the wrench topics are encoded in one numpy operation per batch. With a fixed ``frame_id``
every WrenchStamped has the same layout (plain CDR, XCDR1 little endian, alignment counted from the end of the
4-byte encapsulation header)::

    00 01 00 00          encapsulation: CDR, little endian
    int32  sec           header.stamp (builtin_interfaces/Time)
    uint32 nanosec
    uint32 len           header.frame_id: length with its NUL, the characters, the NUL
    char[len]
    pad to 8             (the float64s that follow are 8-aligned)
    float64[6]           wrench.force x y z, wrench.torque x y z

so a structured array of N such records, turned into bytes, is N messages back to back. Identical, byte for byte,
to :meth:`drivers.ros2.messages.WrenchStamped.serialize` (tests/test_ros2.py checks it, and decodes the bytes with
rosbags' own CDR deserializer).
"""

from __future__ import annotations

import numpy as np

CDR_LE_HEADER = b"\x00\x01\x00\x00"
"""The encapsulation header of plain CDR, little endian (what every ROS 2 middleware writes)."""
NS_PER_S = 1_000_000_000


def stamp_parts(stamp_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split UNIX times in integer nanoseconds (N,) into builtin_interfaces/Time's (sec, nanosec)."""
    return np.divmod(np.asarray(stamp_ns, dtype=np.int64), NS_PER_S)


class WrenchStampedEncoder:
    """Encodes batches of WrenchStamped with one ``frame_id`` (module docstring)."""

    def __init__(self, frame_id: str) -> None:
        text = frame_id.encode("utf-8") + b"\x00"
        strlen = len(text)
        end_of_string = 4 + 4 + 4 + strlen  # offsets after the encapsulation header
        padding = (-end_of_string) % 8
        self.frame_id = frame_id
        self.dtype = np.dtype([("encapsulation", "V4"), ("sec", "<i4"), ("nanosec", "<u4"), ("strlen", "<u4"),
                               ("frame_id", f"V{strlen + padding}"), ("wrench", "<f8", (6,))])
        self._frame = np.void(text + b"\x00" * padding)
        self._strlen = strlen
        self.size = self.dtype.itemsize
        """Bytes of one message (encapsulation header included)."""
        self._blank = self._blank_records(16)
        """Records with the fields every message shares (encapsulation, frame_id) set: copied, then stamped and
        filled (grown when a batch needs more)."""
        self._buffer = self._blank_records(16)
        """:meth:`encode_pairs`' records, stamped and filled in place (the shared fields never change; the bytes are
        copied out by ``tobytes``): no copy of the blank records per read. One thread at a time."""

    def _blank_records(self, count: int) -> np.ndarray:
        out = np.zeros(count, dtype=self.dtype)
        out["encapsulation"] = np.void(CDR_LE_HEADER)
        out["strlen"] = self._strlen
        out["frame_id"] = self._frame
        return out

    def records(self, stamp_ns: np.ndarray, wrench: np.ndarray) -> np.ndarray:
        """The messages as a structured array (N,) of :attr:`dtype`: UNIX stamps (N,) ns and wrenches (N, 6) [N, N·m]."""
        wrench = np.asarray(wrench, dtype=float).reshape(-1, 6)
        if len(wrench) > len(self._blank):
            self._blank = self._blank_records(2 * len(wrench))
        out = self._blank[:len(wrench)].copy()
        out["sec"], out["nanosec"] = stamp_parts(stamp_ns)
        out["wrench"] = wrench
        return out

    def encode(self, stamp_ns: np.ndarray, wrench: np.ndarray) -> list[bytes]:
        """Return one serialized message (bytes, encapsulation header first) per row of ``wrench``."""
        data = self.records(stamp_ns, wrench).tobytes()
        size = self.size
        return [data[i:i + size] for i in range(0, len(data), size)]

    def encode_pairs(self, stamp_ns: np.ndarray, wrenches: np.ndarray) -> tuple[list[bytes], list[bytes]]:
        """:meth:`encode` of ``wrenches[:, :6]`` and of ``wrenches[:, 6:]`` ((M, 12): two topics' messages of the
        same stamps, e.g. raw and compensated), in one batch of 2M records written into a preallocated buffer."""
        wrenches = np.asarray(wrenches, dtype=float)
        count = len(wrenches)
        if 2 * count > len(self._buffer):
            self._buffer = self._blank_records(4 * count)
        out = self._buffer[:2 * count].reshape(count, 2)  # (M, 2): each stamp's two records side by side
        sec, nanosec = stamp_parts(stamp_ns)
        out["sec"], out["nanosec"] = sec[:, None], nanosec[:, None]
        out["wrench"] = wrenches.reshape(count, 2, 6)
        data, size = out.tobytes(), self.size
        return ([data[i:i + size] for i in range(0, len(data), 2 * size)],
                [data[i:i + size] for i in range(size, len(data), 2 * size)])


__all__ = ["WrenchStampedEncoder", "stamp_parts", "CDR_LE_HEADER", "NS_PER_S"]
