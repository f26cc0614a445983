"""ATI Net F/T (and Ethernet Axia) over RDT/UDP, TCP 49151 and HTTP (specs/ati.md §1-3, §6).

``start()`` discovers the scaling twice and cross-checks it: HTTP ``/netftapi2.xml`` (``cfgcpf``, ``cfgcpt``,
``scfgfu``, ``scfgtu``) and TCP READCALINFO (unit codes, counts per unit). Disagreement is an error naming both
answers; a missing source is a warning (``/netftcalapi.xml`` only gives the serial number and a soft check). Values
are converted to SI once: ``wrench = counts × (SI per unit) / counts_per_unit`` (torque is often N-mm: ÷ 1000).

Streaming: one named receive thread owns a UDP socket with a large ``SO_RCVBUF`` and drains it with
``recvfrom_into`` straight into a preallocated byte ring (36-byte records, whole datagrams, also buffered ones of
N × 36 bytes), stamping each datagram with ``time.monotonic()`` when it drains it (after a wake-up the thread
pauses ``COALESCE_S`` = 1 ms, so a stamp may be up to that much after the datagram's arrival). It accepts datagrams only from the sensor's address
and port (others: ``foreign``), never decodes, never raises: a datagram whose length is not a positive multiple of
36 is ``malformed``; silence longer than the timeout is a ``timeout`` and a re-sent start command (``reconnects``,
back-off 0.25 s doubling to 5 s). Readers (``read``, ``average``, ``health``) decode whole batches with numpy
(``np.frombuffer`` of dtype ``>u4,>u4,>u4,6>i4``) and hand out :class:`drivers.sensor.WrenchBatch` objects: no
per-sample Python objects on the fast path.

Sequence tracking (``rdt_sequence``, per stream, first record 1): +1 is normal; a forward gap counts the missing
records as ``lost``; a repeat is a ``duplicate`` (dropped); a late record that was counted lost becomes
``out_of_order`` (no longer lost; dropped, so batches stay in order); a jump back to a small sequence that this
driver did not ask for is a device ``restart``. ``ft_sequence`` equal to the previous one counts as ``stalled``
(the sample is still delivered). Status (§1.8): a sample with an error bit is flagged in ``WrenchBatch.saturated``
and never averaged; the Net F/T and Ethernet Axia bit maps are both known.

URL: ``netft://HOST[:RDT_PORT][?tcp_port=49151&http_port=80&rate_hz=R&buffered=0&buffer_size=N&timeout_s=T
&counts_per_force=C&counts_per_torque=C&force_unit=N&torque_unit=N-mm&status_map=auto|netft|axia]``.
"""

from __future__ import annotations

import collections
import http.client
import logging
import math
import re
import select
import socket
import struct
import sys
import threading
import time
import warnings
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from urllib.parse import parse_qsl, urlencode, urlsplit

import numpy as np

from drivers.sensor import (
    STATUS_HEALTHY_MASK,
    STATUS_SATURATION,
    SensorHealth,
    SensorInfo,
    WrenchAverage,
    WrenchBatch,
)
from ftacq.errors import DeviceConnectionError, DeviceError, DeviceTimeoutError, InputError, SensorFaultError

logger = logging.getLogger(__name__)

# ------------------------------------------------------------------------ protocol (specs/ati.md §1-2)
DEFAULT_RDT_PORT, DEFAULT_TCP_PORT, DEFAULT_HTTP_PORT = 49152, 49151, 80
RDT_HEADER = 0x1234
RDT_STOP, RDT_START, RDT_START_BUFFERED, RDT_RESET_LATCH, RDT_BIAS = 0x0000, 0x0002, 0x0003, 0x0041, 0x0042
RECORD_SIZE = 36
RECORD_DTYPE = np.dtype([("rdt_sequence", ">u4"), ("ft_sequence", ">u4"), ("status", ">u4"), ("counts", ">i4", (6,))])
TCP_READCALINFO = 1
TCP_COMMAND_SIZE, TCP_CALINFO_REPLY_SIZE = 20, 24
UINT32_MASK = 0xFFFF_FFFF
HALF_RANGE = 1 << 31
"""Sequence differences (mod 2³²) at or above this are backward steps."""

FORCE_UNITS = {"lbf": 4.4482216152605, "N": 1.0, "klbf": 4448.2216152605, "kN": 1000.0, "kgf": 9.80665,
               "gf": 0.00980665}
"""Force unit → newtons per unit (specs/ati.md §2, §3.3)."""
TORQUE_UNITS = {"lbf-in": 0.112984829027617, "lbf-ft": 1.3558179483314, "N-m": 1.0, "N-mm": 0.001,
                "kgf-cm": 0.0980665, "kN-m": 1000.0}
"""Torque unit → newton-metres per unit."""
FORCE_UNIT_CODES = {1: "lbf", 2: "N", 3: "klbf", 4: "kN", 5: "kgf", 6: "gf"}
TORQUE_UNIT_CODES = {1: "lbf-in", 2: "lbf-ft", 3: "N-m", 4: "N-mm", 5: "kgf-cm", 6: "kN-m"}
_UNIT_ALIASES = {"nm": "N-m", "n-m": "N-m", "newtonmeter": "N-m", "nmm": "N-mm", "n-mm": "N-mm", "kg-cm": "kgf-cm",
                 "kgcm": "kgf-cm", "kgf-cm": "kgf-cm", "knm": "kN-m", "kn-m": "kN-m", "lbfin": "lbf-in",
                 "lbf-in": "lbf-in", "in-lb": "lbf-in", "inlb": "lbf-in", "in-lbf": "lbf-in", "lbfft": "lbf-ft",
                 "lbf-ft": "lbf-ft", "ft-lb": "lbf-ft", "ftlb": "lbf-ft", "ft-lbf": "lbf-ft", "n": "N",
                 "newton": "N", "lbf": "lbf", "lb": "lbf", "lbs": "lbf", "klbf": "klbf", "kn": "kN", "kgf": "kgf",
                 "kg": "kgf", "gf": "gf", "g": "gf"}

