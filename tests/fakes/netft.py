"""A fake ATI Net F/T box: RDT over UDP, the TCP command port and the HTTP configuration pages (specs/ati.md §7.1-7.3).

One :class:`FakeNetFT` binds three real sockets on a configurable host (port 0 in tests):

- **RDT (UDP)**: 8-byte commands ``>HHI`` (header 0x1234, command, sample count), plus the 14-byte extended form.
  Records (36 bytes, ``>III6i``) go out **from the same socket** to the address of the latest start command.
  0x0000 stops; 0x0001/0x0002/0x0004 stream one record per datagram; 0x0003 streams ``comrdtbsiz`` records per
  datagram; count N > 0 sends exactly N records, 0 streams until stopped. Every start resets ``rdt_sequence`` to 1;
  ``ft_sequence`` is a power-up counter, +round(7000 / rate) per record, never reset by a start. 0x0042 biases
  (later records carry raw − bias, the stream goes on); 0x0041 clears the monitor latch.
- **TCP**: whole 20-byte commands, many per connection: READFT (16-byte reply, sysCommands bias / clear latch),
  READCALINFO (24 bytes: unit codes, counts per unit, scale factors), WRITETRANSFORM / WRITETHRESHOLD (4 bytes).
- **HTTP**: ``/netftapi2.xml`` and ``/netftcalapi.xml`` (query ignored) and the CGI pages ``comm.cgi``,
  ``setting.cgi``, ``config.cgi``, ``moncon.cgi`` (``k=v&k=v``), which update what the XML and RDT show.

Records are paced at ``comrdtrate`` (quantised to 7000/n Hz, rounded up) against an absolute deadline and sent in
small bursts, so Python keeps up at 7 kHz. ``max_rate_hz`` above 7000 lets a benchmark run the fake faster than a
real box (an unfaithful extension, off by default). The wrench comes from a
:class:`tests.fakes.world.SensorPhysics`, converted to the configured units and counts:
``counts = round(value_in_device_units × counts_per_unit)``, torque possibly in N-mm.

Fault knobs (thread-safe, applied to the next records): :meth:`drop`, :meth:`duplicate`, :meth:`reorder`,
:meth:`send_truncated`, :meth:`send_garbage`, :meth:`go_silent` / :meth:`resume`, :meth:`restart`,
:meth:`stall_ft_sequence`, :meth:`set_status` / :meth:`saturate` / :meth:`latch`, :meth:`set_axia_status`.
Everything received is recorded (:attr:`commands`, :meth:`wait_for_command`). Threads are named, joined in
:meth:`close`, and their errors re-raised there.

Run alone: ``python -m tests.fakes.netft --host 127.0.0.1 --rdt-port 0 [--pose-shm NAME]`` prints one JSON line with
the bound ports and URL, then serves until stdin closes (or SIGTERM / SIGINT). A ``stats`` line on stdin prints the
counters as one JSON line.
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import os
import select
import selectors
import signal
import socket
import stat
import struct
import sys
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, HTTPServer
from urllib.parse import parse_qsl, urlsplit

import numpy as np

# ------------------------------------------------------------------------ protocol constants (specs/ati.md)
RDT_HEADER = 0x1234
RDT_STOP, RDT_START_SINGLE_BLOCK, RDT_START, RDT_START_BUFFERED, RDT_START_MULTI_UNIT = 0x0000, 0x0001, 0x0002, 0x0003, 0x0004
RDT_RESET_LATCH, RDT_BIAS = 0x0041, 0x0042
RDT_EXTENDED_FLAG = 0x8000
RECORD_SIZE = 36
RECORD_DTYPE = np.dtype([("rdt_sequence", ">u4"), ("ft_sequence", ">u4"), ("status", ">u4"), ("counts", ">i4", (6,))])
UINT32_MASK = 0xFFFF_FFFF
INT32_MAX, INT32_MIN = 2**31 - 1, -(2**31)

INTERNAL_RATE_HZ = 7000.0
"""The Net F/T's internal sample rate; ``comrdtrate`` is quantised to INTERNAL_RATE_HZ / n."""
MIN_BUFFER_SIZE, MAX_BUFFER_SIZE = 1, 40

TCP_COMMAND_SIZE = 20
TCP_READFT, TCP_READCALINFO, TCP_WRITETRANSFORM, TCP_WRITETHRESHOLD = 0, 1, 2, 3
INT16_MAX = 32767

STATUS_SUMMARY = 0x8000_0000
STATUS_SATURATION = 0x0002_0000
STATUS_LATCH = 0x0001_0000

FORCE_UNIT_CODES = {"lbf": 1, "N": 2, "klbf": 3, "kN": 4, "kgf": 5, "gf": 6}
TORQUE_UNIT_CODES = {"lbf-in": 1, "lbf-ft": 2, "N-m": 3, "Nm": 3, "N-mm": 4, "Nmm": 4, "kgf-cm": 5, "kN-m": 6}
NEWTONS_PER_FORCE_UNIT = {"lbf": 4.4482216152605, "N": 1.0, "klbf": 4448.2216152605, "kN": 1000.0,
                          "kgf": 9.80665, "gf": 0.00980665}
NEWTON_METRES_PER_TORQUE_UNIT = {"lbf-in": 0.112984829027617, "lbf-ft": 1.3558179483314, "N-m": 1.0, "Nm": 1.0,
                                 "N-mm": 0.001, "Nmm": 0.001, "kgf-cm": 0.0980665, "kN-m": 1000.0}

# ------------------------------------------------------------------------ fake's own timing
POLL_S = 0.05
"""Longest a fake thread blocks before checking its stop flag, seconds."""
CLOSE_JOIN_TIMEOUT_S = 5.0
MAX_BURST_RECORDS = 4096
"""Most records sent in one go; a longer backlog (the fake was descheduled) is skipped, not flooded."""
SAMPLE_CHUNK_S = 0.004
"""Physics samples are drawn in chunks covering this much stream time (the pose is read once per chunk)."""
DEFAULT_WAIT_S = 5.0


