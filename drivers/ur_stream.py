"""Every RTDE state sample of a UR controller, kept: :class:`URStateStream` (receive only, never moves anything).

ur-rtde's receive interface keeps only the newest state, which a Python thread polling it at the controller's rate
(500 Hz e-Series, 125 Hz CB3) would miss under load. The dynamic model needs all of them (a recorded motion for
identification; q, q̇, q̈ around every sensor sample for live compensation), so this client speaks RTDE itself
(docs/protocols-ur.md, "RTDE framing": protocol version 2, the controller's version and so its rate, one output
recipe, data packages) on its own connection and appends every package, stamped on arrival with the host's
``time.monotonic()``, to a fixed-size ring of numpy rows.

Outputs: ``timestamp`` (the controller's clock, s), ``actual_q``, ``actual_qd``, ``target_qd``, ``target_qdd``
(rad, rad/s, rad/s²).
The controller's timestamp maps onto the host clock through the minimum-delay line of (timestamp, arrival − timestamp)
(:class:`ftacq.timebase.DeviceClock`, the same estimator as the sensor's: it follows the two clocks' rate error,
±200 ppm and more, without ever mapping a state later than it arrived): host times free of receive jitter, also
after hours of streaming. :meth:`URStateStream.window` maps the rows within the clock's window with its newest line;
each row also keeps an offset, known when it arrived and rewritten once :data:`SETTLE_AFTER_S` later, for the rows
older than the window and those of an earlier session. Each read of the socket (often several packages) is parsed, mapped and stored as one numpy batch. Every call has a deadline; a controller that stops sending is
reported by :attr:`stale`.
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time
from dataclasses import dataclass

import numpy as np

from drivers.ur_connection import state_rate_hz
from ftacq.timebase import CLOCK_WINDOW_S, DeviceClock
from ftacq.errors import DeviceConnectionError, DeviceError

log = logging.getLogger(__name__)

RTDE_PORT = 30004
OUTPUTS = ("timestamp", "actual_q", "actual_qd", "target_qd", "target_qdd")
_HEADER = struct.Struct(">HB")
_V, _VERSION, _O, _S, _P, _U, _M = (ord(c) for c in "VvOSPUM")
CONNECT_TIMEOUT_S = 3.0
RECEIVE_TIMEOUT_S = 1.0
"""No package for this long: :attr:`URStateStream.stale` (the reader keeps waiting until closed)."""
JOIN_TIMEOUT_S = 2.0
DEFAULT_CAPACITY = 1 << 18
"""Rows kept (8.7 minutes at 500 Hz, 35 at 125 Hz); older rows are overwritten."""
ROW_COLUMNS = 27
"""Columns of one kept state row: arrival (host s), timestamp (controller s), q (6), q̇ (6), target q̇ (6), target q̈ (6),
offset (host − controller s, as :class:`ftacq.timebase.DeviceClock` knew it when the row arrived)."""
OFFSET_COLUMN = ROW_COLUMNS - 1
SETTLE_AFTER_S = 0.5 * CLOCK_WINDOW_S
"""A row's kept offset is rewritten once, with the line of the packages up to this long after it (controller s):
the packages after a row that waited less correct it too, and the line's window still holds the row; a row older
than the clock's window is mapped with this offset."""
SETTLE_ROWS = 64
"""Rows settled at most per read (a read brings a few packages: the settling keeps up, a backlog catches up)."""
_DATA_PACKAGE = np.dtype([("size", ">u2"), ("type", "u1"), ("recipe", "u1"), ("values", ">f8", (OFFSET_COLUMN - 1,))])
"""One RTDE data package of the output recipe (header, recipe id, the outputs' doubles), as it is on the wire."""