# Status maps (specs/ati.md §1.8): error bits (flag and never average) and saturation bits.
NETFT_ERROR_MASK = UINT32_MASK & ~STATUS_HEALTHY_MASK
NETFT_SATURATION_MASK = STATUS_SATURATION
AXIA_INFORMATIONAL = (1 << 31) | (1 << 28) | (1 << 16) | (1 << 3)
"""Axia bits that are not errors: summary, simulated error, monitor latch, busy."""
AXIA_ERROR_MASK = UINT32_MASK & ~AXIA_INFORMATIONAL
AXIA_SATURATION_MASK = (1 << 30) | (1 << 27) | (1 << 2)
"""Axia: F/T saturated, gage out of range, broken gage."""
STATUS_MAPS = {"netft": (NETFT_ERROR_MASK, NETFT_SATURATION_MASK), "axia": (AXIA_ERROR_MASK, AXIA_SATURATION_MASK)}
NETFT_STATUS_BITS = {31: "error summary", 30: "CPU/RAM error", 29: "digital board error", 28: "analog board error",
                     27: "serial link error", 26: "program memory error", 25: "halted: configuration errors",
                     24: "settings validation error", 23: "configuration incompatible with calibration",
                     22: "network failure", 21: "CAN error", 20: "RDT error", 19: "EtherNet/IP failure",
                     18: "DeviceNet failure", 17: "transducer saturation or A/D error",
                     16: "monitor condition latched", 14: "watchdog timeout", 13: "stack check error",
                     12: "EEPROM failure", 11: "flash failure", 10: "analog board watchdog",
                     9: "excitation current too high", 8: "excitation current too low",
                     7: "analog ground out of range", 6: "analog supply too high", 5: "analog supply too low",
                     4: "serial link data unavailable", 3: "reference voltage error", 2: "temperature error",
                     1: "HTTP protocol failure"}
AXIA_STATUS_BITS = {0: "temperature out of range", 1: "supply voltage out of range", 2: "broken gage",
                    3: "busy", 5: "common error", 16: "monitor condition latched", 27: "gage out of range",
                    28: "simulated error", 29: "calibration checksum error", 30: "F/T saturated",
                    31: "error summary"}

# ------------------------------------------------------------------------ driver tuning
RING_RECORDS = 1 << 16
"""Records the receive ring holds (9 s at 7 kHz) before the receive thread drops datagrams (counted as lost)."""
MAX_DATAGRAM_BYTES = 65536
SLACK_RECORDS = -(-MAX_DATAGRAM_BYTES // RECORD_SIZE)
"""Room past the ring's end so that a whole datagram always fits at the write position (wrapped after)."""
RECEIVE_BUFFER_BYTES = 8 << 20
"""Requested SO_RCVBUF (the kernel caps it at net.core.rmem_max; SO_RCVBUFFORCE, tried first, needs
CAP_NET_ADMIN)."""
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33 if sys.platform.startswith("linux") else None)
"""Linux's SO_RCVBUFFORCE (33; Python's socket module does not name it)."""
POLL_S = 0.05
"""Longest the receive thread blocks before checking its stop flag, seconds."""
DEFAULT_TIMEOUT_S = 0.25
"""Silence after which the stream counts a timeout and re-sends its start command, seconds (at least 10 periods)."""
BACKOFF_INITIAL_S, BACKOFF_MAX_S = 0.25, 5.0
DEFAULT_HTTP_TIMEOUT_S = 2.0
DEFAULT_TCP_TIMEOUT_S = 2.0
START_TIMEOUT_S = 1.0
"""How long start() waits for the first record (at least 3 periods), seconds."""
RESTART_WINDOW = 16
"""An rdt_sequence at or below this after a backward jump is a stream restart."""
EXPECT_RESTART_RECORDS = 256
"""After sending a start, records that continue the old sequence before a restart shows (device does not reset)."""
BIAS_SETTLE_TIMEOUT_S = 1.0
"""How long bias() waits for the restarted (biased) stream before it accepts whatever comes, seconds."""
MAX_TRACKED_MISSING = 4096
"""Missing sequence numbers remembered, so a late record is counted out of order rather than lost."""
MAX_PENDING_SAMPLES = 1_000_000
RATE_WINDOW_S = 1.0
COALESCE_S = 0.001
"""After a wake-up that drained data (and woke the reader), the receive thread pauses this long so that its next
wake-up drains several datagrams: at 7 kHz this halves the CPU cost. Records arriving meanwhile wait at most this
long in the kernel (their receive stamp is taken when drained), seconds; 0 disables it."""
NOTIFY_INTERVAL_S = 0.001
"""The receive thread wakes a waiting reader at most this often, seconds: readers get batches, not single records,
at the cost of at most this much latency."""
AVERAGE_GRACE_S = 1.0
CLOSE_JOIN_TIMEOUT_S = 2.0
URL_FORM = ("netft://HOST[:RDT_PORT][?tcp_port=49151&http_port=80&rate_hz=R&buffered=0&buffer_size=N&timeout_s=T"
            "&counts_per_force=C&counts_per_torque=C&force_unit=N&torque_unit=N-m&status_map=auto]")


def canonical_unit(text: str, kind: str) -> str:
    """Return the canonical unit name ("N", "N-mm", ...) of a device unit string or code; raise DeviceError."""
    table, codes = (FORCE_UNITS, FORCE_UNIT_CODES) if kind == "force" else (TORQUE_UNITS, TORQUE_UNIT_CODES)
    raw = str(text).strip()
    if raw.isdigit() and int(raw) in codes:
        return codes[int(raw)]
    if raw in table:
        return raw
    key = re.sub(r"[\s·.*_]", "", raw).lower().replace("–", "-")
    name = _UNIT_ALIASES.get(key) or _UNIT_ALIASES.get(key.replace("-", ""))
    if name in table:
        return name
    raise DeviceError(f"unknown {kind} unit {text!r}: expected one of {', '.join(table)}")


def status_text(status: int, status_map: str = "netft") -> str:
    """Return the names of the set bits of a status word, e.g. "error summary, transducer saturation or A/D error"."""
    names = AXIA_STATUS_BITS if status_map == "axia" else NETFT_STATUS_BITS
    return ", ".join(names.get(bit, f"bit {bit}") for bit in range(31, -1, -1) if status >> bit & 1) or "ok"


