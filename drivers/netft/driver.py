"""The ATI Net F/T (and Ethernet Axia) driver: discovery, the RDT stream, decoding in batches, bias.

``start()`` discovers the scaling (:mod:`drivers.netft.discovery`: HTTP and TCP, cross-checked), opens the RDT
socket and its receive thread (:mod:`drivers.netft.receiver`), sends the start command and waits for the first
record. Readers (``read``, ``average``, ``health``) take what the receive thread wrote, put it in sequence order
and account for losses with :class:`drivers.netft.sequence.SequenceTracker`, and decode whole batches with numpy
(``np.frombuffer`` of the 36-byte record): no per-sample Python objects on the fast path. Each sample carries the
box's own sample time (``WrenchBatch.device_time_s``, from ``ft_sequence``: :mod:`drivers.netft.device_time`).
Values are converted to SI once: ``wrench = counts × (SI per unit) / counts_per_unit``. Status: a sample with an error bit is flagged in
``WrenchBatch.saturated`` and never averaged; the Net F/T and Ethernet Axia bit maps are both known. Protocol facts:
docs/protocols-ati.md.

URL: ``netft://HOST[:RDT_PORT][?tcp_port=49151&http_port=80&rate_hz=R&buffered=0&buffer_size=N&timeout_s=T
&counts_per_force=C&counts_per_torque=C&force_unit=N&torque_unit=N-mm&status_map=auto|netft|axia
&http_timeout_s=T&tcp_timeout_s=T&accept_any_port=0]``; each key at most once.
"""

from __future__ import annotations

import collections
import logging
import socket
import threading
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import urlsplit

import numpy as np

from drivers.hosts import host_problem
from drivers.netft.discovery import (
    DEFAULT_HTTP_TIMEOUT_S,
    DEFAULT_TCP_TIMEOUT_S,
    BoxAddress,
    Scaling,
    discover,
    to_float,
)
from drivers.netft.protocol import (
    DEFAULT_HTTP_PORT,
    DEFAULT_RDT_PORT,
    DEFAULT_TCP_PORT,
    INTERNAL_RATE_HZ,
    RDT_BIAS,
    RDT_RESET_LATCH,
    RDT_START,
    RDT_START_BUFFERED,
    RDT_STOP,
    STATUS_MAPS,
    rdt_command,
    status_text,
)
from drivers.netft.device_time import SampleCounterClock
from drivers.netft.receiver import COALESCE_S, POLL_S, RdtReceiver
from drivers.netft.sequence import REORDER_WINDOW_S, SequenceTracker
from drivers.sensor import SensorBase, SensorHealth, SensorInfo, WrenchBatch, check_range, query_items
from drivers.units import canonical_unit
from ftacq.errors import DeviceConnectionError, DeviceError, DeviceTimeoutError, InputError

logger = logging.getLogger("drivers.netft")

DEFAULT_TIMEOUT_S = 0.25
"""Silence after which the stream counts a timeout and re-sends its start command, seconds (at least 10 periods)."""
START_TIMEOUT_S = 1.0
"""How long start() waits for the first record (at least 3 periods), seconds."""
BIAS_SETTLE_TIMEOUT_S = 1.0
"""How long bias() waits for the restarted (biased) stream before it accepts whatever comes, seconds."""
MAX_PENDING_SAMPLES = 1_000_000
"""Decoded samples kept for ``read`` if nobody reads (oldest batches dropped beyond this)."""
RATE_WINDOW_S = 1.0
"""Window of the measured rate in ``SensorHealth.rate_hz``, seconds."""
CLOSE_JOIN_TIMEOUT_S = 2.0
HOLD_RECHECK_S = 0.0005
"""Shortest wait of a reader whose held records' window has expired on its clock but not yet on the receive
thread's (``RdtReceiver.drained_at_s`` lags by up to one poll), seconds."""
URL_FORM = ("netft://HOST[:RDT_PORT][?tcp_port=49151&http_port=80&rate_hz=R&buffered=0&buffer_size=N&timeout_s=T"
            "&counts_per_force=C&counts_per_torque=C&force_unit=N&torque_unit=N-m&status_map=auto]")
_NO_SAMPLES = WrenchBatch.empty()
"""What :meth:`NetFTSensor._take` returns when nothing came (a read on data finds none first, ~0.7 times per read with
--ros2: built once; its arrays hold nothing to change)."""


