"""The RDT socket and its receive thread: datagrams into a byte ring, never decoded here, never raising.

One named thread owns a UDP socket with a large ``SO_RCVBUF``, bound to the local address of the interface that
routes to the box (found with a connected UDP probe, so no packet is sent) and an ephemeral port. It drains the
socket with ``recvfrom_into`` straight into a preallocated byte ring (whole datagrams of N × 36 bytes), stamping
each datagram with ``time.monotonic()`` when it drains it (after a wake-up that woke the reader the thread pauses
``COALESCE_S`` = 1 ms, so a stamp may be up to that much after the datagram's arrival). It also publishes
``drained_at_s``: a host time by which every datagram that had arrived is in the ring (the socket was found empty
after it). The reorder window is measured on that clock, not the reader's, so that a stalled receive thread (a
loaded machine) never makes a swapped record, still waiting in the socket, look later than its window.
It accepts datagrams only from the box's address and RDT port (others: ``foreign``); a datagram whose length is
not a positive multiple of 36 is ``malformed``. Silence longer than the stream timeout is a ``timeout``, and the
start command is re-sent (``reconnects``) on the schedule of :func:`next_retry_interval_s`. The reader side
(:meth:`RdtReceiver.take`) copies whole runs of records out of the ring; records the reader did not take before the
ring filled are dropped whole datagram by datagram (``overflowed``) and show up as sequence gaps, as do the
datagrams the kernel dropped because the socket's buffer was full (:func:`socket_drops`, from /proc on Linux): the
two losses this side of the wire. A sample the box itself skipped (``ft_sequence`` jumps, ``rdt_sequence`` does not) is neither.
"""

from __future__ import annotations

import logging
import os
import select
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Callable

import numpy as np

from drivers.netft.protocol import RECORD_DTYPE, RECORD_SIZE
from drivers.sensor import SensorHealth

logger = logging.getLogger("drivers.netft")

RING_RECORDS = 1 << 16
"""Records the receive ring holds (9 s at 7 kHz) before the receive thread drops datagrams (counted as lost)."""
MAX_DATAGRAM_BYTES = 65536
SLACK_RECORDS = -(-MAX_DATAGRAM_BYTES // RECORD_SIZE)
"""Room past the ring's end so that a whole datagram always fits at the write position (wrapped after)."""
RECEIVE_BUFFER_BYTES = 8 << 20
"""Requested SO_RCVBUF (the kernel caps it at net.core.rmem_max; SO_RCVBUFFORCE, tried first, needs
CAP_NET_ADMIN)."""
UDP_TABLES = (Path("/proc/self/net/udp"), Path("/proc/self/net/udp6"))
"""Linux's tables of this process's UDP sockets, whose last column counts each socket's dropped datagrams."""
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33 if sys.platform.startswith("linux") else None)
"""Linux's SO_RCVBUFFORCE (33; Python's socket module does not name it)."""
POLL_S = 0.05
"""Longest the receive thread blocks before checking its stop flag, seconds."""
COALESCE_S = 0.001
"""After a wake-up that drained data (and woke the reader), the receive thread pauses this long so that its next
wake-up drains several datagrams: at 7 kHz this halves the CPU cost. Records arriving meanwhile wait at most this
long in the kernel (their receive stamp is taken when drained), seconds; 0 disables it."""
NOTIFY_INTERVAL_S = 0.001
"""The receive thread wakes a waiting reader at most this often, seconds: readers get batches, not single records,
at the cost of at most this much latency."""
RECENT_DATA_POLL_S = 0.002
"""For RECENT_DATA_S after the latest datagram the receive thread polls at least this often, so that
``drained_at_s`` keeps up when a stream stops with records held for reordering, seconds."""
RECENT_DATA_S = 0.1
"""How long after the latest datagram the receive thread keeps polling every RECENT_DATA_POLL_S, seconds."""
BACKOFF_INITIAL_S = 0.25
"""First interval between re-sent start commands while the box is silent, seconds."""
BACKOFF_RESTARTING_MAX_S = 0.5
"""Longest interval between re-sent starts during the first UNREACHABLE_AFTER_S of a silence, seconds: a box
that power-cycled or whose link came back streams again at most this long after it can hear us."""
UNREACHABLE_AFTER_S = 30.0
"""A silence longer than this means the box is gone (unplugged, off): re-sends back off to BACKOFF_MAX_S."""
BACKOFF_MAX_S = 5.0
"""Longest interval between re-sent starts to a box that has been unreachable for long, seconds."""