@dataclass(frozen=True)
class Scaling:
    """Counts per unit and units of the active configuration, and where they came from."""

    counts_per_force: float
    counts_per_torque: float
    force_unit: str
    torque_unit: str
    source: str

    @property
    def counts_to_si(self) -> np.ndarray:
        """(6,) multiply counts by this to get N (Fx-Fz) and N·m (Tx-Tz)."""
        return np.array([FORCE_UNITS[self.force_unit] / self.counts_per_force] * 3
                        + [TORQUE_UNITS[self.torque_unit] / self.counts_per_torque] * 3)

    def agrees_with(self, other: "Scaling") -> bool:
        return bool(np.allclose(self.counts_to_si, other.counts_to_si, rtol=1e-6, atol=0.0))

    def describe(self) -> str:
        return (f"{self.source}: {self.counts_per_force:g} counts/{self.force_unit}, "
                f"{self.counts_per_torque:g} counts/{self.torque_unit}")


def parse_flat_xml(text: str) -> dict[str, str]:
    """Return {element name (lower case): text} of a flat XML page; liberal (falls back to a tag scan)."""
    values: dict[str, str] = {}
    try:
        root = ElementTree.fromstring(text.strip().encode() if isinstance(text, str) else text)
        for element in root.iter():
            if element is not root and len(element) == 0:
                values.setdefault(element.tag.split("}")[-1].lower(), (element.text or "").strip())
        if values:
            return values
    except ElementTree.ParseError:
        pass
    for name, value in re.findall(r"<([A-Za-z_][\w.-]*)>([^<]*)</\1>", text):
        values.setdefault(name.lower(), value.strip())
    return values


