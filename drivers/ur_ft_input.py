"""A minimal RTDE client that owns a UR controller's ``external_force_torque`` input and writes it once per
controller cycle (:class:`URForceTorqueInput`).

Why not ur-rtde's own call (verified against the ur-rtde 1.6.5 wheel, docs/bridge.md "ur-rtde 1.6.5"):
``RTDEControlInterface.setExternalForceTorque`` sends command 55 on input recipe 21 with 52 of the recipe's 56
bytes, and the control script it uploads has no branch for 55, so it returns True and nothing reaches
``external_force_torque``; that input belongs to the control interface's recipe 23 unless the interface is opened
with ``FLAG_NO_EXT_FT``. This client takes the input instead, on its own RTDE connection:

- setup: ``V`` (protocol 2), ``v`` (controller version), ``O`` at the controller's rate (500 Hz e-Series, 125 Hz
  CB3) with :data:`OUTPUTS` (the output stream is the controller-cycle clock, and it carries ``actual_q`` for the
  compensation and ``actual_TCP_force`` for ``ftacq bridge --check``), ``I external_force_torque``, ``S``;
- then one input package (recipe id + 6 big-endian doubles) per output package received.

Every read has a deadline (connect, each setup reply, each controller cycle). A controller that gives the input to
another client answers ``IN_USE`` (RTDE guide: only one client may control a variable at a time):
:class:`ExternalInputInUseError` says who usually holds it.
"""

from __future__ import annotations

import select
import socket
import struct
import time
from dataclasses import dataclass

import numpy as np

from drivers.ur_connection import state_rate_hz
from ftacq.errors import DeviceConnectionError, DeviceError, DeviceTimeoutError

RTDE_PORT = 30004
PROTOCOL_VERSION = 2
INPUT_NAME = "external_force_torque"
OUTPUTS = ("timestamp", "actual_q", "actual_qd", "actual_TCP_force", "runtime_state", "safety_status_bits",
           "actual_TCP_pose", "target_qd", "target_qdd")
"""Output recipe: controller time (s), joint angles (rad) and speeds (rad/s), TCP wrench (N, N·m), program state,
safety bits, TCP pose (m, rotation vector), target joint speeds (rad/s) and accelerations (rad/s², for the tool's
inertial wrench). All in every controller version that has ``external_force_torque`` (RTDE guide)."""
CONNECT_TIMEOUT_S = 2.0
REPLY_TIMEOUT_S = 2.0
CYCLE_TIMEOUT_S = 0.1
"""No output package for this long is a lost controller (UR's own watchdog for the input is 0.1 s too)."""

_TYPES = {"BOOL": ("?", 1), "UINT8": ("B", 1), "UINT32": ("I", 1), "INT32": ("i", 1), "UINT64": ("Q", 1),
          "DOUBLE": ("d", 1), "VECTOR3D": ("d", 3), "VECTOR6D": ("d", 6), "VECTOR6INT32": ("i", 6),
          "VECTOR6UINT32": ("I", 6)}
_HEADER = struct.Struct(">HB")
_V, _v, _M, _O, _I, _S, _P, _U = (ord(c) for c in "VvMOISPU")


class ExternalInputInUseError(DeviceError):
    """The controller gave ``external_force_torque`` to another client (answered IN_USE)."""


@dataclass(frozen=True)
class ControllerCycle:
    """One output package: controller time (s), q (rad), q̇ (rad/s), actual_TCP_force (N, N·m, base axes about
    the TCP), runtime_state, safety_status_bits, actual_TCP_pose [x, y, z (m), rx, ry, rz (rad)], the host
    monotonic time it arrived (s), target q̇ (rad/s) and target q̈ (rad/s²)."""

    timestamp_s: float
    q: np.ndarray
    qd: np.ndarray
    tcp_force: np.ndarray
    runtime_state: int
    safety_status_bits: int
    received_s: float
    tcp_pose: np.ndarray
    target_qd: np.ndarray
    target_qdd: np.ndarray