@dataclass(frozen=True)
class StateWindow:
    """Robot samples, oldest first: host times (s, host monotonic clock), q, q̇ (actual), q̇ and q̈ (target) (M, 6)
    (rad, rad/s, rad/s²). ``arrival_s`` are the raw receive stamps, ``controller_time_s`` the controller's own
    timestamps."""

    time_s: np.ndarray
    arrival_s: np.ndarray
    controller_time_s: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    target_qd: np.ndarray

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    @classmethod
    def from_rows(cls, rows: np.ndarray, clock: DeviceClock | None = None) -> "StateWindow":
        """The window of rows laid out as :data:`ROW_COLUMNS` (arrival, timestamp, q, q̇, target q̇, target q̈,
        offset), oldest first, on the host clock: the rows within ``clock``'s window through its newest line (a later
        package that waited less corrects the rows before it too), the older ones (or all, without a clock or with
        timestamps out of order: two controller sessions) as timestamp + the offset known when they arrived."""
        timestamp = rows[:, 1]
        time_s = timestamp + rows[:, OFFSET_COLUMN]
        since = clock.valid_from_s if clock is not None else None
        if since is not None and clock is not None and timestamp.size and not np.count_nonzero(
                timestamp[1:] < timestamp[:-1]):  # (in order; not .any(): its reduction costs 4x)
            first = int(timestamp.searchsorted(since, side="left"))
            if first < timestamp.size:
                time_s[first:] = clock.map_times(timestamp[first:])
        return cls(time_s, rows[:, 0], timestamp, rows[:, 2:8], rows[:, 8:14], rows[:, 20:26], rows[:, 14:20])