class NetFTSensor:
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

    The constructor does no I/O. ``start()`` discovers, opens the socket, starts the receive thread and the
    stream and waits for the first record. ``close()`` sends stop (0x0000) and joins the thread.
    """

    def __init__(self, host: str, rdt_port: int = DEFAULT_RDT_PORT, *, tcp_port: int = DEFAULT_TCP_PORT,
                 http_port: int = DEFAULT_HTTP_PORT, rate_hz: float | None = None, buffered: bool = False,
                 buffer_size: int | None = None, timeout_s: float | None = None,
                 counts_per_force: float | None = None, counts_per_torque: float | None = None,
                 force_unit: str | None = None, torque_unit: str | None = None, status_map: str = "auto",
                 http_timeout_s: float = DEFAULT_HTTP_TIMEOUT_S, tcp_timeout_s: float = DEFAULT_TCP_TIMEOUT_S,
                 accept_any_port: bool = False) -> None:
        if not host:
            raise InputError(f"Net F/T host is empty; expected {URL_FORM}")
        for name, port in (("rdt_port", rdt_port), ("tcp_port", tcp_port), ("http_port", http_port)):
            _check_range(name, port, 1, 65535)
        if rate_hz is not None:
            _check_range("rate_hz", rate_hz, 1e-3, 1e6)
        if buffer_size is not None:
            _check_range("buffer_size", buffer_size, 1, 40)
        if timeout_s is not None:
            _check_range("timeout_s", timeout_s, 1e-3, 3600.0)
        if status_map not in ("auto", "netft", "axia"):
            raise InputError(f"status_map {status_map!r}: must be auto, netft or axia")
        overrides = (counts_per_force, counts_per_torque, force_unit, torque_unit)
        if any(v is not None for v in overrides) and not all(v is not None for v in overrides):
            raise InputError("counts_per_force, counts_per_torque, force_unit and torque_unit override discovery "
                             "only all together")
        self._override = None
        if all(v is not None for v in overrides):
            _check_range("counts_per_force", counts_per_force, 1e-9, 1e12)
            _check_range("counts_per_torque", counts_per_torque, 1e-9, 1e12)
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
        self.coalesce_s = COALESCE_S
        # receive side (written by the receive thread only)
        self._ring = bytearray((RING_RECORDS + SLACK_RECORDS) * RECORD_SIZE)
        self._ring_records = np.frombuffer(self._ring, dtype=RECORD_DTYPE)
        self._times = np.zeros(self._ring_records.shape[0])
        self._written = 0  # records written into the ring (monotonic)
        self._consumed = 0  # records taken out by the decoder (monotonic)
        self._waiters = 0
        self._data_ready = threading.Condition()
        self._rx = SensorHealth()  # received-side counters: malformed, foreign, timeouts, reconnects
        self.overflowed = 0
        self.socket_errors = 0
        self.receive_buffer_bytes = 0
        # decode side (under _decode_lock)
        self._decode_lock = threading.RLock()
        self._health = SensorHealth()
        self._decoded: collections.deque[WrenchBatch] = collections.deque()
        self._decoded_samples = 0
        self._last_rdt: int | None = None
        self._last_ft: int | None = None
        self._missing: dict[int, None] = {}
        self._start_events: collections.deque[tuple[int, bool]] = collections.deque()
        self._expect_restart = False
        self._expect_continuing = 0
        self._bias_discarding = False
        self._bias_done = threading.Event()
        self.ft_backward = 0
        self.delivered = 0
        self._rate_window = (0.0, 0)
        self._scale = np.zeros(6)
        self._error_mask, self._saturation_mask = STATUS_MAPS["netft"]
        # lifecycle
        self._sock: socket.socket | None = None
        self._address: tuple | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._thread_error: BaseException | None = None
        self._send_lock = threading.Lock()
        self._started = self._closed = False

    # ------------------------------------------------------------------ construction from a URL

    @classmethod
    def from_url(cls, url: str, **options) -> "NetFTSensor":
        """Return an unstarted driver for a ``netft://`` URL (module docstring); ``options`` override its keys."""
        kwargs = parse_netft_url(url)
        kwargs.update(options)
        host = kwargs.pop("host")
        return cls(host, **kwargs)

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> None:
        """Discover units and counts per unit (HTTP and TCP, cross-checked), set the rate if asked, open the
        socket, start the receive thread and the stream, and wait for the first record.

        Raises DeviceConnectionError (unreachable, unresolvable), DeviceError (HTTP and TCP disagree, unknown
        units), DeviceTimeoutError (no RDT record in time).
        """
        if self._closed:
            raise DeviceError("NetFTSensor.start() after close(); make a new driver")
        if self._started:
            return
        self._address = self._resolve()
        self._discover()
        self._open_socket()
        self._started = True
        self._thread = threading.Thread(target=self._receive_loop, name=f"NetFT-rx-{self.host}:{self.rdt_port}",
                                        daemon=False)
        self._thread.start()
        try:
            self._send_start()
            wait_s = max(START_TIMEOUT_S, 3.0 / self.info.rate_hz) if self.info.rate_hz > 0 else START_TIMEOUT_S
            deadline = time.monotonic() + wait_s
            with self._data_ready:
                while self._written == 0 and time.monotonic() < deadline:
                    self._data_ready.wait(min(POLL_S, max(deadline - time.monotonic(), 0.0)))
            if self._written == 0:
                raise DeviceTimeoutError(
                    f"Net F/T {self.host}: no RDT data on UDP port {self.rdt_port} within "
                    f"{wait_s:.2g} s (HTTP or TCP answered; is RDT "
                    f"enabled (comrdte) and is the RDT port right?){self._rx_problems()}"
                    + ("; records came from another address or port: if the box sends from another port, add "
                       "accept_any_port=1 to the URL" if self._rx.foreign else ""))
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Send stop (0x0000), join the receive thread, close the socket. Safe to call twice.

        Re-raises (as DeviceError) an unexpected error that ended the receive thread."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(CLOSE_JOIN_TIMEOUT_S)
            if self._thread.is_alive():
                logger.error("%s did not stop within %.1f s", self._thread.name, CLOSE_JOIN_TIMEOUT_S)
        if self._sock is not None and self._started:
            self._send(RDT_STOP)  # after the thread stopped, so no reconnect restarts the stream
        if self._sock is not None:
            self._sock.close()
        with self._data_ready:
            self._data_ready.notify_all()
        if self._thread_error is not None:
            raise DeviceError(f"Net F/T receive thread failed: {self._thread_error!r}") from self._thread_error

    def __enter__(self) -> "NetFTSensor":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        if getattr(self, "_started", False) and not getattr(self, "_closed", True):
            warnings.warn(f"{self!r} was not closed", ResourceWarning, stacklevel=2)

    def __repr__(self) -> str:
        state = "closed" if self._closed else "streaming" if self._started else "not started"
        return (f"NetFTSensor(host={self.host!r}, rdt_port={self.rdt_port}, tcp_port={self.tcp_port}, "
                f"http_port={self.http_port}, rate_hz={self.info.rate_hz:g}, buffered={self.buffered}, {state})")

    # ------------------------------------------------------------------ the sensor contract

    def read(self, timeout_s: float | None = 1.0) -> WrenchBatch:
        """Return every sample received since the last call, oldest first; wait up to ``timeout_s`` seconds
        (None = forever) for at least one. Raises DeviceTimeoutError when none arrives in time."""
        self._require_started()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            batch = self._take()
            if len(batch):
                return batch
            self._raise_if_dead()
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                health = self.health()
                raise DeviceTimeoutError(
                    f"no sample from the Net F/T {self.host}:{self.rdt_port} within {timeout_s} s "
                    f"({health.received} received so far, {health.timeouts} timeouts, {health.reconnects} "
                    f"reconnects){self._rx_problems()}")
            self._wait_for_data(POLL_S if remaining is None else min(remaining, POLL_S))

    def average(self, duration_s: float, timeout_s: float | None = None) -> WrenchAverage:
        """Collect fresh samples for ``duration_s`` seconds and return their mean and sample standard deviation.

        Samples already waiting are discarded. Samples with an error status (saturation included) are excluded
        and counted in ``saturated``; ``lost`` counts records lost during the window. Raises DeviceTimeoutError
        when no sample arrives by ``timeout_s`` (default duration + 1 s) and SensorFaultError when every sample
        was flagged.
        """
        self._require_started()
        _check_range("duration_s", duration_s, 0.0, 3600.0)
        timeout_s = duration_s + AVERAGE_GRACE_S if timeout_s is None else timeout_s
        self._take()
        lost_before = self.health().lost
        start = time.monotonic()
        batches = []
        while True:
            now = time.monotonic()
            if (now - start >= duration_s and batches) or now - start >= timeout_s:
                break
            wait = min(max(start + duration_s - now, 0.0), start + timeout_s - now)
            try:
                batches.append(self.read(timeout_s=max(wait, 1e-3)))
            except DeviceTimeoutError:
                continue
        batch = WrenchBatch.concatenate(batches)
        lost = self.health().lost - lost_before
        if len(batch) == 0:
            raise DeviceTimeoutError(f"no sample from the Net F/T {self.host}:{self.rdt_port} within "
                                     f"{timeout_s:.3g} s while averaging ({lost} lost)")
        good = ~batch.saturated
        count = int(good.sum())
        if count == 0:
            last = int(batch.status[-1])
            raise SensorFaultError(f"all {len(batch)} samples in the {duration_s} s window had an error status "
                                   f"(last status {last:#010x}: {status_text(last, self.status_map)})")
        wrench = batch.wrench[good]
        return WrenchAverage(mean=wrench.mean(axis=0), std=wrench.std(axis=0, ddof=1) if count > 1 else np.zeros(6),
                             count=count, saturated=int(len(batch) - count), lost=int(lost),
                             duration_s=float(batch.time_s[-1] - batch.time_s[0]) if len(batch) > 1 else 0.0)

    def bias(self, timeout_s: float = BIAS_SETTLE_TIMEOUT_S) -> None:
        """Tare on the device (RDT 0x0042), then restart the stream so that every later sample is biased.

        Records received before the restart are discarded. A device that does not restart its sequence on a
        new start is given ``timeout_s`` seconds, after which everything received so far is discarded.
        """
        self._require_started()
        with self._decode_lock:
            self._bias_done.clear()
            self._start_events.append((self._written, True))
        self._send(RDT_BIAS)
        self._send(RDT_START_BUFFERED if self.buffered else RDT_START)
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
                self._bias_discarding = False  # a late restart still counts as ours (expect_restart stays)
                self._start_events = collections.deque((index, False) for index, _ in self._start_events)
                self._decoded.clear()
                self._decoded_samples = 0

    def reset_latch(self) -> None:
        """Clear the monitor-condition latch (RDT 0x0041)."""
        self._require_started()
        self._send(RDT_RESET_LATCH)

    def health(self) -> SensorHealth:
        """Return a snapshot: received (well-formed records), lost, duplicate, out_of_order, stalled, restarts,
        saturated (saturation bits), status_errors (any error bit), malformed, foreign (other senders), timeouts,
        reconnects, last_status and the measured rate_hz."""
        if self._started and not self._closed:
            self._decode()
        with self._decode_lock:
            snapshot = self._health.snapshot()
        snapshot.malformed, snapshot.foreign = self._rx.malformed, self._rx.foreign
        snapshot.timeouts, snapshot.reconnects = self._rx.timeouts, self._rx.reconnects
        return snapshot

    @property
    def local_address(self) -> tuple | None:
        """The (address, port) this driver receives RDT records on (None before start)."""
        return self._sock.getsockname() if self._sock is not None and not self._closed else None

    # ------------------------------------------------------------------ discovery

    def _resolve(self) -> tuple:
        try:
            infos = socket.getaddrinfo(self.host, self.rdt_port, type=socket.SOCK_DGRAM)
        except socket.gaierror as error:
            raise DeviceConnectionError(f"cannot resolve Net F/T host {self.host!r}: {error}") from error
        infos.sort(key=lambda info: info[0] != socket.AF_INET)
        family, _, _, _, address = infos[0]
        self._family = family
        return address

    def _http_get(self, path: str) -> str:
        """GET a page; return its text or raise DeviceConnectionError / DeviceError."""
        host = self._address[0]
        connection = http.client.HTTPConnection(host, self.http_port, timeout=self.http_timeout_s)
        try:
            connection.request("GET", path, headers={"Host": self.host})
            response = connection.getresponse()
            body = response.read(1 << 20)
        except (OSError, http.client.HTTPException) as error:
            raise DeviceConnectionError(f"HTTP {self.host}:{self.http_port}{path}: {error or type(error).__name__}") from error
        finally:
            connection.close()
        if response.status != 200:
            raise DeviceError(f"HTTP {self.host}:{self.http_port}{path}: status {response.status} {response.reason}")
        return body.decode("utf-8", errors="replace")

    def _read_calinfo(self) -> tuple[int, int, int, int, tuple[int, ...]]:
        """TCP READCALINFO → (force code, torque code, CpF, CpT, scale factors)."""
        try:
            with socket.create_connection((self._address[0], self.tcp_port), timeout=self.tcp_timeout_s) as sock:
                sock.sendall(bytes([TCP_READCALINFO]) + bytes(TCP_COMMAND_SIZE - 1))
                reply = b""
                while len(reply) < TCP_CALINFO_REPLY_SIZE:
                    chunk = sock.recv(TCP_CALINFO_REPLY_SIZE - len(reply))
                    if not chunk:
                        break
                    reply += chunk
        except OSError as error:
            raise DeviceConnectionError(f"TCP {self.host}:{self.tcp_port} READCALINFO: {error or type(error).__name__}") from error
        if len(reply) != TCP_CALINFO_REPLY_SIZE or reply[:2] != b"\x12\x34":
            raise DeviceError(f"TCP {self.host}:{self.tcp_port} READCALINFO: bad reply {reply.hex()!r} "
                              f"(expected {TCP_CALINFO_REPLY_SIZE} bytes starting 1234)")
        _, force_code, torque_code, cpf, cpt, *scales = struct.unpack(">HBBII6H", reply)
        return force_code, torque_code, cpf, cpt, tuple(scales)

    def _discover(self) -> None:
        problems: list[str] = []
        api: dict[str, str] = {}
        try:
            api = parse_flat_xml(self._http_get("/netftapi2.xml"))
        except DeviceError as error:
            problems.append(str(error))
        if api and (self.requested_rate_hz is not None or self.requested_buffer_size is not None):
            api = self._configure_rate(api)
        calibration_page: dict[str, str] = {}
        if api:
            try:
                calibration_page = parse_flat_xml(self._http_get("/netftcalapi.xml"))
            except DeviceError as error:
                logger.warning("Net F/T %s: /netftcalapi.xml unavailable (%s); using /netftapi2.xml only",
                               self.host, error)
        calinfo = None
        try:
            calinfo = self._read_calinfo()
        except DeviceError as error:
            problems.append(str(error))

        http_scaling = tcp_scaling = None
        if api:
            http_scaling = self._scaling_from_xml(api, ("cfgcpf", "cfgcpt", "scfgfu", "scfgtu", "cfgfu", "cfgtu"),
                                                  "HTTP /netftapi2.xml")
        if http_scaling is None and calibration_page:
            http_scaling = self._scaling_from_xml(calibration_page, ("calcpf", "calcpt", "scalfu", "scaltu", "calfu", "caltu"),
                                                  "HTTP /netftcalapi.xml")
        if calinfo is not None:
            force_code, torque_code, cpf, cpt, scales = calinfo
            try:
                tcp_scaling = Scaling(float(cpf), float(cpt), canonical_unit(str(force_code), "force"),
                                      canonical_unit(str(torque_code), "torque"), "TCP READCALINFO")
            except DeviceError as error:
                problems.append(f"TCP READCALINFO: {error}")
            if tcp_scaling is not None and (cpf <= 0 or cpt <= 0):
                problems.append(f"TCP READCALINFO: counts per unit {cpf}, {cpt} must be positive")
                tcp_scaling = None

        if self._override is not None:
            scaling = self._override
            for other in (http_scaling, tcp_scaling):
                if other is not None and not other.agrees_with(scaling):
                    logger.warning("Net F/T %s: URL scaling (%s) differs from the device's (%s); using the URL's",
                                   self.host, scaling.describe(), other.describe())
        elif http_scaling is not None and tcp_scaling is not None:
            if not http_scaling.agrees_with(tcp_scaling):
                raise DeviceError(
                    f"Net F/T {self.host}: the device's two answers about scaling disagree — {http_scaling.describe()}; "
                    f"{tcp_scaling.describe()}. Check the active configuration (setcfgsel) or pass "
                    f"counts_per_force, counts_per_torque, force_unit and torque_unit in the URL")
            scaling = http_scaling
        elif http_scaling is not None or tcp_scaling is not None:
            scaling = http_scaling or tcp_scaling
            logger.warning("Net F/T %s: scaling from %s only (%s)", self.host, scaling.source, "; ".join(problems))
        else:
            if not api and calinfo is None:
                raise DeviceConnectionError(f"cannot reach the Net F/T at {self.host}: " + "; ".join(problems))
            why = "; ".join(problems) or "netftapi2.xml has no cfgcpf/cfgcpt/scfgfu/scfgtu"
            raise DeviceError(f"Net F/T {self.host}: no counts per unit found ({why}); pass counts_per_force, "
                              f"counts_per_torque, force_unit and torque_unit in the URL")
        self.scaling = scaling
        self._scale = scaling.counts_to_si
        product = api.get("prodname", "")
        if self.status_map_setting == "auto":
            self.status_map = "axia" if ("axia" in product.lower() or "setrate" in api) else "netft"
        else:
            self.status_map = self.status_map_setting
        self._error_mask, self._saturation_mask = STATUS_MAPS[self.status_map]
        rate = _to_float(api.get("comrdtrate")) or float(self.requested_rate_hz or 0.0)
        buffer_size = int(_to_float(api.get("comrdtbsiz")) or 1)
        self.timeout_s = self.requested_timeout_s or max(DEFAULT_TIMEOUT_S, 10.0 / rate if rate > 0 else 1.0)
        self.info = SensorInfo(
            transport="netft",
            serial=api.get("cfgcalsn") or calibration_page.get("calsn", ""),
            firmware=api.get("mfgdigver", ""),
            force_unit=scaling.force_unit, torque_unit=scaling.torque_unit,
            counts_per_force=scaling.counts_per_force, counts_per_torque=scaling.counts_per_torque,
            rate_hz=rate, model=product,
            extra={"product": product, "host": self.host, "rdt_port": self.rdt_port, "tcp_port": self.tcp_port,
                   "http_port": self.http_port, "scaling_source": scaling.source,
                   "sources_missing": problems, "status_map": self.status_map, "buffered": self.buffered,
                   "buffer_size": buffer_size, "runstat": api.get("runstat", ""),
                   "max_rating": api.get("cfgmr", ""), "filter": api.get("setuserfilter", "")})

    def _scaling_from_xml(self, values: dict[str, str], keys: tuple[str, ...], source: str) -> Scaling | None:
        cpf_key, cpt_key, fu_key, tu_key, fu_code_key, tu_code_key = keys
        cpf, cpt = _to_float(values.get(cpf_key)), _to_float(values.get(cpt_key))
        force_text = values.get(fu_key) or values.get(fu_code_key)
        torque_text = values.get(tu_key) or values.get(tu_code_key)
        if not cpf or not cpt or cpf <= 0 or cpt <= 0 or not force_text or not torque_text:
            return None
        try:
            return Scaling(cpf, cpt, canonical_unit(force_text, "force"), canonical_unit(torque_text, "torque"), source)
        except DeviceError as error:
            raise DeviceError(f"Net F/T {self.host}: {source}: {error}") from None

    def _configure_rate(self, api: dict[str, str]) -> dict[str, str]:
        """Set comrdtrate / comrdtbsiz over CGI, then re-read netftapi2.xml (the box quantises and clamps)."""
        params = {}
        if self.requested_rate_hz is not None:
            params["comrdtrate"] = f"{self.requested_rate_hz:g}"
        if self.requested_buffer_size is not None:
            params["comrdtbsiz"] = str(int(self.requested_buffer_size))
        try:
            self._http_get("/comm.cgi?" + urlencode(params))
            api = parse_flat_xml(self._http_get("/netftapi2.xml"))
        except DeviceError as error:
            logger.warning("Net F/T %s: could not set %s over HTTP (%s); streaming at the device's setting",
                           self.host, params, error)
        rate = _to_float(api.get("comrdtrate"))
        if self.requested_rate_hz is not None and rate and abs(rate - self.requested_rate_hz) > 0.01 * self.requested_rate_hz:
            logger.warning("Net F/T %s: asked for %g Hz, the device streams at %g Hz", self.host,
                           self.requested_rate_hz, rate)
        return api

    # ------------------------------------------------------------------ socket and receive thread

    def _open_socket(self) -> None:
        sock = socket.socket(self._family, socket.SOCK_DGRAM)
        for option in (SO_RCVBUFFORCE, socket.SO_RCVBUF):
            if option is None:
                continue
            try:
                sock.setsockopt(socket.SOL_SOCKET, option, RECEIVE_BUFFER_BYTES)
                break
            except OSError:
                continue
        self.receive_buffer_bytes = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        sock.bind(("::" if self._family == socket.AF_INET6 else "0.0.0.0", 0))
        sock.setblocking(False)
        self._sock = sock
        self.info.extra["receive_buffer_bytes"] = self.receive_buffer_bytes

    def _send(self, command: int, count: int = 0) -> None:
        try:
            with self._send_lock:
                self._sock.sendto(struct.pack(">HHI", RDT_HEADER, command, count), self._address)
        except OSError as error:
            self.socket_errors += 1
            logger.debug("Net F/T %s: sending %#06x failed: %s", self.host, command, error)

    def _send_start(self) -> None:
        with self._decode_lock:
            self._start_events.append((self._written, False))
        self._send(RDT_START_BUFFERED if self.buffered else RDT_START)

    def _receive_loop(self) -> None:
        try:
            self._receive()
        except BaseException as error:  # re-raised from close(); the loop below catches everything expected
            self._thread_error = error
            with self._data_ready:
                self._data_ready.notify_all()

    def _receive(self) -> None:
        sock, ring, times, stop = self._sock, memoryview(self._ring), self._times, self._stop
        expected, any_port = self._address, self.accept_any_port
        capacity_mask = RING_RECORDS - 1
        room_needed = SLACK_RECORDS + 1
        scratch = bytearray(MAX_DATAGRAM_BYTES)
        rx = self._rx
        monotonic = time.monotonic
        poller = select.poll()
        poller.register(sock, select.POLLIN)
        last_data_s = last_notify_s = monotonic()
        next_retry_s = last_data_s + self.timeout_s
        backoff_s = BACKOFF_INITIAL_S
        notify_pending = False
        while not stop.is_set():
            try:
                events = poller.poll((NOTIFY_INTERVAL_S if notify_pending else POLL_S) * 1000.0)
                written = self._written
                got = arrived = False
                while events:
                    if written - self._consumed > RING_RECORDS - room_needed:
                        try:
                            sock.recv_into(scratch)
                        except (BlockingIOError, InterruptedError):
                            break
                        except OSError:
                            self.socket_errors += 1
                            break
                        self.overflowed += 1  # the reader fell behind: a gap the decoder counts as lost
                        arrived = True
                        continue
                    position = written & capacity_mask
                    try:
                        size, sender = sock.recvfrom_into(ring[position * RECORD_SIZE:], MAX_DATAGRAM_BYTES)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError:  # ICMP port unreachable etc.: count and keep going
                        self.socket_errors += 1
                        break
                    if sender != expected and (not any_port or sender[0] != expected[0]):
                        rx.foreign += 1
                        continue
                    if size == 0 or size % RECORD_SIZE:
                        rx.malformed += 1
                        continue
                    records = size // RECORD_SIZE
                    now = monotonic()
                    if records == 1:
                        times[position] = now
                    else:
                        times[position:position + records] = now
                        overflow = position + records - RING_RECORDS
                        if overflow > 0:  # wrap: copy the tail past the ring's end to its start
                            ring[:overflow * RECORD_SIZE] = ring[RING_RECORDS * RECORD_SIZE:(position + records) * RECORD_SIZE]
                            times[:overflow] = times[RING_RECORDS:RING_RECORDS + overflow]
                    written += records
                    self._written = written
                    got = True
                now = monotonic()
                if got or arrived:  # the box is streaming (even if the ring is full)
                    last_data_s = now
                    next_retry_s = now + self.timeout_s
                    backoff_s = BACKOFF_INITIAL_S
                    notify_pending = notify_pending or got
                if notify_pending and now - last_notify_s >= NOTIFY_INTERVAL_S:
                    notify_pending = False
                    last_notify_s = now
                    if self._waiters:
                        with self._data_ready:
                            self._data_ready.notify_all()
                if not (got or arrived) and now >= next_retry_s:
                    rx.timeouts += 1
                    rx.reconnects += 1
                    logger.info("Net F/T %s: no data for %.2f s; re-sending start (retry in %.2f s)",
                                self.host, now - last_data_s, backoff_s)
                    self._send_start()
                    next_retry_s = now + backoff_s
                    backoff_s = min(backoff_s * 2.0, BACKOFF_MAX_S)
                if got and self.coalesce_s > 0.0 and not notify_pending:
                    stop.wait(self.coalesce_s)  # let a few datagrams queue: the next wake-up drains them all
            except Exception:  # never raise out of the receive loop
                self.socket_errors += 1
                logger.exception("Net F/T %s: unexpected error in the receive loop", self.host)
                stop.wait(POLL_S)

    def _wait_for_data(self, timeout_s: float) -> None:
        with self._data_ready:
            self._waiters += 1
            try:
                if self._written == self._consumed and not self._stop.is_set():
                    self._data_ready.wait(max(timeout_s, 0.0))
            finally:
                self._waiters -= 1

    def _rx_problems(self) -> str:
        parts = [f"{n} {name}" for name, n in (("malformed", self._rx.malformed), ("foreign", self._rx.foreign),
                                              ("socket errors", self.socket_errors)) if n]
        return f"; datagrams rejected: {', '.join(parts)}" if parts else ""

    # ------------------------------------------------------------------ decoding (reader side)

    def _take(self) -> WrenchBatch:
        with self._decode_lock:
            self._decode()
            if not self._decoded:
                return WrenchBatch.empty()
            batches = list(self._decoded)
            self._decoded.clear()
            self._decoded_samples = 0
        return batches[0] if len(batches) == 1 else WrenchBatch.concatenate(batches)

    def _decode(self) -> None:
        """Move every record the receive thread wrote into decoded batches, updating the counters."""
        with self._decode_lock:
            start, end = self._consumed, self._written
            if end == start:
                return
            count = end - start
            position = start & (RING_RECORDS - 1)
            if position + count <= RING_RECORDS:
                records = self._ring_records[position:position + count].copy()
                times = self._times[position:position + count].copy()
            else:
                head = RING_RECORDS - position
                records = np.concatenate([self._ring_records[position:RING_RECORDS],
                                          self._ring_records[:count - head]])
                times = np.concatenate([self._times[position:RING_RECORDS], self._times[:count - head]])
            self._consumed = end
            rdt = records["rdt_sequence"].astype(np.int64)
            ft = records["ft_sequence"].astype(np.int64)
            keep = self._track(rdt, ft, start)
            health = self._health
            health.received += count
            if not keep.all():
                records, times, rdt = records[keep], times[keep], rdt[keep]
            if len(records) == 0:
                return
            status = records["status"].astype(np.uint32)
            counts = records["counts"].astype(np.int64)
            errors = (status & np.uint32(self._error_mask)) != 0
            saturated = int(np.count_nonzero(status & np.uint32(self._saturation_mask)))
            health.saturated += saturated
            health.status_errors += int(np.count_nonzero(errors))
            health.last_status = int(status[-1])
            batch = WrenchBatch(time_s=times, wrench=counts * self._scale, counts=counts, status=status,
                                sequence=rdt, saturated=errors)
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
                    health.rate_hz = window_count / span
                    self._rate_window = (float(times[-1]), 0)
                else:
                    self._rate_window = (window_start, window_count)

    def _track(self, rdt: np.ndarray, ft: np.ndarray, first_index: int) -> np.ndarray:
        """Classify records by sequence; return the mask of records to deliver (decode lock held)."""
        n = rdt.shape[0]
        if (self._last_rdt is not None and not self._start_events and not self._expect_restart
                and not self._bias_discarding):
            previous = np.empty(n, dtype=np.int64)
            previous[0] = self._last_rdt
            previous[1:] = rdt[:-1]
            step = (rdt - previous) & UINT32_MASK
            if np.all((step >= 1) & (step < HALF_RANGE)):
                gaps = np.flatnonzero(step > 1)
                for i in gaps:
                    self._note_missing(int(previous[i]), int(step[i]) - 1)
                previous[0] = self._last_ft
                previous[1:] = ft[:-1]
                self._health.stalled += int(np.count_nonzero(ft == previous))
                self._last_rdt, self._last_ft = int(rdt[-1]), int(ft[-1])
                return np.ones(n, dtype=bool)
        return self._track_slow(rdt.tolist(), ft.tolist(), first_index)

    def _track_slow(self, rdt: list[int], ft: list[int], first_index: int) -> np.ndarray:
        keep = np.zeros(len(rdt), dtype=bool)
        health = self._health
        for i, (sequence, ft_sequence) in enumerate(zip(rdt, ft)):
            while self._start_events and self._start_events[0][0] <= first_index + i:
                _, is_bias = self._start_events.popleft()
                self._expect_restart, self._expect_continuing = True, 0
                self._bias_discarding = self._bias_discarding or is_bias
            if self._bias_discarding:
                if sequence > RESTART_WINDOW:
                    continue  # sent before the device biased (only bias()'s timeout ends this)
                keep[:i] = False  # the first post-bias record: everything before it is stale
                self._decoded.clear()
                self._decoded_samples = 0
                self._bias_discarding = self._expect_restart = False
                self._bias_done.set()
                self._reset_tracker(sequence, ft_sequence)
                keep[i] = True
                continue
            if self._expect_restart:
                if sequence <= RESTART_WINDOW:
                    self._expect_restart = False
                    self._reset_tracker(sequence, ft_sequence)
                    keep[i] = True
                    continue
                self._expect_continuing += 1
                if self._expect_continuing >= EXPECT_RESTART_RECORDS:
                    self._expect_restart = False  # the device does not restart its sequence on a start
            last = self._last_rdt
            if last is None:
                self._reset_tracker(sequence, ft_sequence)
                keep[i] = True
                continue
            step = (sequence - last) & UINT32_MASK
            if step == 0:
                health.duplicate += 1
                continue
            if step < HALF_RANGE:
                if step > 1:
                    self._note_missing(last, step - 1)
                if ft_sequence == self._last_ft:
                    health.stalled += 1
                elif (ft_sequence - self._last_ft) & UINT32_MASK >= HALF_RANGE:
                    self.ft_backward += 1
                self._last_rdt, self._last_ft = sequence, ft_sequence
                keep[i] = True
                continue
            if sequence in self._missing:  # a late record already counted lost
                del self._missing[sequence]
                health.lost -= 1
                health.out_of_order += 1
                continue
            if sequence <= RESTART_WINDOW < last:
                health.restarts += 1
                logger.warning("Net F/T %s: RDT sequence restarted (%d after %d)", self.host, sequence, last)
                self._reset_tracker(sequence, ft_sequence)
                keep[i] = True
                continue
            health.duplicate += 1
        return keep

    def _note_missing(self, last: int, gap: int) -> None:
        self._health.lost += gap
        if gap > MAX_TRACKED_MISSING:
            return
        for k in range(1, gap + 1):
            self._missing[(last + k) & UINT32_MASK] = None
        while len(self._missing) > MAX_TRACKED_MISSING:
            del self._missing[next(iter(self._missing))]

    def _reset_tracker(self, sequence: int, ft_sequence: int) -> None:
        self._last_rdt, self._last_ft = sequence, ft_sequence
        self._missing.clear()

    # ------------------------------------------------------------------ helpers

    def _require_started(self) -> None:
        if not self._started or self._closed:
            raise DeviceError(f"{self!r}: call start() before reading (and not after close())")

    def _raise_if_dead(self) -> None:
        if self._thread_error is not None:
            raise DeviceError(f"Net F/T receive thread failed: {self._thread_error!r}") from self._thread_error