class NetFTSensor(SensorBase):
    """ATI Net F/T over RDT/TCP/HTTP, implementing :class:`drivers.sensor.ForceTorqueSensor`.

    Args:
        host: the box's address (name or IP). rdt_port, tcp_port, http_port: its ports (49152, 49151, 80).
        rate_hz: if given, ``start()`` sets ``comrdtrate`` over HTTP (the box rounds up to 7000/n Hz).
        buffered: stream with 0x0003 (``buffer_size`` records per datagram, set over HTTP when given).
        timeout_s: silence (s) after which the stream counts a timeout and re-sends its start (None: automatic).
        counts_per_force, counts_per_torque, force_unit, torque_unit: override discovery (all four together).
        status_map: "netft", "axia" or "auto" (Axia when the product name says so or ``setrate`` exists).
        http_timeout_s, tcp_timeout_s: discovery timeouts, seconds.
        accept_any_port: also accept records from the box's address but another port (a box that does not send
            from its RDT port; by default such datagrams are rejected as ``foreign``).
        reorder_window_s: how long records past a gap wait for late ones, seconds.

    The constructor does no I/O. ``start()`` discovers, opens the socket, starts the receive thread and the
    stream and waits for the first record. ``close()`` sends stop (0x0000) and joins the thread.
    """

    URL_FORM = URL_FORM

    def __init__(self, host: str, rdt_port: int = DEFAULT_RDT_PORT, *, tcp_port: int = DEFAULT_TCP_PORT,
                 http_port: int = DEFAULT_HTTP_PORT, rate_hz: float | None = None, buffered: bool = False,
                 buffer_size: int | None = None, timeout_s: float | None = None,
                 counts_per_force: float | None = None, counts_per_torque: float | None = None,
                 force_unit: str | None = None, torque_unit: str | None = None, status_map: str = "auto",
                 http_timeout_s: float = DEFAULT_HTTP_TIMEOUT_S, tcp_timeout_s: float = DEFAULT_TCP_TIMEOUT_S,
                 accept_any_port: bool = False, reorder_window_s: float = REORDER_WINDOW_S) -> None:
        super().__init__()
        if not host:
            raise InputError(f"Net F/T host is empty; expected {URL_FORM}")
        for name, port in (("rdt_port", rdt_port), ("tcp_port", tcp_port), ("http_port", http_port)):
            check_range(name, port, 1, 65535)
        if rate_hz is not None:
            check_range("rate_hz", rate_hz, 1e-3, 1e6)
        if buffer_size is not None:
            check_range("buffer_size", buffer_size, 1, 40)
        if timeout_s is not None:
            check_range("timeout_s", timeout_s, 1e-3, 3600.0)
        check_range("http_timeout_s", http_timeout_s, 1e-3, 600.0)
        check_range("tcp_timeout_s", tcp_timeout_s, 1e-3, 600.0)
        check_range("reorder_window_s", reorder_window_s, 0.0, 1.0)
        if status_map not in ("auto", "netft", "axia"):
            raise InputError(f"status_map {status_map!r}: must be auto, netft or axia")
        overrides = (counts_per_force, counts_per_torque, force_unit, torque_unit)
        if any(v is not None for v in overrides) and not all(v is not None for v in overrides):
            raise InputError("counts_per_force, counts_per_torque, force_unit and torque_unit override discovery "
                             "only all together")
        self._override: Scaling | None = None
        if (counts_per_force is not None and counts_per_torque is not None and force_unit is not None
                and torque_unit is not None):
            check_range("counts_per_force", counts_per_force, 1e-9, 1e12)
            check_range("counts_per_torque", counts_per_torque, 1e-9, 1e12)
            try:
                self._override = Scaling(float(counts_per_force), float(counts_per_torque),
                                         canonical_unit(force_unit, "force"), canonical_unit(torque_unit, "torque"),
                                         "URL")
            except DeviceError as error:
                raise InputError(str(error)) from None
        self.host, self.rdt_port, self.tcp_port, self.http_port = host, int(rdt_port), int(tcp_port), int(http_port)
        self.requested_rate_hz, self.buffered, self.requested_buffer_size = rate_hz, bool(buffered), buffer_size
        self.requested_timeout_s, self.status_map_setting = timeout_s, status_map
        self.http_timeout_s, self.tcp_timeout_s = http_timeout_s, tcp_timeout_s
        self.accept_any_port = bool(accept_any_port)
        self.scaling: Scaling | None = None
        self.status_map = "netft"
        self.info = SensorInfo(transport="netft", serial="", firmware="", force_unit="", torque_unit="",
                               counts_per_force=0.0, counts_per_torque=0.0, rate_hz=float(rate_hz or 0.0))
        self.timeout_s = DEFAULT_TIMEOUT_S
        # decode side (under _decode_lock)
        self._decode_lock = threading.RLock()
        self._tracker = SequenceTracker(reorder_window_s=reorder_window_s)
        self._sample_clock = SampleCounterClock()
        self._decoded: collections.deque[WrenchBatch] = collections.deque()
        self._decoded_samples = 0
        self._bias_done = threading.Event()
        self.delivered = 0
        self._rate_window = (0.0, 0)
        self._rate_hz = 0.0
        self._saturated_count = self._status_error_count = self._last_status = 0
        self._scale = np.zeros(6)
        self._error_mask, self._saturation_mask = STATUS_MAPS["netft"]
        self._error_bits, self._saturation_bits = np.uint32(self._error_mask), np.uint32(self._saturation_mask)
        # connection
        self._address: tuple | None = None
        self._family: int = socket.AF_INET
        self._receiver: RdtReceiver | None = None

    # ------------------------------------------------------------------ construction from a URL

    @classmethod
    def parse_url(cls, url: str) -> dict:
        """Return the constructor keyword arguments (plus ``host``) named by a ``netft://`` URL (no I/O)."""
        return parse_netft_url(url)

    @classmethod
    def from_url(cls, url: str, **options) -> "NetFTSensor":
        """Return an unstarted driver for a ``netft://`` URL (module docstring); ``options`` override its keys."""
        kwargs = parse_netft_url(url)
        kwargs.update(options)
        host = kwargs.pop("host")
        return cls(host, **kwargs)

    # ------------------------------------------------------------------ lifecycle (SensorBase hooks)

    @property
    def label(self) -> str:
        return f"Net F/T {self.host}:{self.rdt_port}"

    def _apply_hold(self) -> None:
        """The receive thread's pause after a wake-up (drivers/netft/receiver.py ``COALESCE_S``, 1 ms: the datagrams
        arriving meanwhile are drained by one wake-up) at most :attr:`max_hold_s`: the newest record is readable
        sooner, for more wake-ups (CPU) per second; None gives ``COALESCE_S`` back."""
        receiver = self._receiver
        if receiver is not None:
            hold = self.max_hold_s
            receiver.coalesce_s = COALESCE_S if hold is None else min(COALESCE_S, hold)

    def _open(self) -> None:
        """Discover units and counts per unit (HTTP and TCP, cross-checked), set the rate if asked, open the
        socket, start the receive thread and the stream, and wait for the first record.

        Raises DeviceConnectionError (unreachable, unresolvable), DeviceError (HTTP and TCP disagree, unknown
        units), DeviceTimeoutError (no RDT record in time).
        """
        self._address, self._family = self._resolve()
        box = BoxAddress(self.host, self._address[0], self.http_port, self.tcp_port, self.http_timeout_s,
                         self.tcp_timeout_s)
        found = discover(box, override=self._override, rate_hz=self.requested_rate_hz,
                         buffer_size=self.requested_buffer_size, status_map=self.status_map_setting)
        self._apply(found)
        receiver = RdtReceiver(self.host, self._address, self._family, self.timeout_s, self._resend,
                               self.accept_any_port)
        receiver.open()
        self._receiver = receiver
        self._apply_hold()
        self.info.extra["receive_buffer_bytes"] = receiver.receive_buffer_bytes
        self._started = True
        receiver.start()
        self._send_start()
        rate = self.info.rate_hz
        wait_s = max(START_TIMEOUT_S, 3.0 / rate) if rate > 0 else START_TIMEOUT_S
        deadline = time.monotonic() + wait_s
        with receiver.data_ready:
            while receiver.written == 0 and time.monotonic() < deadline and receiver.thread_error is None:
                receiver.data_ready.wait(min(POLL_S, max(deadline - time.monotonic(), 0.0)))
        if receiver.written == 0:
            raise DeviceTimeoutError(
                f"Net F/T {self.host}: no RDT data on UDP port {self.rdt_port} within "
                f"{wait_s:.2g} s (HTTP or TCP answered; is RDT "
                f"enabled (comrdte) and is the RDT port right?){receiver.problems()}"
                + ("; records came from another address or port: if the box sends from another port, add "
                   "accept_any_port=1 to the URL" if receiver.counters.foreign else ""))

    def _apply(self, found) -> None:
        scaling = found.scaling
        self.scaling = scaling
        self._scale = scaling.counts_to_si
        self.status_map = found.status_map
        self._error_mask, self._saturation_mask = STATUS_MAPS[self.status_map]
        self._error_bits, self._saturation_bits = np.uint32(self._error_mask), np.uint32(self._saturation_mask)
        rate = found.rate_hz
        self.timeout_s = self.requested_timeout_s or max(DEFAULT_TIMEOUT_S, 10.0 / rate if rate > 0 else 1.0)
        api, calibration_page = found.api, found.calibration_page
        self._tracker.rate_hz = rate
        internal_rate = to_float(api.get("runrate"))
        self._tracker.internal_rate_hz = internal_rate if internal_rate and internal_rate > 0 else INTERNAL_RATE_HZ
        self._sample_clock.internal_rate_hz = self._tracker.internal_rate_hz
        self.info = SensorInfo(
            transport="netft",
            serial=api.get("cfgcalsn") or calibration_page.get("calsn", ""),
            firmware=api.get("mfgdigver", ""),
            force_unit=scaling.force_unit, torque_unit=scaling.torque_unit,
            counts_per_force=scaling.counts_per_force, counts_per_torque=scaling.counts_per_torque,
            rate_hz=rate, model=api.get("prodname", ""),
            extra={"product": api.get("prodname", ""), "host": self.host, "rdt_port": self.rdt_port,
                   "tcp_port": self.tcp_port, "http_port": self.http_port, "scaling_source": scaling.source,
                   "sources_missing": found.problems, "status_map": self.status_map, "buffered": self.buffered,
                   "buffer_size": found.buffer_size, "runstat": api.get("runstat", ""),
                   "max_rating": api.get("cfgmr", ""), "filter": api.get("setuserfilter", "")})

    def _shutdown(self) -> None:
        """Join the receive thread, send stop (0x0000), close the socket."""
        receiver = self._receiver
        if receiver is None:
            return
        receiver.stop(CLOSE_JOIN_TIMEOUT_S)
        if self._started and receiver.sock is not None:
            receiver.send(rdt_command(RDT_STOP))  # after the thread stopped, so no re-send restarts the stream
        receiver.close_socket()
        self._thread_error = receiver.thread_error

    def __repr__(self) -> str:
        state = "closed" if self._closed else "streaming" if self._started else "not started"
        return (f"NetFTSensor(host={self.host!r}, rdt_port={self.rdt_port}, tcp_port={self.tcp_port}, "
                f"http_port={self.http_port}, rate_hz={self.info.rate_hz:g}, buffered={self.buffered}, {state})")

    def describe_status(self, status: int) -> str:
        return f"{status:#010x} ({status_text(status, self.status_map)})"

    def _silence_message(self, timeout_s: float | None) -> str:
        return super()._silence_message(timeout_s) + (self._receiver.problems() if self._receiver else "")

    def _raise_if_dead(self) -> None:
        if self._receiver is not None and self._receiver.thread_error is not None:
            error = self._receiver.thread_error
            raise DeviceError(f"Net F/T receive thread failed: {error!r}") from error

    # ------------------------------------------------------------------ the sensor contract

    def bias(self, timeout_s: float = BIAS_SETTLE_TIMEOUT_S) -> None:
        """Tare on the device (RDT 0x0042), then restart the stream so that every later sample is biased.

        Records received before the restart are discarded. A device that does not restart its sequence on a
        new start is given ``timeout_s`` seconds, after which everything received so far is discarded.
        """
        self._require_started()
        self._bias_done.clear()
        self._send_start(bias=True)
        deadline = time.monotonic() + timeout_s
        while not self._bias_done.is_set() and time.monotonic() < deadline:
            self._decode()
            if not self._bias_done.is_set():
                self._wait_for_data(min(POLL_S, max(deadline - time.monotonic(), 1e-3)))
        if not self._bias_done.is_set():
            logger.warning("Net F/T %s did not restart its RDT sequence after bias within %.2g s: discarding "
                           "samples received so far", self.host, timeout_s)
            with self._decode_lock:
                self._decode()
                self._tracker.bias_timed_out()
                self._decoded.clear()
                self._decoded_samples = 0

    def reset_latch(self) -> None:
        """Clear the monitor-condition latch (RDT 0x0041)."""
        self._require_started()
        self._started_receiver().send(rdt_command(RDT_RESET_LATCH))

    def health(self) -> SensorHealth:
        """Return a snapshot: received (well-formed records), lost, gaps, longest_gap_s, duplicate, out_of_order,
        stalled, restarts, saturated (saturation bits), status_errors (any error bit), malformed, foreign (other
        senders), timeouts, reconnects, socket_drops (the kernel's, at the socket), ring_overflows, last_status and the
        measured rate_hz."""
        if self._started and not self._closed:
            self._decode()
        with self._decode_lock:
            snapshot = self._health_locked()
        if self._receiver is not None:
            rx = self._receiver.counters
            snapshot.malformed, snapshot.foreign = rx.malformed, rx.foreign
            snapshot.timeouts, snapshot.reconnects = rx.timeouts, rx.reconnects
            snapshot.socket_drops, snapshot.ring_overflows = self._receiver.socket_drops() or 0, self._receiver.overflowed
        return snapshot

    @property
    def local_address(self) -> tuple | None:
        """The (address, port) this driver receives RDT records on (None before start)."""
        return self._receiver.local_address if self._receiver is not None and not self._closed else None

    @property
    def overflowed(self) -> int:
        """Datagrams the receive thread dropped because the reader fell behind the ring."""
        return self._receiver.overflowed if self._receiver is not None else 0

    @property
    def receive_buffer_bytes(self) -> int:
        """The socket's receive buffer as the kernel granted it, bytes (0 before start)."""
        return self._receiver.receive_buffer_bytes if self._receiver is not None else 0

    @property
    def ft_backward(self) -> int:
        return self._tracker.counters.ft_backward

    # ------------------------------------------------------------------ connection

    def _resolve(self) -> tuple[tuple, int]:
        try:
            infos = socket.getaddrinfo(self.host, self.rdt_port, type=socket.SOCK_DGRAM)
        except socket.gaierror as error:
            raise DeviceConnectionError(f"cannot resolve Net F/T host {self.host!r}: {error}") from error
        infos.sort(key=lambda info: info[0] != socket.AF_INET)
        family, _, _, _, address = infos[0]
        return address, family

    def _send_start(self, bias: bool = False) -> None:
        """Send the start command (after a bias command when ``bias``), telling the tracker first."""
        receiver = self._started_receiver()
        with self._decode_lock:
            self._tracker.expect_start(receiver.written, time.monotonic(), bias=bias)
        if bias:
            receiver.send(rdt_command(RDT_BIAS))
        receiver.send(rdt_command(RDT_START_BUFFERED if self.buffered else RDT_START))

    def _started_receiver(self) -> RdtReceiver:
        """The receive side, which exists from start() on (DeviceError before)."""
        if self._receiver is None:
            raise DeviceError(f"{self.label}: not started")
        return self._receiver

    def _resend(self) -> None:
        self._send_start()

    # ------------------------------------------------------------------ decoding (reader side)

    def _wait_for_data(self, timeout_s: float) -> None:
        deadline = self._tracker.hold_deadline
        if deadline is not None:  # held records are released when their reorder window expires (receiver's clock)
            timeout_s = min(timeout_s, max(deadline - time.monotonic(), HOLD_RECHECK_S))
        self._started_receiver().wait(timeout_s, lambda: self._closed)

    def _take(self) -> WrenchBatch:
        with self._decode_lock:
            if not self._decoded and not self._tracker.held and not self._started_receiver().has_new():
                return _NO_SAMPLES  # what _decode would find (a read on data looks once before it waits)
            self._decode()
            if not self._decoded:
                return _NO_SAMPLES
            batches = list(self._decoded)
            self._decoded.clear()
            self._decoded_samples = 0
        return batches[0] if len(batches) == 1 else WrenchBatch.concatenate(batches)

    def _decode(self) -> None:
        """Move every record the receive thread wrote into decoded batches, updating the counters."""
        with self._decode_lock:
            receiver = self._started_receiver()
            drained_at_s = receiver.drained_at_s  # read before take(): all that arrived by then is taken
            records, times, first_index = receiver.take()
            if not len(records) and not self._tracker.held:
                return
            tracker = self._tracker
            records, times = tracker.push(records, times, first_index, drained_at_s)
            if tracker.bias_restarted:
                tracker.bias_restarted = False
                self._decoded.clear()
                self._decoded_samples = 0
                self._bias_done.set()
            if len(records) == 0:
                return
            status = records["status"].astype(np.uint32)
            counts = records["counts"].astype(np.int64)
            flagged = np.bitwise_and(status, self._error_bits)
            errors = flagged.astype(bool)
            error_count = np.count_nonzero(flagged)
            if error_count:  # saturation bits are error bits in both maps
                self._saturated_count += int(np.count_nonzero(np.bitwise_and(status, self._saturation_bits)))
                self._status_error_count += int(error_count)
            self._last_status = int(status[-1])
            batch = WrenchBatch(time_s=times, wrench=counts * self._scale, counts=counts, status=status,
                                sequence=records["rdt_sequence"].astype(np.int64), saturated=errors,
                                device_time_s=self._sample_clock.device_times(records["ft_sequence"]))
            self.delivered += len(batch)
            self._decoded.append(batch)
            self._decoded_samples += len(batch)
            while self._decoded_samples > MAX_PENDING_SAMPLES and len(self._decoded) > 1:
                self._decoded_samples -= len(self._decoded.popleft())
            window_start, window_count = self._rate_window
            if window_count == 0:
                self._rate_window = (float(times[0]), len(batch))
            else:
                window_count += len(batch)
                span = float(times[-1]) - window_start
                if span >= RATE_WINDOW_S:
                    self._rate_hz = window_count / span
                    self._rate_window = (float(times[-1]), 0)
                else:
                    self._rate_window = (window_start, window_count)

    def _health_locked(self) -> SensorHealth:
        c = self._tracker.counters
        return SensorHealth(received=c.received, lost=c.lost, gaps=c.gaps, longest_gap_s=c.longest_gap_s,
                            duplicate=c.duplicate, out_of_order=c.out_of_order, stalled=c.stalled,
                            saturated=self._saturated_count, status_errors=self._status_error_count,
                            restarts=c.restarts, last_status=self._last_status, rate_hz=self._rate_hz)