class URStateStream:
    """A receive-only RTDE client keeping every state sample (context manager; :meth:`close` is safe twice).

    Args: host (the controller), frequency_hz (the rate asked; by default the controller's,
    :func:`drivers.ur_connection.state_rate_hz` of its version), capacity (rows kept), connect_timeout_s (the
    handshake's deadline). After :meth:`start`, ``frequency_hz`` is the rate asked and ``version`` the controller's.
    """

    def __init__(self, host: str, frequency_hz: float | None = None, capacity: int = DEFAULT_CAPACITY,
                 connect_timeout_s: float = CONNECT_TIMEOUT_S, port: int = RTDE_PORT) -> None:
        self.host, self.port = host, port
        self.requested_frequency_hz = frequency_hz
        self.frequency_hz = float(frequency_hz or 0.0)
        """The stream's rate, Hz (0 until :meth:`start` asked the controller's, when none was given)."""
        self.version: tuple[int, int, int, int] | None = None
        self.connect_timeout_s = connect_timeout_s
        self._rows = np.empty((capacity, ROW_COLUMNS))
        self._count = 0
        self._lock = threading.Lock()
        self._arrived = threading.Condition(self._lock)
        """Notified with every stored read (and when the stream ends): :meth:`wait_for_samples` sleeps on it."""
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.clock = DeviceClock()
        """The controller's timestamp on the host clock (written by the reader thread only)."""
        self._settled = 0
        """Rows (counted from the first) whose offset was rewritten with a line fitted SETTLE_AFTER_S after them."""
        self._last_arrival = 0.0
        self.error: str | None = None

    # ------------------------------------------------------------------ protocol
    def _connected(self, sock: socket.socket | None = None) -> socket.socket:
        """``sock``, else the stream's socket; DeviceConnectionError when there is none (not started, closed)."""
        sock = sock or self._sock
        if sock is None:
            raise DeviceConnectionError(f"robot controller {self.host} port {self.port} (RTDE): not connected")
        return sock

    def _send(self, package_type: int, payload: bytes = b"") -> None:
        self._connected().sendall(_HEADER.pack(_HEADER.size + len(payload), package_type) + payload)

    def _recv_exact(self, n: int, sock: socket.socket | None = None) -> bytes:
        sock = self._connected(sock)
        data = b""
        while len(data) < n:
            chunk = sock.recv(n - len(data))
            if not chunk:
                raise DeviceConnectionError(f"robot controller {self.host} port {self.port} (RTDE) closed the connection")
            data += chunk
        return data

    def _package(self, sock: socket.socket | None = None) -> tuple[int, bytes]:
        size, package_type = _HEADER.unpack(self._recv_exact(_HEADER.size, sock))
        return package_type, self._recv_exact(max(size - _HEADER.size, 0), sock)

    def _reply(self, expected: int, deadline: float) -> bytes:
        while True:
            if time.monotonic() > deadline:
                raise DeviceConnectionError(f"robot controller {self.host} port {self.port} (RTDE): no reply to the "
                                            f"setup within {self.connect_timeout_s:.1f} s")
            package_type, body = self._package()
            if package_type == expected:
                return body

    def start(self) -> "URStateStream":
        """Connect, set up the output recipe and start streaming (DeviceConnectionError naming host and port)."""
        deadline = time.monotonic() + self.connect_timeout_s
        where = f"robot controller {self.host} port {self.port} (RTDE)"
        try:
            self._sock = sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout_s)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._send(_V, struct.pack(">H", 2))
            if not self._reply(_V, deadline)[:1] == b"\x01":
                raise DeviceConnectionError(f"{where}: the controller refused RTDE protocol version 2")
            self._send(_VERSION)
            reply = self._reply(_VERSION, deadline)
            if len(reply) < 16:
                raise DeviceConnectionError(f"{where}: a controller-version reply of {len(reply)} bytes (16 expected)")
            self.version = struct.unpack(">IIII", reply[:16])
            self.frequency_hz = float(self.requested_frequency_hz or state_rate_hz(self.version))
            self._send(_O, struct.pack(">d", self.frequency_hz) + ",".join(OUTPUTS).encode())
            reply = self._reply(_O, deadline)
            types = reply[1:].decode(errors="replace").split(",")
            if len(types) != len(OUTPUTS) or any(t not in ("DOUBLE", "VECTOR6D") for t in types):
                raise DeviceConnectionError(f"{where}: output recipe refused ({', '.join(types)})")
            self._send(_S)
            if not self._reply(_S, deadline)[:1] == b"\x01":
                raise DeviceConnectionError(f"{where}: the controller refused to start the data stream")
        except OSError as error:
            self.close()
            raise DeviceConnectionError(f"{where}: {error}") from error
        except DeviceError:
            self.close()
            raise
        sock.settimeout(RECEIVE_TIMEOUT_S)
        self._thread = threading.Thread(target=self._read_loop, args=(sock,), name="ftacq-rtde-stream",
                                        daemon=True)
        self._thread.start()
        return self

    def _read_loop(self, sock: socket.socket) -> None:
        buffer = b""
        while not self._stop.is_set():
            try:
                chunk = sock.recv(1 << 16)
            except socket.timeout:
                continue
            except OSError as error:
                chunk, failure = b"", str(error)
            else:
                failure = "the controller closed the connection"
            if not chunk:
                if not self._stop.is_set():
                    self.error = failure
                    log.warning("RTDE state stream from %s ended: %s", self.host, failure)
                with self._arrived:
                    self._arrived.notify_all()
                return
            arrival = time.monotonic()
            buffer += chunk
            values, used = _data_packages(buffer)
            buffer = buffer[used:]
            if len(values):
                self._store(values, arrival)

    def _store(self, values: np.ndarray, arrival_s: float) -> None:
        """Keep one read's data packages (their output values, oldest first), all stamped ``arrival_s`` (host s)."""
        restarts = self.clock.restarts
        self.clock.observe(values[:, 0], arrival_s)
        offsets = self.clock.map_times(values[:, 0]) - values[:, 0]
        capacity = self._rows.shape[0]
        n = len(values)
        kept = min(n, capacity)  # a read longer than the ring keeps its newest rows
        with self._lock:
            if self.clock.restarts != restarts:  # a new session: the older rows keep the offsets of their own
                self._settled = self._count
            index = np.arange(self._count + n - kept, self._count + n) % capacity
            self._rows[index, 0] = arrival_s
            self._rows[index, 1:OFFSET_COLUMN] = values[n - kept:]
            self._rows[index, OFFSET_COLUMN] = offsets[n - kept:]
            self._count += n
            self._last_arrival = arrival_s
            self._settle(float(values[-1, 0]) - SETTLE_AFTER_S)
            self._arrived.notify_all()

    def _settle(self, before_s: float) -> None:
        """Give the rows older than ``before_s`` (controller s) and not settled yet the offset of the newest line,
        at most :data:`SETTLE_ROWS` per read (amortised O(1) per row; lock held)."""
        capacity = self._rows.shape[0]
        start = max(self._settled, self._count - capacity)
        stop = min(start + SETTLE_ROWS, self._count)
        if stop <= start:
            return
        index = np.arange(start, stop) % capacity
        timestamp = self._rows[index, 1]
        due = int(np.searchsorted(timestamp, before_s, side="left"))  # in order within a session
        valid_from = self.clock.valid_from_s
        if due == 0 or valid_from is None:
            return
        index, timestamp = index[:due], timestamp[:due]
        inside = timestamp >= valid_from  # rows the line was fitted over (the others keep their offsets)
        self._rows[index[inside], OFFSET_COLUMN] = self.clock.map_times(timestamp[inside]) - timestamp[inside]
        self._settled = start + due

    # ------------------------------------------------------------------ reading
    @property
    def count(self) -> int:
        """State samples received so far."""
        return self._count

    @property
    def stale(self) -> bool:
        """True when no package arrived for :data:`RECEIVE_TIMEOUT_S` (or the stream ended)."""
        return self.error is not None or time.monotonic() - self._last_arrival > RECEIVE_TIMEOUT_S

    def window(self, since_s: float | None = None, last: int | None = None) -> StateWindow:
        """Return the samples kept (or those with host time ≥ ``since_s``, or the ``last`` N), oldest first."""
        with self._lock:
            count = self._count
            capacity = self._rows.shape[0]
            n = min(count, capacity)
            if last is not None:
                n = min(n, last)
            start = (count - n) % capacity
            if start + n <= capacity:  # one slice, copied (the reader rewrites rows and offsets): no index array
                rows = self._rows[start:start + n].copy()
            else:
                rows = np.concatenate((self._rows[start:], self._rows[:start + n - capacity]))
        window = StateWindow.from_rows(rows, self.clock)
        if since_s is not None:
            window = StateWindow.from_rows(rows[window.time_s >= since_s], self.clock)
        return window

    def wait_for_samples(self, count: int, timeout_s: float) -> bool:
        """Wait until at least ``count`` samples were received in total; False after ``timeout_s`` or when the stream
        ended. Woken by the reader as each read is stored (no polling: a waiting caller holds neither the lock nor
        the interpreter, so the reader gets both at once)."""
        deadline = time.monotonic() + timeout_s
        with self._arrived:
            while self._count < count:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self.error is not None or self._stop.is_set():
                    return False
                self._arrived.wait(remaining)
        return True

    # ------------------------------------------------------------------ life cycle
    def close(self) -> None:
        """Stop the reader and close the connection. Safe to call twice."""
        self._stop.set()
        with self._arrived:
            self._arrived.notify_all()
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            sock.close()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout=JOIN_TIMEOUT_S)

    def __enter__(self) -> "URStateStream":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()