def _to_float(text) -> float | None:
    try:
        value = float(str(text).strip().split(";")[0])
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


def _check_range(name: str, value, low, high) -> None:
    """Raise InputError naming ``name`` when ``value`` is not a number in [low, high]."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not low <= value <= high:
        raise InputError(f"{name} = {value!r} is out of range {low}..{high}")


def _parse_bool(text: str) -> bool:
    lowered = text.strip().lower()
    if lowered in ("1", "true", "yes", "on"):
        return True
    if lowered in ("0", "false", "no", "off", ""):
        return False
    raise ValueError(text)


_URL_KEYS = {
    "tcp_port": int, "http_port": int, "rate_hz": float, "buffered": _parse_bool, "buffer_size": int,
    "timeout_s": float, "counts_per_force": float, "counts_per_torque": float, "force_unit": str,
    "torque_unit": str, "status_map": str, "http_timeout_s": float, "tcp_timeout_s": float,
    "accept_any_port": _parse_bool,
}


def parse_netft_url(url: str) -> dict:
    """Return the constructor keyword arguments (plus ``host``) named by a ``netft://`` URL.

    Raises InputError with the expected form and the offending part of the URL.
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
    kwargs: dict = {"host": parts.hostname}
    if port is not None:
        if port == 0:
            raise InputError(f"sensor URL {url!r}: RDT port 0 is not a port; expected {URL_FORM}")
        kwargs["rdt_port"] = port
    for key, value in parse_qsl(parts.query, keep_blank_values=True):
        if key not in _URL_KEYS:
            raise InputError(f"sensor URL {url!r}: unknown key {key!r}; known keys: {', '.join(_URL_KEYS)}")
        try:
            kwargs[key] = _URL_KEYS[key](value)
        except ValueError:
            raise InputError(f"sensor URL {url!r}: {key}={value!r} is not a valid "
                             f"{'boolean' if _URL_KEYS[key] is _parse_bool else _URL_KEYS[key].__name__}") from None
    return kwargs


__all__ = ["NetFTSensor", "Scaling", "parse_netft_url", "parse_flat_xml", "canonical_unit", "status_text"]