def next_retry_interval_s(previous_s: float, silent_for_s: float) -> float:
    """Interval before the next re-sent start: doubling from BACKOFF_INITIAL_S, at most BACKOFF_RESTARTING_MAX_S
    while the silence is recent (a box restarting or a link hiccup), at most BACKOFF_MAX_S after that."""
    cap = BACKOFF_RESTARTING_MAX_S if silent_for_s < UNREACHABLE_AFTER_S else BACKOFF_MAX_S
    return min(max(previous_s, BACKOFF_INITIAL_S / 2.0) * 2.0, cap)


def socket_drops(sock: socket.socket, tables: tuple[Path, ...] = UDP_TABLES) -> int | None:
    """Datagrams the kernel dropped at ``sock`` because its receive buffer was full (the receive thread did not
    drain it in time), from the ``drops`` column of Linux's /proc/net/udp(6) (the socket found by its inode);
    None where the system does not say. Read on demand (a diagnostic), never per datagram."""
    try:
        inode = str(os.fstat(sock.fileno()).st_ino)
    except OSError:
        return None
    for table in tables:
        try:
            lines = table.read_text(encoding="ascii", errors="replace").splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) >= 13 and fields[9] == inode:
                try:
                    return int(fields[-1])
                except ValueError:
                    return None
    return None


def local_address_towards(family: int, address: tuple) -> str:
    """The local address of the interface that routes to ``address`` (a connected UDP socket sends nothing)."""
    with socket.socket(family, socket.SOCK_DGRAM) as probe:
        probe.connect(address)
        return probe.getsockname()[0]