def _data_packages(buffer: bytes) -> tuple[np.ndarray, int]:
    """The output values (n, :data:`OFFSET_COLUMN` − 1) of the complete data packages at the start of ``buffer``,
    and the bytes used (other packages are skipped; an incomplete one is left for the next read). A run of data
    packages, the usual read, is one ``np.frombuffer``: no Python object per package."""
    runs: list[np.ndarray] = []
    offset, size = 0, _DATA_PACKAGE.itemsize
    while len(buffer) - offset >= _HEADER.size:
        whole = (len(buffer) - offset) // size
        if whole:
            packages = np.frombuffer(buffer, _DATA_PACKAGE, count=whole, offset=offset)
            data = (packages["size"] == size) & (packages["type"] == _U)
            run = whole if data.all() else int(np.argmin(data))
            if run:
                runs.append(packages["values"][:run])
                offset += run * size
                continue
        package_size, _ = _HEADER.unpack_from(buffer, offset)
        if package_size < _HEADER.size or len(buffer) - offset < package_size:
            break
        offset += package_size
    if not runs:
        return np.empty((0, _DATA_PACKAGE["values"].shape[0])), offset
    return (runs[0] if len(runs) == 1 else np.concatenate(runs)).astype(float), offset


__all__ = ["URStateStream", "StateWindow", "OUTPUTS"]