class URForceTorqueInput:
    """Owner of ``external_force_torque`` on ``host``: :meth:`start`, then per cycle :meth:`next_cycle` and
    :meth:`write`; :meth:`close` (or ``with``). Not thread-safe: one thread reads and writes."""

    def __init__(self, host: str, *, frequency_hz: float | None = None, port: int = RTDE_PORT,
                 connect_timeout_s: float = CONNECT_TIMEOUT_S, reply_timeout_s: float = REPLY_TIMEOUT_S) -> None:
        self.host, self.port = host, port
        self.requested_frequency_hz = frequency_hz
        self.connect_timeout_s, self.reply_timeout_s = connect_timeout_s, reply_timeout_s
        self.version: tuple[int, int, int, int] | None = None
        self.frequency_hz = 0.0
        self._sock: socket.socket | None = None
        self._buffer = bytearray()
        self._input_id = 0
        self._output_codec: struct.Struct | None = None
        self._input_codec = struct.Struct(">B6d")
        self.packages_written = 0

    # ------------------------------------------------------------------ life cycle
    def start(self) -> "URForceTorqueInput":
        """Connect and set up; raises DeviceConnectionError / DeviceTimeoutError / ExternalInputInUseError."""
        try:
            self._sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout_s)
        except socket.timeout as error:
            raise DeviceTimeoutError(f"robot controller {self.host}: no answer on RTDE port {self.port} within "
                                     f"{self.connect_timeout_s:g} s") from error
        except OSError as error:
            raise DeviceConnectionError(f"robot controller {self.host}: cannot connect to RTDE port {self.port} "
                                        f"({error.strerror or error})") from error
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            self._setup()
        except BaseException:
            self.close()
            raise
        return self

    def __enter__(self) -> "URForceTorqueInput":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection (the controller then frees the input). Safe to call twice."""
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.close()
            except OSError:
                pass

    @property
    def cycle_s(self) -> float:
        return 1.0 / self.frequency_hz if self.frequency_hz else 0.0

    # ------------------------------------------------------------------ setup
    def _setup(self) -> None:
        reply = self._request(_V, struct.pack(">H", PROTOCOL_VERSION))
        if not reply or reply[0] != 1:
            raise DeviceError(f"robot controller {self.host}: refused RTDE protocol version {PROTOCOL_VERSION}")
        reply = self._request(_v)
        if len(reply) < 16:
            raise DeviceError(f"robot controller {self.host}: malformed version reply ({len(reply)} bytes)")
        self.version = struct.unpack(">IIII", reply[:16])
        self.frequency_hz = float(self.requested_frequency_hz or state_rate_hz(self.version))
        reply = self._request(_O, struct.pack(">d", self.frequency_hz) + ",".join(OUTPUTS).encode("ascii"))
        types = reply[1:].decode("ascii", "replace").split(",")
        if len(types) != len(OUTPUTS) or any(t not in _TYPES for t in types):
            missing = [name for name, t in zip(OUTPUTS, types) if t not in _TYPES]
            raise DeviceError(f"robot controller {self.host}: RTDE outputs not available: {missing or types}")
        fmt = ">B" + "".join(_TYPES[t][0] * _TYPES[t][1] for t in types)
        self._output_codec = struct.Struct(fmt)
        reply = self._request(_I, INPUT_NAME.encode("ascii"))
        answer = reply[1:].decode("ascii", "replace")
        if "IN_USE" in answer:
            raise ExternalInputInUseError(
                f"robot controller {self.host}: another client already writes '{INPUT_NAME}' (controller answered "
                "IN_USE). Usually ur-rtde's RTDEControlInterface opened without FLAG_NO_EXT_FT, a URCap of an "
                "F/T sensor, or a second ftacq bridge. Close it, or open the control interface with FLAG_NO_EXT_FT")
        if answer != "VECTOR6D" or reply[0] == 0:
            raise DeviceError(f"robot controller {self.host}: RTDE input '{INPUT_NAME}' not available "
                              f"(answer {answer!r}; needs software 3.3 or newer)")
        self._input_id = reply[0]
        reply = self._request(_S)
        if not reply or reply[0] != 1:
            raise DeviceError(f"robot controller {self.host}: refused to start RTDE synchronisation")

    def _request(self, package_type: int, payload: bytes = b"") -> bytes:
        """Send one setup request and return the payload of its reply (text messages in between are skipped)."""
        self._send(package_type, payload)
        deadline = time.monotonic() + self.reply_timeout_s
        while True:
            reply_type, body = self._read_package(deadline, what=f"the reply to '{chr(package_type)}'")
            if reply_type == package_type:
                return body

    # ------------------------------------------------------------------ wire
    def _send(self, package_type: int, payload: bytes) -> None:
        if self._sock is None:
            raise DeviceConnectionError(f"robot controller {self.host}: RTDE input not connected")
        try:
            self._sock.sendall(_HEADER.pack(_HEADER.size + len(payload), package_type) + payload)
        except OSError as error:
            raise DeviceConnectionError(f"robot controller {self.host}: RTDE connection lost ({error})") from error

    def _read_package(self, deadline: float, what: str) -> tuple[int, bytes]:
        sock = self._sock
        if sock is None:
            raise DeviceConnectionError(f"robot controller {self.host}: RTDE input not connected")
        buffer = self._buffer
        while True:
            if len(buffer) >= 3:
                size, package_type = _HEADER.unpack_from(buffer)
                if size < 3:
                    raise DeviceError(f"robot controller {self.host}: malformed RTDE package (size {size})")
                if len(buffer) >= size:
                    body = bytes(buffer[3:size])
                    del buffer[:size]
                    return package_type, body
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeoutError(f"robot controller {self.host}: no RTDE data for {what}")
            sock.settimeout(remaining)
            try:
                chunk = sock.recv(65536)
            except socket.timeout as error:
                raise DeviceTimeoutError(f"robot controller {self.host}: no RTDE data for {what}") from error
            except OSError as error:
                raise DeviceConnectionError(f"robot controller {self.host}: RTDE connection lost ({error})") from error
            if not chunk:
                raise DeviceConnectionError(f"robot controller {self.host}: the controller closed the RTDE connection")
            buffer += chunk

    # ------------------------------------------------------------------ cycle
    def next_cycle(self, timeout_s: float = CYCLE_TIMEOUT_S) -> ControllerCycle:
        """Wait for the next output package (one controller cycle). Packages are returned in order, none skipped:
        a caller that fell behind answers each queued cycle at once and so catches up."""
        deadline = time.monotonic() + timeout_s
        body = None
        while body is None:
            package_type, payload = self._read_package(deadline, what=f"{timeout_s * 1000:.0f} ms (controller cycle)")
            if package_type == _U:
                body = payload
        received_s = time.monotonic()
        codec = self._output_codec
        assert codec is not None
        if len(body) != codec.size:
            raise DeviceError(f"robot controller {self.host}: RTDE data package of {len(body)} bytes, expected "
                              f"{codec.size}")
        values = codec.unpack(body)
        return ControllerCycle(timestamp_s=values[1], q=np.array(values[2:8]), qd=np.array(values[8:14]),
                               tcp_force=np.array(values[14:20]), runtime_state=int(values[20]),
                               safety_status_bits=int(values[21]), received_s=received_s,
                               tcp_pose=np.array(values[22:28]), target_qd=np.array(values[28:34]),
                               target_qdd=np.array(values[34:40]))

    def queued(self) -> bool:
        """True when bytes of a newer package are already here (in this client's buffer or readable on the socket):
        the cycle :meth:`next_cycle` returned last is not the controller's newest. A caller that starts reading
        late (the packages queue from :meth:`start` on) skips those instead of answering them with old values."""
        if self._buffer:
            return True
        sock = self._sock
        if sock is None:
            return False
        readable, _, _ = select.select([sock], [], [], 0.0)
        return bool(readable)

    def write(self, wrench) -> None:
        """Send one ``external_force_torque`` value [Fx, Fy, Fz (N), Tx, Ty, Tz (N·m)]."""
        w = [float(v) for v in wrench]
        if len(w) != 6 or not all(np.isfinite(w)):
            raise ValueError(f"external wrench must be 6 finite numbers, got {wrench!r}")
        self._send(_U, self._input_codec.pack(self._input_id, *w))
        self.packages_written += 1