def _parse_bool(text: str) -> bool:
    lowered = text.strip().lower()
    if lowered in ("1", "true", "yes", "on"):
        return True
    if lowered in ("0", "false", "no", "off", ""):
        return False
    raise ValueError(text)


_URL_KEYS: dict[str, Callable[[str], Any]] = {
    "tcp_port": int, "http_port": int, "rate_hz": float, "buffered": _parse_bool, "buffer_size": int,
    "timeout_s": float, "counts_per_force": float, "counts_per_torque": float, "force_unit": str,
    "torque_unit": str, "status_map": str, "http_timeout_s": float, "tcp_timeout_s": float,
    "accept_any_port": _parse_bool,
}


def parse_netft_url(url: str) -> dict:
    """Return the constructor keyword arguments (plus ``host``) named by a ``netft://`` URL (no I/O).

    Raises InputError with the expected form and the offending part of the URL (unknown or repeated keys too).
    """
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as error:
        raise InputError(f"sensor URL {url!r}: {error}; expected {URL_FORM}") from None
    if parts.scheme != "netft":
        raise InputError(f"sensor URL {url!r}: scheme must be netft; expected {URL_FORM}")
    if not parts.hostname:
        raise InputError(f"sensor URL {url!r}: no host; expected {URL_FORM}")
    if parts.path not in ("", "/"):
        raise InputError(f"sensor URL {url!r}: unexpected path {parts.path!r}; expected {URL_FORM}")
    problem = host_problem(parts.hostname)
    if problem is not None:
        raise InputError(f"sensor URL {url!r}: host {parts.hostname!r} is not an IP address or host name ({problem}); "
                         f"expected {URL_FORM}")
    kwargs: dict = {"host": parts.hostname}
    if port is not None:
        if port == 0:
            raise InputError(f"sensor URL {url!r}: RDT port 0 is not a port; expected {URL_FORM}")
        kwargs["rdt_port"] = port
    for key, value in query_items(url, parts.query, _URL_KEYS):
        try:
            kwargs[key] = _URL_KEYS[key](value)
        except ValueError:
            raise InputError(f"sensor URL {url!r}: {key}={value!r} is not a valid "
                             f"{'boolean' if _URL_KEYS[key] is _parse_bool else _URL_KEYS[key].__name__}") from None
    return kwargs