@dataclass(frozen=True)
class ReceivedCommand:
    """One thing the fake received. ``source`` is "udp", "tcp" or "http".

    udp: ``code`` = RDT command, ``count`` = sample count, ``raw`` = the datagram. tcp: ``code`` = command byte,
    ``raw`` = the 20 bytes. http: ``code`` = the path (e.g. "/comm.cgi"), ``params`` = the query.
    """

    source: str
    code: int | str
    count: int = 0
    address: tuple = ()
    time_s: float = 0.0
    raw: bytes = b""
    params: dict = field(default_factory=dict)


def quantise_rate_hz(requested_hz: float, max_rate_hz: float = INTERNAL_RATE_HZ) -> tuple[float, int]:
    """Return (rate Hz, ft_sequence step) the box streams at for a requested ``comrdtrate``.

    Up to the internal rate: INTERNAL_RATE_HZ / n with n = floor(7000 / requested), i.e. rounded **up**
    (150 → 7000/46 ≈ 152.2). Above it (only when ``max_rate_hz`` allows): the requested rate, step 1.
    """
    requested_hz = max(float(requested_hz), 1.0)
    if requested_hz > INTERNAL_RATE_HZ and max_rate_hz > INTERNAL_RATE_HZ:
        return min(requested_hz, max_rate_hz), 1
    divisor = max(1, int(INTERNAL_RATE_HZ // min(requested_hz, INTERNAL_RATE_HZ)))
    return INTERNAL_RATE_HZ / divisor, divisor


class FakeNetFT:
    """A simulated ATI Net F/T on loopback (see the module docstring).

    Args:
        physics: a :class:`tests.fakes.world.SensorPhysics` (``sample(n)`` → (n, 6) N and N·m).
        host: address to bind all three sockets on. rdt_port, tcp_port, http_port: 0 picks free ports.
        rate_hz: initial ``comrdtrate`` (quantised as the box does). buffer_size: initial ``comrdtbsiz`` (1-40).
        force_unit, torque_unit: unit strings the box reports ("N", "Nm", "N-mm", "lbf", ...).
        counts_per_force, counts_per_torque: counts per force / torque unit (different on purpose).
        serial: calibration serial number. prodname: product name, or None to omit it (legacy firmware).
        serve_calibration_page: False makes ``/netftcalapi.xml`` answer 404 (older firmware).
        serve_tcp: False serves no TCP port. send_from_other_socket: records leave from another UDP port (a
        box that breaks spec §7.1.1; connected clients drop them).
        max_rate_hz: highest streaming rate; above 7000 only for benchmarks (not what a real box does).
        max_rating: (6,) max rating per axis in device units (``cfgmr``; sets the READFT scale factors).
        seed: seed of the garbage-datagram generator.
    """

    def __init__(self, physics, host: str = "127.0.0.1", rdt_port: int = 0, tcp_port: int = 0, http_port: int = 0,
                 rate_hz: float = INTERNAL_RATE_HZ, buffer_size: int = 1, force_unit: str = "N",
                 torque_unit: str = "Nm", counts_per_force: int = 1_000_000, counts_per_torque: int = 500_000,
                 serial: str = "FT12345", prodname: str | None = "Net F/T (simulated)",
                 serve_calibration_page: bool = True, serve_tcp: bool = True, send_from_other_socket: bool = False,
                 max_rate_hz: float = INTERNAL_RATE_HZ, max_rating: tuple | None = None, firmware: str = "2.2.59",
                 seed: int = 0) -> None:
        if force_unit not in FORCE_UNIT_CODES:
            raise ValueError(f"force_unit {force_unit!r}: must be one of {sorted(FORCE_UNIT_CODES)}")
        if torque_unit not in TORQUE_UNIT_CODES:
            raise ValueError(f"torque_unit {torque_unit!r}: must be one of {sorted(TORQUE_UNIT_CODES)}")
        self.physics = physics
        self.host = host
        self._requested_ports = (rdt_port, tcp_port, http_port)
        self.force_unit, self.torque_unit = force_unit, torque_unit
        self.counts_per_force, self.counts_per_torque = int(counts_per_force), int(counts_per_torque)
        self.serial, self.prodname, self.firmware = serial, prodname, firmware
        self.serve_calibration_page = serve_calibration_page
        self.serve_tcp = serve_tcp
        self.send_from_other_socket = send_from_other_socket
        self.max_rate_hz = float(max_rate_hz)
        if max_rating is None:
            max_rating = (660.0 / NEWTONS_PER_FORCE_UNIT[force_unit],) * 2 + (1980.0 / NEWTONS_PER_FORCE_UNIT[force_unit],) \
                + (60.0 / NEWTON_METRES_PER_TORQUE_UNIT[torque_unit],) * 3
        self.max_rating = tuple(float(v) for v in max_rating)
        self._rng = np.random.default_rng(seed)
        self._update_scaling()

        self._lock = threading.Condition()
        self._settings = {"comrdtrate": 0.0, "comrdtbsiz": int(buffer_size), "comrdte": 1, "setuserfilter": 0,
                          "setpke": 0, "setcfgsel": 0, "cfgcalsel": 0, "cfgnam": "", "setmce": 0,
                          "setbias": [0] * 6, "monitor": {}}
        self.set_rate(rate_hz)
        self._settings["comrdtbsiz"] = int(min(max(int(buffer_size), MIN_BUFFER_SIZE), MAX_BUFFER_SIZE))
        # stream state (RDT thread; knobs take the lock)
        self._target: tuple | None = None
        self._mode = RDT_START
        self._remaining: int | None = None
        self._rdt_sequence = 0
        self._ft_sequence = 0
        self._bias_counts = np.zeros(6, dtype=np.int64)
        self._latched = False
        self._stream_t0 = 0.0
        self._stream_done = 0
        self._silent = False
        self._pending_faults: collections.deque = collections.deque()
        self._drop_remaining = 0
        self._stall_remaining = 0
        self._status_bits = 0
        self._status_remaining: int | None = None
        self._restart_requested = False
        self._held: list[bytes] = []
        self.calinfo_override: tuple[int, int, int, int] | None = None
        """(force code, torque code, CpF, CpT) READCALINFO answers instead of the configuration (a box whose
        TCP and HTTP answers disagree)."""
        self._sample_buffer = np.empty((0, 6))
        self._last_counts = np.zeros(6, dtype=np.int64)
        # observables
        self.commands: list[ReceivedCommand] = []
        self.records_produced = 0
        self.records_sent = 0
        self.datagrams_sent = 0
        self.records_dropped = 0
        self.send_errors = 0
        self.skipped_backlog = 0
        self.streams_started = 0
        # sockets and threads
        self._udp: socket.socket | None = None
        self._udp_out: socket.socket | None = None
        self._tcp: socket.socket | None = None
        self._http: HTTPServer | None = None
        self._threads: list[threading.Thread] = []
        self._errors: list[BaseException] = []
        self._stop = threading.Event()
        self.rdt_port = self.tcp_port = self.http_port = 0
        self._started = self._closed = False

    def _update_scaling(self) -> None:
        """Recompute the SI → counts factors and the READFT scale factors from units and counts per unit."""
        self._si_to_counts = np.array(
            [self.counts_per_force / NEWTONS_PER_FORCE_UNIT[self.force_unit]] * 3
            + [self.counts_per_torque / NEWTON_METRES_PER_TORQUE_UNIT[self.torque_unit]] * 3)
        cp = np.array([self.counts_per_force] * 3 + [self.counts_per_torque] * 3, dtype=float)
        self.scale_factors = tuple(int(min(max(1, math.ceil(m * c / INT16_MAX)), 0xFFFF))
                                   for m, c in zip(self.max_rating, cp))
        """READFT scale factors (u16): ⌈max rating × counts per unit / 32767⌉, at most 65535 (values saturate)."""

    def set_units(self, force_unit: str | None = None, torque_unit: str | None = None) -> None:
        """Change the configured units as config.cgi ``cfgfu`` / ``cfgtu`` does: counts per unit and max ratings
        follow, so the counts per newton (newton-metre) stay the same."""
        with self._lock:
            if force_unit is not None:
                ratio = NEWTONS_PER_FORCE_UNIT[force_unit] / NEWTONS_PER_FORCE_UNIT[self.force_unit]
                self.counts_per_force = int(round(self.counts_per_force * ratio))
                self.max_rating = tuple(v / ratio for v in self.max_rating[:3]) + self.max_rating[3:]
                self.force_unit = force_unit
            if torque_unit is not None:
                ratio = NEWTON_METRES_PER_TORQUE_UNIT[torque_unit] / NEWTON_METRES_PER_TORQUE_UNIT[self.torque_unit]
                self.counts_per_torque = max(1, int(round(self.counts_per_torque * ratio)))
                self.max_rating = self.max_rating[:3] + tuple(v / ratio for v in self.max_rating[3:])
                self.torque_unit = torque_unit
            self._update_scaling()

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> "FakeNetFT":
        """Bind the sockets and start the threads; return self."""
        if self._started:
            return self
        rdt_port, tcp_port, http_port = self._requested_ports
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        self._udp = socket.socket(family, socket.SOCK_DGRAM)
        self._udp.bind((self.host, rdt_port))
        self._udp.setblocking(False)
        try:
            self._udp.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
        except OSError:
            pass
        self.rdt_port = self._udp.getsockname()[1]
        if self.send_from_other_socket:  # a misbehaving box: records come from another port (clients drop them)
            self._udp_out = socket.socket(family, socket.SOCK_DGRAM)
            self._udp_out.bind((self.host, 0))
        if self.serve_tcp:
            self._tcp = socket.socket(family, socket.SOCK_STREAM)
            self._tcp.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._tcp.bind((self.host, tcp_port))
            self._tcp.listen(8)
            self._tcp.setblocking(False)
            self.tcp_port = self._tcp.getsockname()[1]
        self._http = _make_http_server(self, (self.host, http_port), family)
        self.http_port = self._http.server_address[1]
        self._started = True
        self._spawn("rdt", self._rdt_loop)
        if self._tcp is not None:
            self._spawn("tcp", self._tcp_loop)
        self._spawn("http", lambda: self._http.serve_forever(poll_interval=POLL_S))
        return self

    def _spawn(self, name: str, target) -> None:
        def run() -> None:
            try:
                target()
            except BaseException as error:  # re-raised in close()
                self._errors.append(error)
        thread = threading.Thread(target=run, name=f"FakeNetFT-{name}-{self.rdt_port}", daemon=False)
        self._threads.append(thread)
        thread.start()

    def close(self) -> None:
        """Stop the threads, join them, close the sockets; re-raise the first thread error. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._http is not None and self._started:
            self._http.shutdown()
        for thread in self._threads:
            thread.join(CLOSE_JOIN_TIMEOUT_S)
        alive = [t.name for t in self._threads if t.is_alive()]
        for sock in (self._udp, self._udp_out, self._tcp):
            if sock is not None:
                sock.close()
        if self._http is not None:
            self._http.server_close()
        if self._errors:
            raise RuntimeError(f"FakeNetFT thread failed: {self._errors[0]!r}") from self._errors[0]
        if alive:
            raise RuntimeError(f"FakeNetFT threads did not stop within {CLOSE_JOIN_TIMEOUT_S} s: {alive}")

    def __enter__(self) -> "FakeNetFT":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def url(self) -> str:
        """The ``netft://`` URL of this fake for :class:`drivers.netft.NetFTSensor`."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"netft://{host}:{self.rdt_port}?tcp_port={self.tcp_port}&http_port={self.http_port}"

    # ------------------------------------------------------------------ settings

    @property
    def rate_hz(self) -> float:
        """The streaming rate in Hz (``comrdtrate`` after quantisation)."""
        return self._settings["comrdtrate"]

    @property
    def buffer_size(self) -> int:
        """``comrdtbsiz``: records per datagram in buffered mode (0x0003)."""
        return self._settings["comrdtbsiz"]

    def set_rate(self, rate_hz: float) -> float:
        """Set ``comrdtrate`` as the CGI page does (quantised); return the rate in force."""
        rate, divisor = quantise_rate_hz(rate_hz, self.max_rate_hz)
        with self._lock:
            self._settings["comrdtrate"] = rate
            self._ft_step = divisor
            self._stream_t0, self._stream_done = time.monotonic(), 0
        return rate

    def set_buffer_size(self, records: int) -> int:
        """Set ``comrdtbsiz`` (clamped to 1-40); return the value in force."""
        with self._lock:
            self._settings["comrdtbsiz"] = int(min(max(int(records), MIN_BUFFER_SIZE), MAX_BUFFER_SIZE))
            return self._settings["comrdtbsiz"]

    @property
    def bias_counts(self) -> np.ndarray:
        """(6,) the device bias in counts (set by RDT 0x0042 or READFT sysCommands bit 0)."""
        with self._lock:
            return self._bias_counts.copy()

    def status_word(self) -> int:
        """The status the next record carries (latch, knob bits and the summary bit)."""
        with self._lock:
            return self._status_now()

    def _status_now(self) -> int:
        status = self._status_bits if (self._status_remaining is None or self._status_remaining > 0) else 0
        if self._latched:
            status |= STATUS_LATCH
        if status & ~STATUS_SUMMARY & UINT32_MASK:
            status |= STATUS_SUMMARY
        return status & UINT32_MASK

    # ------------------------------------------------------------------ fault knobs

    def drop(self, records: int) -> None:
        """Produce the next ``records`` records (sequence numbers advance) but do not send them."""
        with self._lock:
            self._drop_remaining += int(records)

    def duplicate(self, times: int = 1) -> None:
        """Send each of the next ``times`` records twice."""
        with self._lock:
            self._pending_faults.extend([("duplicate",)] * int(times))

    def reorder(self) -> None:
        """Swap the next two records (the second goes out first)."""
        with self._lock:
            self._pending_faults.append(("reorder",))

    def send_truncated(self, length: int = 35) -> None:
        """Send one extra datagram: the next record cut to ``length`` bytes (or padded, if > 36). It takes no
        sequence number: the record itself still goes out whole."""
        with self._lock:
            self._pending_faults.append(("truncated", int(length)))

    def send_garbage(self, datagrams: int = 1) -> None:
        """Send ``datagrams`` extra datagrams of random bytes whose length is not a multiple of 36."""
        with self._lock:
            for _ in range(int(datagrams)):
                length = int(self._rng.integers(1, 200))
                if length % RECORD_SIZE == 0:
                    length += 1
                self._pending_faults.append(("garbage", self._rng.integers(0, 256, length, dtype=np.uint8).tobytes()))

    def go_silent(self) -> None:
        """Stop sending (commands are still received and recorded; the stream pauses, sequences do not advance)."""
        with self._lock:
            self._silent = True

    def resume(self) -> None:
        """Send again after :meth:`go_silent` (the schedule restarts now: no burst of the silent time)."""
        with self._lock:
            self._silent = False
            self._stream_t0, self._stream_done = time.monotonic(), 0
            self._lock.notify_all()

    def restart(self) -> None:
        """Simulate a power cycle while streaming: rdt_sequence restarts at 1 and ft_sequence at 0."""
        with self._lock:
            self._restart_requested = True

    def stall_ft_sequence(self, records: int) -> None:
        """The next ``records`` records repeat the previous ``ft_sequence`` (rdt_sequence still advances)."""
        with self._lock:
            self._stall_remaining += int(records)

    def set_status(self, bits: int, records: int | None = None) -> None:
        """OR ``bits`` into the status of the next ``records`` records (None: until :meth:`clear_status`).
        Bit 31 (summary) is added whenever another bit is set."""
        with self._lock:
            self._status_bits = int(bits) & UINT32_MASK
            self._status_remaining = None if records is None else int(records)

    def clear_status(self) -> None:
        """Clear the knob status bits (not the latch)."""
        self.set_status(0)

    def saturate(self, records: int | None = None) -> None:
        """Flag transducer saturation (0x80020000) on the next ``records`` records (None: until cleared)."""
        self.set_status(STATUS_SATURATION, records)

    def set_axia_status(self, bits: int, records: int | None = None) -> None:
        """Status bits of the Ethernet Axia map (e.g. 0x8 busy, 1 << 30 saturated); same as :meth:`set_status`."""
        self.set_status(bits, records)

    def latch(self) -> None:
        """Latch the monitor condition (bit 16, informational) until RDT 0x0041 or READFT sysCommands bit 1."""
        with self._lock:
            self._latched = True

    # ------------------------------------------------------------------ observation

    def wait_for_command(self, code: int | str | None = None, *, source: str = "udp", count: int = 1,
                         timeout_s: float = DEFAULT_WAIT_S, since: int = 0) -> list[ReceivedCommand]:
        """Wait until ``count`` commands matching (``source``, ``code``; None = any) were received after index
        ``since`` of :attr:`commands`; return them. Raises TimeoutError (with what was received) at the deadline."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while True:
                matches = [c for c in self.commands[since:] if c.source == source and (code is None or c.code == code)]
                if len(matches) >= count:
                    return matches
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    seen = [(c.source, c.code) for c in self.commands[since:]]
                    raise TimeoutError(f"FakeNetFT: {count} × {source} {code!r} not received within {timeout_s} s; "
                                       f"received {seen}")
                self._lock.wait(remaining)

    @property
    def faults_pending(self) -> bool:
        """Whether injected faults are still waiting for records to apply to."""
        with self._lock:
            return bool(self._pending_faults or self._drop_remaining or self._held or self._stall_remaining
                        or self._restart_requested or (self._status_remaining or 0) > 0)

    def wait_until(self, predicate, timeout_s: float = DEFAULT_WAIT_S, what: str = "condition") -> None:
        """Wait until ``predicate(self)`` is true (checked whenever the fake sends or receives). Raises TimeoutError."""
        deadline = time.monotonic() + timeout_s
        while not predicate(self):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(f"FakeNetFT: {what} not reached within {timeout_s} s ({self.stats()})")
            with self._lock:
                self._lock.wait(min(remaining, POLL_S))

    def wait_for_records(self, records: int, timeout_s: float = DEFAULT_WAIT_S) -> int:
        """Wait until ``records_sent`` ≥ ``records``; return it. Raises TimeoutError at the deadline."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while self.records_sent < records:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError(f"FakeNetFT: {self.records_sent} records sent, not {records}, in {timeout_s} s")
                self._lock.wait(remaining)
            return self.records_sent

    def stats(self) -> dict:
        """Counters as a JSON-friendly dict."""
        with self._lock:
            return {"records_produced": self.records_produced, "records_sent": self.records_sent,
                    "datagrams_sent": self.datagrams_sent, "records_dropped": self.records_dropped,
                    "send_errors": self.send_errors, "skipped_backlog": self.skipped_backlog,
                    "streams_started": self.streams_started, "rate_hz": self.rate_hz,
                    "buffer_size": self.buffer_size, "streaming": self._target is not None,
                    "rdt_sequence": self._rdt_sequence, "ft_sequence": self._ft_sequence,
                    "commands": len(self.commands), "stream_t0_s": self._stream_t0}

    def _record(self, command: ReceivedCommand) -> None:
        with self._lock:
            self.commands.append(command)
            self._lock.notify_all()

    # ------------------------------------------------------------------ RDT

    def _rdt_loop(self) -> None:
        buffer = bytearray(2048)
        while not self._stop.is_set():
            timeout = self._next_send_in_s()
            readable, _, _ = select.select([self._udp], [], [], min(timeout, POLL_S))
            if readable:
                self._drain_commands(buffer)
            self._send_due()

    def _next_send_in_s(self) -> float:
        with self._lock:
            if self._target is None or self._silent:
                return POLL_S
            rate = self._settings["comrdtrate"]
            records_per_datagram = self._settings["comrdtbsiz"] if self._mode == RDT_START_BUFFERED else 1
            due_at = self._stream_t0 + (self._stream_done + records_per_datagram) / rate
        return max(0.0, due_at - time.monotonic())

    def _drain_commands(self, buffer: bytearray) -> None:
        while True:
            try:
                size, address = self._udp.recvfrom_into(buffer)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # e.g. ICMP port unreachable from a client that went away
                continue
            self._handle_command(bytes(buffer[:size]), address)

    def _handle_command(self, data: bytes, address: tuple) -> None:
        now = time.monotonic()
        if len(data) not in (8, 14):
            self._record(ReceivedCommand("udp", -1, 0, address, now, data))
            return
        header, command, count = struct.unpack(">HHI", data[:8])
        if header != RDT_HEADER:
            self._record(ReceivedCommand("udp", -1, 0, address, now, data))
            return
        target = address
        if command & RDT_EXTENDED_FLAG:
            if len(data) != 14:
                self._record(ReceivedCommand("udp", -1, 0, address, now, data))
                return
            ip, port = struct.unpack(">4sH", data[8:14])
            target = (socket.inet_ntoa(ip), port)
            command &= ~RDT_EXTENDED_FLAG
        elif len(data) != 8:
            self._record(ReceivedCommand("udp", -1, 0, address, now, data))
            return
        with self._lock:
            if command == RDT_STOP:
                self._target = None
            elif command in (RDT_START_SINGLE_BLOCK, RDT_START, RDT_START_BUFFERED, RDT_START_MULTI_UNIT):
                self._target = target
                self._mode = command
                self._remaining = count if count > 0 else None
                self._rdt_sequence = 0
                self._stream_t0, self._stream_done = now, 0
                self._held.clear()
                self.streams_started += 1
            elif command == RDT_BIAS:
                self._bias_now()
            elif command == RDT_RESET_LATCH:
                self._latched = False
            self.commands.append(ReceivedCommand("udp", command, count, address, now, data))
            self._lock.notify_all()
        if command in (RDT_START_SINGLE_BLOCK, RDT_START, RDT_START_BUFFERED, RDT_START_MULTI_UNIT):
            self._send_due(first=True)

    def _bias_now(self) -> None:
        """Take the current raw counts as the bias (lock held)."""
        self._bias_counts = self._raw_counts(self._draw(1))[0]

    def _draw(self, n: int, due_s: float | None = None) -> np.ndarray:
        """Return n physics samples (n, 6) in SI, drawing chunks so the pose is read once per chunk (lock held).
        ``due_s``: when the first of them is due in the stream (the physics evaluates a moving arm at each
        record's own time, however late this thread gets to it)."""
        if self._sample_buffer.shape[0] < n:
            chunk = max(n, int(self._settings["comrdtrate"] * SAMPLE_CHUNK_S), 1)
            start = None if due_s is None else due_s + self._sample_buffer.shape[0] / self._settings["comrdtrate"]
            self._sample_buffer = np.concatenate([self._sample_buffer, self._physics_sample(chunk, start)])
        out, self._sample_buffer = self._sample_buffer[:n], self._sample_buffer[n:]
        return out

    def _physics_sample(self, n: int, start_s: float | None) -> np.ndarray:
        if start_s is None:
            return self.physics.sample(n)
        try:
            return self.physics.sample(n, start_time_s=start_s)
        except TypeError:  # a physics without sample times (tests' stand-ins)
            return self.physics.sample(n)

    def _raw_counts(self, wrench_si: np.ndarray) -> np.ndarray:
        return np.clip(np.rint(wrench_si * self._si_to_counts), INT32_MIN, INT32_MAX).astype(np.int64)

    def _send_due(self, first: bool = False) -> None:
        with self._lock:
            if self._target is None or self._silent:
                return
            now = time.monotonic()
            buffered = self._mode == RDT_START_BUFFERED
            per_datagram = self._settings["comrdtbsiz"] if buffered else 1
            rate = self._settings["comrdtrate"]
            due = int((now - self._stream_t0) * rate) - self._stream_done
            if first:
                due = max(due, 1)
            if buffered:
                due = (due // per_datagram) * per_datagram
            if due <= 0:
                return
            if due > MAX_BURST_RECORDS:  # descheduled: skip the backlog instead of flooding
                self.skipped_backlog += due - per_datagram
                self._stream_done += due - per_datagram
                due = per_datagram
            if self._remaining is not None:
                due = min(due, self._remaining)
            records = self._produce(due)
            self._stream_done += due
            if self._remaining is not None:
                self._remaining -= due
            target = self._target
            if self._remaining == 0:
                self._target = None
            faults = bool(self._pending_faults or self._drop_remaining or self._held)
            datagrams = self._datagrams(records, per_datagram, faults)
            # counted before sending, so a client that saw the last record also sees the count
            self.records_sent += sum(len(d) // RECORD_SIZE for d in datagrams if len(d) % RECORD_SIZE == 0)
            self.datagrams_sent += len(datagrams)
            self._lock.notify_all()
        failed_records = failed_datagrams = 0
        sender = self._udp_out or self._udp
        for datagram in datagrams:
            try:
                sender.sendto(datagram, target)
            except OSError:
                failed_datagrams += 1
                failed_records += len(datagram) // RECORD_SIZE if len(datagram) % RECORD_SIZE == 0 else 0
        if failed_datagrams:
            with self._lock:
                self.records_sent -= failed_records
                self.datagrams_sent -= failed_datagrams
                self.send_errors += failed_datagrams

    def _produce(self, n: int) -> np.ndarray:
        """Return n records (structured array) and advance the sequences (lock held)."""
        records = np.zeros(n, dtype=RECORD_DTYPE)
        if self._restart_requested:
            self._restart_requested = False
            self._rdt_sequence, self._ft_sequence = 0, 0
        rdt = (self._rdt_sequence + 1 + np.arange(n, dtype=np.int64)) & UINT32_MASK
        steps = np.full(n, self._ft_step, dtype=np.int64)
        if self._stall_remaining:
            stalled = min(self._stall_remaining, n)
            steps[:stalled] = 0
            self._stall_remaining -= stalled
        ft = (self._ft_sequence + np.cumsum(steps)) & UINT32_MASK
        self._rdt_sequence, self._ft_sequence = int(rdt[-1]), int(ft[-1])
        due_s = self._stream_t0 + self._stream_done / self._settings["comrdtrate"] if self._target is not None else None
        counts = self._raw_counts(self._draw(n, due_s)) - self._bias_counts
        self._last_counts = counts[-1] + self._bias_counts
        if self._settings["setmce"] and not self._latched and self._monitor_breached(counts):
            self._latched = True  # the status of these records already went out without the latch: next ones
        status = np.full(n, self._status_now(), dtype=np.int64)
        if self._status_remaining is not None and self._status_remaining > 0:
            flagged = min(self._status_remaining, n)
            self._status_remaining -= flagged
            status[flagged:] = self._status_now()  # the knob bits end after `flagged` records
        records["rdt_sequence"], records["ft_sequence"], records["status"] = rdt, ft, status
        records["counts"] = np.clip(counts, INT32_MIN, INT32_MAX)
        self.records_produced += n
        return records

    def _monitor_breached(self, counts: np.ndarray) -> bool:
        """Whether any enabled monitor condition (moncon.cgi mce/mcx/mcc/mcv, counts) is breached (lock held)."""
        monitor = self._settings["monitor"]
        for index in range(16):
            try:
                if not int(float(monitor.get(f"mce{index}", 0))):
                    continue
                axis, comparison = int(float(monitor[f"mcx{index}"])), int(float(monitor[f"mcc{index}"]))
                value = float(monitor[f"mcv{index}"])
            except (KeyError, ValueError):
                continue
            if not 0 <= axis < 6:
                continue
            column = counts[:, axis]
            if (comparison > 0 and np.any(column > value)) or (comparison < 0 and np.any(column < value)):
                return True
        return False

    def _datagrams(self, records: np.ndarray, per_datagram: int, faults: bool) -> list[bytes]:
        """Split records into datagrams, applying pending faults (lock held)."""
        raw = records.tobytes()
        if not faults:
            return [raw[i:i + per_datagram * RECORD_SIZE] for i in range(0, len(raw), per_datagram * RECORD_SIZE)]
        out_records: list[bytes] = []
        extras: list[tuple[int, bytes]] = []  # (position in out_records, datagram) sent before that record
        for i in range(len(records)):
            record = raw[i * RECORD_SIZE:(i + 1) * RECORD_SIZE]
            if self._drop_remaining:
                self._drop_remaining -= 1
                self.records_dropped += 1
                continue
            while self._pending_faults and self._pending_faults[0][0] in ("truncated", "garbage"):
                kind, arg = self._pending_faults.popleft()
                if kind == "truncated":
                    extras.append((len(out_records), (record + b"\0" * max(0, arg - RECORD_SIZE))[:arg]))
                else:
                    extras.append((len(out_records), arg))
            if self._held:
                out_records.append(record)
                out_records.append(self._held.pop())
                continue
            if self._pending_faults:
                kind = self._pending_faults[0][0]
                if kind == "duplicate":
                    self._pending_faults.popleft()
                    out_records += [record, record]
                    continue
                if kind == "reorder":
                    self._pending_faults.popleft()
                    self._held.append(record)
                    continue
            out_records.append(record)
        datagrams: list[bytes] = []
        extra_iter = iter(extras)
        pending_extra = next(extra_iter, None)
        group: list[bytes] = []
        for index, record in enumerate(out_records):
            while pending_extra is not None and pending_extra[0] <= index:
                datagrams.append(pending_extra[1])
                pending_extra = next(extra_iter, None)
            group.append(record)
            if len(group) == per_datagram:
                datagrams.append(b"".join(group))
                group = []
        if group:
            datagrams.append(b"".join(group))
        while pending_extra is not None:
            datagrams.append(pending_extra[1])
            pending_extra = next(extra_iter, None)
        return datagrams

    # ------------------------------------------------------------------ TCP 49151

    def _tcp_loop(self) -> None:
        selector = selectors.DefaultSelector()
        selector.register(self._tcp, selectors.EVENT_READ, None)
        buffers: dict[socket.socket, bytearray] = {}
        try:
            while not self._stop.is_set():
                for key, _ in selector.select(POLL_S):
                    if key.data is None:
                        try:
                            connection, _ = self._tcp.accept()
                        except OSError:
                            continue
                        connection.setblocking(False)
                        buffers[connection] = bytearray()
                        selector.register(connection, selectors.EVENT_READ, "client")
                        continue
                    connection = key.fileobj
                    try:
                        chunk = connection.recv(4096)
                    except (BlockingIOError, InterruptedError):
                        continue
                    except OSError:
                        chunk = b""
                    if not chunk:
                        selector.unregister(connection)
                        connection.close()
                        buffers.pop(connection, None)
                        continue
                    pending = buffers[connection]
                    pending += chunk
                    while len(pending) >= TCP_COMMAND_SIZE:
                        command = bytes(pending[:TCP_COMMAND_SIZE])
                        del pending[:TCP_COMMAND_SIZE]
                        reply = self._tcp_reply(command, connection.getpeername())
                        if reply:
                            try:
                                connection.sendall(reply)
                            except OSError:
                                break
        finally:
            for connection in list(buffers):
                connection.close()
            selector.close()

    def _tcp_reply(self, command: bytes, address: tuple) -> bytes:
        code = command[0]
        self._record(ReceivedCommand("tcp", code, 0, address, time.monotonic(), command))
        if code == TCP_READFT:
            _, system_commands = struct.unpack(">HH", command[16:20])
            with self._lock:
                if system_commands & 0x1:
                    self._bias_now()
                if system_commands & 0x2:
                    self._latched = False
                counts = self._raw_counts(self._draw(1))[0] - self._bias_counts
                status = self._status_now()
            values = [int(np.clip(round(c / s), -INT16_MAX - 1, INT16_MAX)) for c, s in zip(counts, self.scale_factors)]
            return struct.pack(">HH6h", RDT_HEADER, status >> 16, *values)
        if code == TCP_READCALINFO:
            answer = self.calinfo_override or (FORCE_UNIT_CODES[self.force_unit], TORQUE_UNIT_CODES[self.torque_unit],
                                               self.counts_per_force, self.counts_per_torque)
            return struct.pack(">HBBII6H", RDT_HEADER, *answer, *self.scale_factors)
        if code in (TCP_WRITETRANSFORM, TCP_WRITETHRESHOLD):
            return struct.pack(">HBB", RDT_HEADER, code, 0)
        return b""  # no reply layout is documented for unknown commands

    # ------------------------------------------------------------------ HTTP

    def netftapi2_xml(self) -> str:
        """The body of ``/netftapi2.xml`` (flat, one element each, text only)."""
        with self._lock:
            s = dict(self._settings)
            status = self._status_now()
            bias = ";".join(str(int(v)) for v in self._bias_counts)
        elements = []
        if self.prodname is not None:
            elements.append(("prodname", self.prodname))
        elements += [
            ("runstat", f"0x{status:08X}"), ("runrate", f"{INTERNAL_RATE_HZ:g}"),
            ("cfgnam", s["cfgnam"]), ("cfgcalsel", s["cfgcalsel"]), ("cfgcalsn", self.serial),
            ("scfgfu", self.force_unit), ("scfgtu", self.torque_unit),
            ("cfgfu", FORCE_UNIT_CODES[self.force_unit]), ("cfgtu", TORQUE_UNIT_CODES[self.torque_unit]),
            ("cfgcpf", self.counts_per_force), ("cfgcpt", self.counts_per_torque),
            ("cfgmr", ";".join(f"{v:g}" for v in self.max_rating)),
            ("setcfgsel", s["setcfgsel"]), ("setpke", s["setpke"]), ("setmce", s["setmce"]), ("setbias", bias),
            ("setuserfilter", s["setuserfilter"]),
            ("comrdte", "Enabled" if s["comrdte"] else "Disabled"),
            ("comrdtrate", f"{s['comrdtrate']:.6g}"), ("comrdtbsiz", s["comrdtbsiz"]),
            ("mfgdigver", self.firmware),
        ]
        body = "".join(f"<{k}>{_xml_text(v)}</{k}>" for k, v in elements)
        return f'<?xml version="1.0" encoding="utf-8"?>\n<netft>{body}</netft>\n'

    def netftcalapi_xml(self) -> str:
        """The body of ``/netftcalapi.xml``."""
        elements = [("calsn", self.serial), ("calcpf", self.counts_per_force), ("calcpt", self.counts_per_torque),
                    ("scalfu", self.force_unit), ("scaltu", self.torque_unit)]
        body = "".join(f"<{k}>{_xml_text(v)}</{k}>" for k, v in elements)
        return f'<?xml version="1.0" encoding="utf-8"?>\n<netftCalibration>{body}</netftCalibration>\n'

    def apply_cgi(self, page: str, params: dict[str, str]) -> None:
        """Apply a CGI settings request (values the box clamps or quantises are stored as the box would)."""
        for key, value in params.items():
            try:
                if key == "comrdtrate":
                    self.set_rate(float(value))
                elif key == "comrdtbsiz":
                    self.set_buffer_size(int(float(value)))
                elif key in ("comrdte", "setuserfilter", "setpke", "setcfgsel", "setmce", "cfgcalsel"):
                    with self._lock:
                        self._settings[key] = int(float(value))
                elif key.startswith("setbias") and key[7:].isdigit():
                    with self._lock:
                        self._bias_counts[int(key[7:]) % 6] = int(float(value))
                elif key == "cfgfu":
                    self.set_units(force_unit={v: k for k, v in FORCE_UNIT_CODES.items()}[int(float(value))])
                elif key == "cfgtu":
                    names = {1: "lbf-in", 2: "lbf-ft", 3: "Nm", 4: "N-mm", 5: "kgf-cm", 6: "kN-m"}
                    self.set_units(torque_unit=names[int(float(value))])
                elif key == "cfgnam":
                    with self._lock:
                        self._settings["cfgnam"] = value
                else:
                    with self._lock:
                        self._settings["monitor"][key] = value
            except (ValueError, KeyError):
                continue  # the box ignores what it cannot parse


def _xml_text(value) -> str:
    return str(value).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _make_http_server(fake: FakeNetFT, address: tuple, family: int) -> HTTPServer:
    class Handler(BaseHTTPRequestHandler):
        server_version = "FakeNetFT/1.0"

        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            parts = urlsplit(self.path)
            params = dict(parse_qsl(parts.query, keep_blank_values=True))
            fake._record(ReceivedCommand("http", parts.path, 0, self.client_address, time.monotonic(),
                                         self.path.encode(), params))
            if parts.path == "/netftapi2.xml":
                self._reply(200, fake.netftapi2_xml(), "text/xml")
            elif parts.path == "/netftcalapi.xml" and fake.serve_calibration_page:
                self._reply(200, fake.netftcalapi_xml(), "text/xml")
            elif parts.path in ("/comm.cgi", "/setting.cgi", "/config.cgi", "/moncon.cgi"):
                fake.apply_cgi(parts.path, params)
                self._reply(200, "<html><body>OK</body></html>", "text/html")
            else:
                self._reply(404, "not found", "text/plain")

        def _reply(self, code: int, body: str, content_type: str) -> None:
            data = body.encode()
            self.send_response(code)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(data)))
            self.send_header("Connection", "close")
            self.end_headers()
            self.wfile.write(data)

        def log_message(self, format: str, *args) -> None:  # noqa: A002 (http.server's signature)
            pass

    class Server(HTTPServer):
        address_family = family
        allow_reuse_address = True

    return Server(address, Handler)


# ------------------------------------------------------------------------ running alone

def _watch_stdin() -> bool:
    """Whether stdin is a pipe or terminal that can tell us to stop (not /dev/null or closed)."""
    try:
        mode = os.fstat(0).st_mode
    except OSError:
        return False
    return stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode) or os.isatty(0) or stat.S_ISREG(mode)


def main(argv: list[str] | None = None) -> int:
    """Run one fake Net F/T until stdin closes (or SIGTERM / SIGINT); print its ports as one JSON line."""
    parser = argparse.ArgumentParser(description="A fake ATI Net F/T (RDT UDP, TCP, HTTP) on loopback.")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--rdt-port", type=int, default=0)
    parser.add_argument("--tcp-port", type=int, default=0)
    parser.add_argument("--http-port", type=int, default=0)
    parser.add_argument("--rate-hz", type=float, default=INTERNAL_RATE_HZ, help="comrdtrate, Hz (default %(default)s)")
    parser.add_argument("--max-rate-hz", type=float, default=INTERNAL_RATE_HZ,
                        help="allow rates above 7000 Hz (benchmarks only; a real box cannot)")
    parser.add_argument("--buffer-size", type=int, default=1, help="comrdtbsiz, records per buffered datagram")
    parser.add_argument("--force-unit", default="N")
    parser.add_argument("--torque-unit", default="Nm")
    parser.add_argument("--counts-per-force", type=int, default=1_000_000)
    parser.add_argument("--counts-per-torque", type=int, default=500_000)
    parser.add_argument("--serial", default="FT12345")
    parser.add_argument("--pose-shm", help="read the flange pose from this tests.fakes.world.SharedPose")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    from tests.fakes.world import CellTruth, SensorPhysics, SettablePose, SharedPose

    shared = SharedPose(args.pose_shm) if args.pose_shm else None
    if shared is not None:
        # The block belongs to the process that created it: keep this process's resource tracker (Python < 3.13,
        # bpo-39959) from unlinking it when this process exits.
        from multiprocessing import resource_tracker

        try:
            resource_tracker.unregister("/" + shared.name.lstrip("/"), "shared_memory")
        except Exception:  # noqa: BLE001 (best effort; only matters for the owner's clean-up)
            pass
    physics = SensorPhysics(CellTruth(), shared if shared is not None else SettablePose(), seed=args.seed)
    fake = FakeNetFT(physics, host=args.host, rdt_port=args.rdt_port, tcp_port=args.tcp_port,
                     http_port=args.http_port, rate_hz=args.rate_hz, buffer_size=args.buffer_size,
                     force_unit=args.force_unit, torque_unit=args.torque_unit,
                     counts_per_force=args.counts_per_force, counts_per_torque=args.counts_per_torque,
                     serial=args.serial, max_rate_hz=args.max_rate_hz, seed=args.seed)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    fake.start()
    try:
        print(json.dumps({"host": args.host, "rdt_port": fake.rdt_port, "tcp_port": fake.tcp_port,
                          "http_port": fake.http_port, "url": fake.url, "pid": os.getpid()}), flush=True)
        if _watch_stdin():
            while not stop.is_set():
                ready, _, _ = select.select([sys.stdin], [], [], POLL_S)
                if not ready:
                    continue
                line = sys.stdin.readline()
                if not line:
                    break
                if line.strip() == "stats":
                    print(json.dumps(fake.stats()), flush=True)
                elif line.startswith("rate "):
                    print(json.dumps({"rate_hz": fake.set_rate(float(line.split()[1]))}), flush=True)
                elif line.startswith("buffer "):
                    print(json.dumps({"buffer_size": fake.set_buffer_size(int(line.split()[1]))}), flush=True)
        else:
            while not stop.wait(POLL_S):
                pass
    finally:
        fake.close()
        if shared is not None:
            shared.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