class RdtReceiver:
    """The socket, the ring and the receive thread of one Net F/T stream (see the module docstring).

    Args:
        host: the box's name (for messages). address: its resolved RDT (ip, port). family: its address family.
        timeout_s: silence after which ``resend`` is called (the driver re-sends its start), seconds.
        resend: called from the receive thread to re-send the start command.
        accept_any_port: also accept records from the box's address but another port.
    """

    def __init__(self, host: str, address: tuple, family: int, timeout_s: float, resend: Callable[[], None],
                 accept_any_port: bool = False) -> None:
        self.host, self.address, self.family = host, address, family
        self.timeout_s = timeout_s
        self.coalesce_s = COALESCE_S
        self.accept_any_port = accept_any_port
        self._resend = resend
        self.capacity = RING_RECORDS
        self.slack = SLACK_RECORDS
        self.max_datagram_bytes = MAX_DATAGRAM_BYTES
        self._ring = bytearray((self.capacity + self.slack) * RECORD_SIZE)
        self._records = np.frombuffer(self._ring, dtype=RECORD_DTYPE)
        self._times = np.zeros(self._records.shape[0])
        self.written = 0  # records written into the ring (monotonic)
        self.drained_at_s = 0.0
        """Host time (monotonic) by which every datagram that arrived is in the ring: set after ``written``."""
        self.consumed = 0  # records taken out by the reader (monotonic)
        self.waiters = 0
        self.data_ready = threading.Condition()
        self.counters = SensorHealth()  # malformed, foreign, timeouts, reconnects
        self.overflowed = 0
        self.socket_errors = 0
        self.last_retry_interval_s = 0.0
        """Interval the receive thread scheduled after its latest re-sent start, seconds (0: none re-sent yet)."""
        self.receive_buffer_bytes = 0
        self.sock: socket.socket | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.thread_error: BaseException | None = None
        self._send_lock = threading.Lock()

    # ------------------------------------------------------------------ socket

    def open(self) -> None:
        """Create the socket, bound to the interface that routes to the box, with a large receive buffer."""
        sock = socket.socket(self.family, socket.SOCK_DGRAM)
        try:
            for option in (SO_RCVBUFFORCE, socket.SO_RCVBUF):
                if option is None:
                    continue
                try:
                    sock.setsockopt(socket.SOL_SOCKET, option, RECEIVE_BUFFER_BYTES)
                    break
                except OSError:
                    continue
            self.receive_buffer_bytes = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
            # Linux reports twice the payload it accounts (its bookkeeping included); under RECEIVE_BUFFER_BYTES the
            # request was capped by net.core.rmem_max (no CAP_NET_ADMIN for SO_RCVBUFFORCE)
            capped = self.receive_buffer_bytes < RECEIVE_BUFFER_BYTES
            logger.log(logging.WARNING if capped else logging.INFO,
                       "Net F/T %s: UDP receive buffer %d kB granted (%d kB asked)%s", self.host,
                       self.receive_buffer_bytes >> 10, RECEIVE_BUFFER_BYTES >> 10,
                       "; raise it with 'sysctl -w net.core.rmem_max=8388608' (docs/hardware.md)" if capped else "")
            try:
                local = local_address_towards(self.family, self.address)
            except OSError:  # no route yet: any interface (the sender filter still applies)
                local = "::" if self.family == socket.AF_INET6 else "0.0.0.0"
            sock.bind((local, 0))
            sock.setblocking(False)
        except BaseException:
            sock.close()
            raise
        self.sock = sock

    def send(self, datagram: bytes) -> None:
        """Send a command datagram to the box (a failure is counted, never raised)."""
        try:
            if self.sock is None:
                raise OSError("socket not open")
            with self._send_lock:
                self.sock.sendto(datagram, self.address)
        except OSError as error:
            self.socket_errors += 1
            logger.debug("Net F/T %s: sending %s failed: %s", self.host, datagram.hex(), error)

    @property
    def local_address(self) -> tuple | None:
        return self.sock.getsockname() if self.sock is not None else None

    # ------------------------------------------------------------------ thread

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=f"NetFT-rx-{self.host}:{self.address[1]}",
                                        daemon=False)
        self._thread.start()

    def stop(self, join_timeout_s: float) -> None:
        """Stop and join the thread (the socket stays open for a last command), then wake any reader."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(join_timeout_s)
            if self._thread.is_alive():
                logger.error("%s did not stop within %.1f s", self._thread.name, join_timeout_s)
        self.drained_at_s = float("inf")  # nothing more enters the ring: no held record waits for another
        with self.data_ready:
            self.data_ready.notify_all()

    def close_socket(self) -> None:
        if self.sock is not None:
            self.sock.close()

    def _run(self) -> None:
        try:
            self._receive()
        except BaseException as error:  # re-raised by the driver's close(); the loop catches everything expected
            self.thread_error = error
            with self.data_ready:
                self.data_ready.notify_all()

    def _receive(self) -> None:
        sock, ring, times, stop = self.sock, memoryview(self._ring), self._times, self._stop
        if sock is None:
            raise RuntimeError("RdtReceiver.start() before open()")
        expected, any_port = self.address, self.accept_any_port
        capacity, capacity_mask, max_bytes = self.capacity, self.capacity - 1, self.max_datagram_bytes
        room_needed = self.slack + 1
        scratch = bytearray(max_bytes)
        counters = self.counters
        monotonic = time.monotonic
        poller = select.poll()
        poller.register(sock, select.POLLIN)
        last_data_s = last_notify_s = monotonic()
        next_retry_s = last_data_s + self.timeout_s
        interval_s = 0.0
        notify_pending = False
        while not stop.is_set():
            try:
                if notify_pending:
                    poll_s = NOTIFY_INTERVAL_S
                else:
                    poll_s = RECENT_DATA_POLL_S if monotonic() - last_data_s < RECENT_DATA_S else POLL_S
                poller.poll(poll_s * 1000.0)
                checked_s = monotonic()  # what had arrived by now is read below, up to an empty socket
                written = self.written
                got = arrived = False
                while True:
                    if written - self.consumed > capacity - room_needed:
                        try:
                            sock.recv_into(scratch)
                        except (BlockingIOError, InterruptedError):
                            break
                        except OSError:
                            self.socket_errors += 1
                            break
                        self.overflowed += 1  # the reader fell behind: a gap the tracker counts as lost
                        arrived = True
                        continue
                    position = written & capacity_mask
                    try:
                        size, sender = sock.recvfrom_into(ring[position * RECORD_SIZE:], max_bytes)
                    except BlockingIOError:  # empty: everything that arrived before checked_s is in the ring
                        self.drained_at_s = checked_s
                        break
                    except InterruptedError:
                        break
                    except OSError:  # ICMP port unreachable etc.: count and keep going
                        self.socket_errors += 1
                        break
                    if sender != expected and (not any_port or sender[0] != expected[0]):
                        counters.foreign += 1
                        continue
                    if size == 0 or size % RECORD_SIZE:
                        counters.malformed += 1
                        continue
                    records = size // RECORD_SIZE
                    now = checked_s = monotonic()
                    if records == 1:
                        times[position] = now
                    else:
                        times[position:position + records] = now
                        overflow = position + records - capacity
                        if overflow > 0:  # wrap: copy the tail past the ring's end to its start
                            ring[:overflow * RECORD_SIZE] = ring[capacity * RECORD_SIZE:(position + records) * RECORD_SIZE]
                            times[:overflow] = times[capacity:capacity + overflow]
                    written += records
                    self.written = written
                    got = True
                now = monotonic()
                if got or arrived:  # the box is streaming (even if the ring is full)
                    last_data_s = now
                    next_retry_s = now + self.timeout_s
                    interval_s = 0.0
                    notify_pending = notify_pending or got
                if notify_pending and now - last_notify_s >= NOTIFY_INTERVAL_S:
                    notify_pending = False
                    last_notify_s = now
                    if self.waiters:
                        with self.data_ready:
                            self.data_ready.notify_all()
                if not (got or arrived) and now >= next_retry_s:
                    counters.timeouts += 1
                    counters.reconnects += 1
                    interval_s = next_retry_interval_s(interval_s, now - last_data_s)
                    self.last_retry_interval_s = interval_s
                    logger.info("Net F/T %s: no data for %.2f s; re-sending start (next in %.2f s)",
                                self.host, now - last_data_s, interval_s)
                    self._resend()
                    next_retry_s = now + interval_s
                if got and self.coalesce_s > 0.0 and not notify_pending:
                    stop.wait(self.coalesce_s)  # let a few datagrams queue: the next wake-up drains them all
            except Exception:  # never raise out of the receive loop
                self.socket_errors += 1
                logger.exception("Net F/T %s: unexpected error in the receive loop", self.host)
                stop.wait(POLL_S)

    # ------------------------------------------------------------------ reader side

    def has_new(self) -> bool:
        """Whether records were written since the last :meth:`take`."""
        return self.written != self.consumed

    def take(self) -> tuple[np.ndarray, np.ndarray, int]:
        """Copy every record written since the last call; return (records, receive times, index of the first).

        Call from one reader at a time (the driver's decode lock)."""
        start, end = self.consumed, self.written
        count = end - start
        if count == 0:
            return self._records[:0].copy(), self._times[:0].copy(), start
        position = start & (self.capacity - 1)
        if position + count <= self.capacity:
            records = self._records[position:position + count].copy()
            times = self._times[position:position + count].copy()
        else:
            head = self.capacity - position
            records = np.concatenate([self._records[position:self.capacity], self._records[:count - head]])
            times = np.concatenate([self._times[position:self.capacity], self._times[:count - head]])
        self.consumed = end
        return records, times, start

    def wait(self, timeout_s: float, stopped: Callable[[], bool]) -> None:
        """Block until the receive thread notifies new records or ``timeout_s`` passes."""
        with self.data_ready:
            self.waiters += 1
            try:
                if self.written == self.consumed and not stopped():
                    self.data_ready.wait(max(timeout_s, 0.0))
            finally:
                self.waiters -= 1

    def socket_drops(self) -> int | None:
        """Datagrams the kernel dropped at this socket (its buffer full); None where the system does not say."""
        return socket_drops(self.sock) if self.sock is not None else None

    def problems(self) -> str:
        """``; datagrams rejected: …`` when some were, else ""."""
        parts = [f"{n} {name}" for name, n in (("malformed", self.counters.malformed),
                                              ("foreign", self.counters.foreign),
                                              ("socket errors", self.socket_errors)) if n]
        return f"; datagrams rejected: {', '.join(parts)}" if parts else ""
