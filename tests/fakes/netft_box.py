"""The simulated Net F/T's state: settings, units, the RDT stream, fault knobs and what it sent. No sockets here.

:class:`NetFTBox` is what the box *is*; tests/fakes/netft.py puts it behind real sockets (RDT/UDP, TCP, HTTP) and
tests/fakes/netft_protocol.py holds the wire format. All public methods take ``self._lock``. Over 600 lines
because the settings, the stream's schedule, the sample physics and the fault knobs share that one lock's state.

Stream (docs/protocols-ati.md, "RDT sequences"): every start command restarts ``rdt_sequence`` at 1 and the
schedule; ``ft_sequence`` is the power-up sample counter, never reset by a start.

The box's own clock (docs/simulation.md, "Simulated clocks"): the box samples at 7000 Hz on its own crystal, which
runs ``clock_rate_error`` (e.g. +150e-6) fast against the host's ``time.monotonic()``; a stream at 7000/n Hz sends
its internal samples k0, k0 + n, k0 + 2n, ... and ``ft_sequence`` is that internal sample number (counted from
power-up), so ``ft_sequence`` / 7000 is the box's time of the sample. Records leave in bursts: every
``burst_interval_s`` (× a random factor 0.5-1.5) the box sends what was due up to a random delay in
[0, ``burst_jitter_s``] before, several records at once, as a real box's network stack does. When the sender falls
behind by more than ``max_backlog_s`` (a descheduled process on a loaded host) the oldest due records are skipped:
``rdt_sequence`` still counts the records sent one by one, ``ft_sequence`` jumps over the skipped samples.

Faults as a real link and box show them: :meth:`go_silent` is a link that goes quiet from the box to the host —
the box streams on (sequences advance, :attr:`records_silenced` counts what the link swallowed) and still hears
commands, so a start re-sent meanwhile restarts its ``rdt_sequence``; :meth:`power_off` / :meth:`power_on` is a
power cycle (nothing sent or heard while off; on power-up both sequences start again and the box waits for a
start); :meth:`restart` resets both sequences mid-stream. Everything put on the wire is logged
(:meth:`sent_records`) so a test can check that every record sent reached the client exactly once.

Why one class of ~800 lines: the settings (HTTP), the calibration answers (TCP), the stream and the fault knobs
all read and write one state under one lock (a CGI rate change moves the stream's schedule, a TCP bias changes
the next records, a start resets the sequence the knobs act on); splitting them would only pass that state around.
"""

from __future__ import annotations

import collections
import math
import struct
import threading
import time

import numpy as np

from tests.fakes.netft_protocol import (
    FORCE_UNIT_CODES,
    INT16_MAX,
    INT32_MAX,
    INT32_MIN,
    INTERNAL_RATE_HZ,
    MAX_BUFFER_SIZE,
    MIN_BUFFER_SIZE,
    NEWTON_METRES_PER_TORQUE_UNIT,
    NEWTONS_PER_FORCE_UNIT,
    RDT_BIAS,
    RDT_HEADER,
    RDT_RESET_LATCH,
    RDT_START,
    RDT_START_BUFFERED,
    RDT_STARTS,
    RDT_STOP,
    RECORD_DTYPE,
    RECORD_SIZE,
    STATUS_LATCH,
    STATUS_SATURATION,
    STATUS_SUMMARY,
    TCP_READCALINFO,
    TCP_READFT,
    TCP_WRITETHRESHOLD,
    TCP_WRITETRANSFORM,
    TORQUE_UNIT_CODES,
    UINT32_MASK,
    ReceivedCommand,
    parse_rdt_command,
    quantise_rate_hz,
    xml_text,
)

POLL_S = 0.05
"""Longest a wait on the box blocks before re-checking, seconds."""
MAX_BURST_RECORDS = 4096
"""Most records sent in one go by default; a longer backlog (the fake was descheduled) is skipped, not flooded."""
BURST_INTERVAL_SPREAD = (0.5, 1.5)
"""A burst follows the previous one after ``burst_interval_s`` × a factor drawn uniformly in this range."""
SAMPLE_CHUNK_S = 0.004
"""Physics samples are drawn in chunks covering this much stream time (the pose is read once per chunk)."""
DEFAULT_WAIT_S = 5.0
SENT_LOG_LIMIT = 2_000_000
"""Records :meth:`NetFTBox.sent_records` keeps (72 MB); later ones are counted, not logged."""


class NetFTBox:
    """The simulated box's state (see the module docstring); :class:`tests.fakes.netft.FakeNetFT` serves it.

    Args:
        physics: a :class:`tests.fakes.world.SensorPhysics` (``sample(n)`` → (n, 6) N and N·m).
        rate_hz: initial ``comrdtrate`` (quantised as the box does). buffer_size: initial ``comrdtbsiz`` (1-40).
        force_unit, torque_unit: unit strings the box reports ("N", "Nm", "N-mm", "lbf", ...).
        counts_per_force, counts_per_torque: counts per force / torque unit (different on purpose).
        serial: calibration serial number. prodname: product name, or None to omit it (legacy firmware).
        serve_calibration_page: False makes ``/netftcalapi.xml`` answer 404 (older firmware).
        max_rate_hz: highest streaming rate; above 7000 only for benchmarks (not what a real box does).
        max_rating: (6,) max rating per axis in device units (``cfgmr``; sets the READFT scale factors).
        seed: seed of the garbage-datagram generator.
        sent_log_limit: records kept in :meth:`sent_records` (what went on the wire); later ones are not logged.
        clock_rate_error: the box's sample clock rate against the host's, minus one (+150e-6: the box's crystal
            runs 150 ppm fast, 7000 × (1 + 150e-6) samples per host second). 0: the host's rate exactly.
        burst_interval_s: mean time between the box's bursts of datagrams, s (0: each record leaves when due).
        burst_jitter_s: a burst carries the records due up to a random delay in [0, this] before it, s.
        max_backlog_s: records due longer ago than this are skipped (``ft_sequence`` jumps, ``rdt_sequence`` does
            not), s; None: only a backlog of more than MAX_BURST_RECORDS records is (all but one datagram).
    """

    def __init__(self, physics, rate_hz: float = INTERNAL_RATE_HZ, buffer_size: int = 1, force_unit: str = "N",
                 torque_unit: str = "Nm", counts_per_force: int = 1_000_000, counts_per_torque: int = 500_000,
                 serial: str = "FT12345", prodname: str | None = "Net F/T (simulated)",
                 serve_calibration_page: bool = True, max_rate_hz: float = INTERNAL_RATE_HZ,
                 max_rating: tuple | None = None, firmware: str = "2.2.59", seed: int = 0,
                 sent_log_limit: int = SENT_LOG_LIMIT, clock_rate_error: float = 0.0, burst_interval_s: float = 0.0,
                 burst_jitter_s: float = 0.0, max_backlog_s: float | None = None) -> None:
        if force_unit not in FORCE_UNIT_CODES:
            raise ValueError(f"force_unit {force_unit!r}: must be one of {sorted(FORCE_UNIT_CODES)}")
        if torque_unit not in TORQUE_UNIT_CODES:
            raise ValueError(f"torque_unit {torque_unit!r}: must be one of {sorted(TORQUE_UNIT_CODES)}")
        self.physics = physics
        self.force_unit, self.torque_unit = force_unit, torque_unit
        self.counts_per_force, self.counts_per_torque = int(counts_per_force), int(counts_per_torque)
        self.serial, self.prodname, self.firmware = serial, prodname, firmware
        self.serve_calibration_page = serve_calibration_page
        self.max_rate_hz = float(max_rate_hz)
        if max_rating is None:
            max_rating = (660.0 / NEWTONS_PER_FORCE_UNIT[force_unit],) * 2 + (1980.0 / NEWTONS_PER_FORCE_UNIT[force_unit],) \
                + (60.0 / NEWTON_METRES_PER_TORQUE_UNIT[torque_unit],) * 3
        self.max_rating = tuple(float(v) for v in max_rating)
        self._rng = np.random.default_rng(seed)
        self._timing_rng = np.random.default_rng([seed, 1])
        self._update_scaling()
        if not -0.01 < clock_rate_error < 0.01:
            raise ValueError(f"clock_rate_error {clock_rate_error!r}: a crystal is off by ppm, not percent")
        if burst_interval_s < 0.0 or burst_jitter_s < 0.0 or (max_backlog_s is not None and max_backlog_s <= 0.0):
            raise ValueError("burst_interval_s and burst_jitter_s must be >= 0, max_backlog_s > 0 (or None)")
        self.clock_rate_error = float(clock_rate_error)
        self.burst_interval_s, self.burst_jitter_s = float(burst_interval_s), float(burst_jitter_s)
        self.max_backlog_s = max_backlog_s
        self._clock_t0 = time.monotonic()  # host time of power-up: the box's internal sample 0
        self._last_index = 0  # internal sample number of the last record produced (ft_sequence's clock)
        self._next_burst_s = 0.0
        self._paused_until_s = 0.0

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
        self._stream_k0 = 0
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
        self.records_silenced = 0
        self.sent_log_limit = int(sent_log_limit)
        self._sent_log: list[np.ndarray] = []
        self._sent_logged = 0
        self._powered = True

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
            self._tick_hz = rate * divisor  # the internal rate (7000 Hz; higher only with max_rate_hz)
            self._restart_schedule(time.monotonic())
        return rate

    def _ticks_per_host_s(self) -> float:
        """The box's internal samples per host second: the internal rate on the box's own crystal."""
        return self._tick_hz * (1.0 + self.clock_rate_error)

    def _restart_schedule(self, now: float) -> None:
        """A stream's schedule starts at the box's next internal sample (a multiple of n at 7000/n Hz) after host time
        ``now`` (lock held)."""
        self._stream_t0, self._stream_done = now, 0
        # every n-th internal sample (7000/n Hz), from the next one after the start
        self._stream_k0 = math.ceil((now - self._clock_t0) * self._ticks_per_host_s() / self._ft_step) * self._ft_step
        self._sample_buffer = np.empty((0, 6))
        self._next_burst_s = now

    def _due_s(self, record: int) -> float:
        """Host time at which record ``record`` (0 = the stream's first) of the stream is sampled (lock held)."""
        return self._clock_t0 + (self._stream_k0 + record * self._ft_step) / self._ticks_per_host_s()

    def _due_count(self, until_s: float) -> int:
        """Records of the stream sampled by host time ``until_s`` (lock held)."""
        ticks = (until_s - self._clock_t0) * self._ticks_per_host_s() - self._stream_k0
        return int(math.floor(ticks / self._ft_step)) + 1 if ticks >= 0.0 else 0

    def device_time_s(self, host_s: float) -> float:
        """The box's clock at host time ``host_s`` (``time.monotonic``): its internal sample number / 7000, s."""
        with self._lock:
            return (host_s - self._clock_t0) * self._ticks_per_host_s() / self._tick_hz

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
        """The link from the box to the host goes quiet: the box streams on (sequences advance; the records are
        counted in :attr:`records_silenced`, not sent) and still hears commands (a start restarts its sequence)."""
        with self._lock:
            self._silent = True

    def resume(self) -> None:
        """The link comes back after :meth:`go_silent`: the next records due reach the host again."""
        with self._lock:
            self._silent = False
            self._lock.notify_all()

    def power_off(self) -> None:
        """Switch the box off: it stops streaming and hears nothing until :meth:`power_on`."""
        with self._lock:
            self._powered = False
            self._target = None
            self._lock.notify_all()

    def power_on(self) -> float:
        """Switch the box on again: both sequences start from zero and it streams only after a start command.
        Return the host time (``time.monotonic``) it came back."""
        with self._lock:
            self._powered = True
            now = time.monotonic()
            self._rdt_sequence = self._ft_sequence = 0
            self._clock_t0, self._last_index = now, 0  # the box's clock starts again at sample 0
            self._bias_counts = np.zeros(6, dtype=np.int64)
            self._held.clear()
            self._lock.notify_all()
            return now

    def restart(self) -> None:
        """Simulate a power cycle while streaming: rdt_sequence restarts at 1 and ft_sequence at 0."""
        with self._lock:
            self._restart_requested = True

    def deschedule(self, seconds: float) -> None:
        """The sender sends nothing for ``seconds`` of host time from now, as when the fake's process is not
        scheduled on a loaded host; the box samples on (``max_backlog_s`` then decides what is skipped)."""
        with self._lock:
            self._paused_until_s = time.monotonic() + float(seconds)

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
                    "commands": len(self.commands), "stream_t0_s": self._stream_t0,
                    "clock_rate_error": self.clock_rate_error,
                    "records_silenced": self.records_silenced, "powered": self._powered}

    def _record(self, command: ReceivedCommand) -> None:
        with self._lock:
            self.commands.append(command)
            self._lock.notify_all()

    def sent_records(self) -> np.ndarray:
        """Every well-formed record put on the wire so far (RECORD_DTYPE, in sending order, copies included),
        up to ``sent_log_limit``."""
        with self._lock:
            if not self._sent_log:
                return np.empty(0, dtype=RECORD_DTYPE)
            return np.concatenate(self._sent_log)

    # ------------------------------------------------------------------ RDT stream

    def handle_rdt(self, data: bytes, address: tuple, now: float) -> bool:
        """Apply one RDT request received from ``address``; return True when it started a stream."""
        if not self._powered:
            return False  # switched off: hears nothing
        parsed = parse_rdt_command(data)
        if parsed is None:
            self._record(ReceivedCommand("udp", -1, 0, address, now, data))
            return False
        command, count, embedded = parsed
        with self._lock:
            if command == RDT_STOP:
                self._target = None
            elif command in RDT_STARTS:
                if self._target is not None and self._silent:
                    # the old stream's records due by now went into the quiet link too: the caller's flush
                    # (FakeNetFT) counted whole datagrams of them; a buffered stream's partial one is counted here
                    self.records_silenced += max(0, self._due_count(now) - self._stream_done)
                self._target = embedded or address
                self._mode = command
                self._remaining = count if count > 0 else None
                self._rdt_sequence = 0
                self._restart_schedule(now)
                self._held.clear()
                self.streams_started += 1
            elif command == RDT_BIAS:
                self._bias_now()
            elif command == RDT_RESET_LATCH:
                self._latched = False
            self.commands.append(ReceivedCommand("udp", command, count, address, now, data))
            self._lock.notify_all()
        return command in RDT_STARTS

    def next_send_in_s(self, now: float) -> float:
        """Seconds until the next datagram is due (POLL_S when not streaming)."""
        with self._lock:
            if self._target is None:
                return POLL_S
            if now < self._paused_until_s:
                return self._paused_until_s - now
            if self.burst_interval_s > 0.0:
                return max(0.0, self._next_burst_s - now)
            records_per_datagram = self._settings["comrdtbsiz"] if self._mode == RDT_START_BUFFERED else 1
            due_at = self._due_s(self._stream_done + records_per_datagram - 1)
        return max(0.0, due_at - now)

    def due_datagrams(self, now: float, first: bool = False,
                      flush: bool = False) -> tuple[list[bytes], tuple | None]:
        """Produce the records due by ``now`` and return (datagrams to send, target); nothing while the link is
        silent (the records are produced all the same) or the box is off. ``flush``: every record due by ``now``,
        whatever the burst schedule (before a command is applied: a real box has sent each record it sampled
        before it hears a start or a stop; this fake produces in bursts, so the tail due so far is sent first)."""
        with self._lock:
            if self._target is None:
                return [], None
            buffered = self._mode == RDT_START_BUFFERED
            per_datagram = self._settings["comrdtbsiz"] if buffered else 1
            if now < self._paused_until_s:
                return [], None
            until = now
            if self.burst_interval_s > 0.0 and not first and not flush:
                if now < self._next_burst_s:
                    return [], None
                until = now - self.burst_jitter_s * self._timing_rng.random()
                self._next_burst_s = now + self.burst_interval_s * self._timing_rng.uniform(*BURST_INTERVAL_SPREAD)
            due = self._due_count(until) - self._stream_done
            if first:
                due = max(due, 1)
            if buffered:
                due = (due // per_datagram) * per_datagram
            if due <= 0:
                return [], None
            if self.max_backlog_s is None:
                limit, keep = MAX_BURST_RECORDS, per_datagram
            else:
                keep = limit = max(per_datagram, int(self.max_backlog_s * self._settings["comrdtrate"])
                                   // per_datagram * per_datagram)
            if due > limit:  # descheduled: skip the oldest of the backlog instead of flooding
                self.skipped_backlog += due - keep
                self._stream_done += due - keep
                self._sample_buffer = np.empty((0, 6))  # samples drawn for the skipped records
                due = keep
            if self._remaining is not None:
                due = min(due, self._remaining)
            records = self._produce(due)
            self._stream_done += due
            if self._remaining is not None:
                self._remaining -= due
            target = self._target
            if self._remaining == 0:
                self._target = None
            if self._silent:
                self.records_silenced += due
                self._lock.notify_all()
                return [], None
            faults = bool(self._pending_faults or self._drop_remaining or self._held)
            datagrams = self._datagrams(records, per_datagram, faults)
            # counted before sending, so a client that saw the last record also sees the count
            if faults:
                well_formed = [d for d in datagrams if len(d) % RECORD_SIZE == 0 and d]
                sent = sum(len(d) // RECORD_SIZE for d in well_formed)
            else:  # every record once, in order, whole
                well_formed, sent = datagrams, len(records)
            self.records_sent += sent
            self.datagrams_sent += len(datagrams)
            if self._sent_logged < self.sent_log_limit and sent:
                logged = records if not faults else np.frombuffer(b"".join(well_formed), dtype=RECORD_DTYPE)
                self._sent_log.append(logged)
                self._sent_logged += len(logged)
            self._lock.notify_all()
        return datagrams, target

    def send_failed(self, datagrams: list[bytes]) -> None:
        """Take back the counts of datagrams that could not be sent."""
        records = sum(len(d) // RECORD_SIZE for d in datagrams if len(d) % RECORD_SIZE == 0)
        with self._lock:
            self.records_sent -= records
            self.datagrams_sent -= len(datagrams)
            self.send_errors += len(datagrams)

    def _bias_now(self) -> None:
        """Take the current raw counts as the bias (lock held)."""
        self._bias_counts = self._raw_counts(self._draw(1))[0]

    def _draw(self, n: int, due_s: float | None = None) -> np.ndarray:
        """Return n physics samples (n, 6) in SI, drawing chunks so the pose is read once per chunk (lock held).
        ``due_s``: when the first of them is due in the stream (the physics evaluates a moving arm at each
        record's own time, however late this thread gets to it)."""
        if self._sample_buffer.shape[0] < n:
            chunk = max(n, int(self._settings["comrdtrate"] * SAMPLE_CHUNK_S), 1)
            period_s = self._ft_step / self._ticks_per_host_s()
            start = None if due_s is None else due_s + self._sample_buffer.shape[0] * period_s
            self._sample_buffer = np.concatenate([self._sample_buffer, self._physics_sample(chunk, start, period_s)])
        out, self._sample_buffer = self._sample_buffer[:n], self._sample_buffer[n:]
        return out

    def _physics_sample(self, n: int, start_s: float | None, period_s: float) -> np.ndarray:
        if start_s is None:
            return self.physics.sample(n)
        try:
            return self.physics.sample(n, start_time_s=start_s, period_s=period_s)
        except TypeError:  # a physics without sample times or spacing (tests' stand-ins)
            try:
                return self.physics.sample(n, start_time_s=start_s)
            except TypeError:
                return self.physics.sample(n)

    def _raw_counts(self, wrench_si: np.ndarray) -> np.ndarray:
        # np.minimum/np.maximum: np.clip's own checks cost more than the clipping on a burst's few records
        return np.minimum(np.maximum(np.rint(wrench_si * self._si_to_counts), INT32_MIN), INT32_MAX).astype(np.int64)

    def _produce(self, n: int) -> np.ndarray:
        """Return n records (structured array) and advance the sequences (lock held). The records are built as
        one (n, 9) integer table (few numpy calls: this runs per burst)."""
        step = self._ft_step
        first_index = self._stream_k0 + self._stream_done * step  # internal sample numbers: first + k × step
        if self._restart_requested:  # a power cycle mid-stream: the next record is the box's sample 1 × step
            self._restart_requested = False
            self._rdt_sequence, self._ft_sequence = 0, 0
            self._last_index = first_index - step
        table = np.empty((n, 9), dtype=np.int64)  # rdt_sequence, ft_sequence, status, counts (6)
        table[:, 0] = np.arange(self._rdt_sequence + 1, self._rdt_sequence + 1 + n, dtype=np.int64)
        first_step = first_index - self._last_index  # internal samples since the previous record
        self._last_index = first_index + (n - 1) * step
        if self._stall_remaining:
            steps = np.full(n, step, dtype=np.int64)
            steps[0] = first_step
            stalled = min(self._stall_remaining, n)
            steps[:stalled] = 0
            self._stall_remaining -= stalled
            table[:, 1] = self._ft_sequence + np.cumsum(steps)
        else:  # the cumulative sum of (first_step, step, step, ...)
            table[:, 1] = np.arange(self._ft_sequence + first_step, self._ft_sequence + first_step + n * step, step,
                                    dtype=np.int64)
        table[:, :2] &= UINT32_MASK
        self._rdt_sequence, self._ft_sequence = int(table[-1, 0]), int(table[-1, 1])
        due_s = self._due_s(self._stream_done) if self._target is not None else None
        counts = self._raw_counts(self._draw(n, due_s)) - self._bias_counts
        self._last_counts = counts[-1] + self._bias_counts
        if self._settings["setmce"] and not self._latched and self._monitor_breached(counts):
            self._latched = True  # the status of these records already went out without the latch: next ones
        table[:, 2] = self._status_now()
        if self._status_remaining is not None and self._status_remaining > 0:
            flagged = min(self._status_remaining, n)
            self._status_remaining -= flagged
            table[flagged:, 2] = self._status_now()  # the knob bits end after `flagged` records
        np.minimum(np.maximum(counts, INT32_MIN), INT32_MAX, out=table[:, 3:])
        self.records_produced += n
        # big-endian 32-bit words: a count's two's complement is its low 32 bits
        return np.frombuffer((table & UINT32_MASK).astype(">u4"), dtype=RECORD_DTYPE)

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

    def tcp_reply(self, command: bytes, address: tuple) -> bytes:
        """The reply to one 20-byte TCP command (b"" when the box sends none)."""
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
        body = "".join(f"<{k}>{xml_text(v)}</{k}>" for k, v in elements)
        return f'<?xml version="1.0" encoding="utf-8"?>\n<netft>{body}</netft>\n'

    def netftcalapi_xml(self) -> str:
        """The body of ``/netftcalapi.xml``."""
        elements = [("calsn", self.serial), ("calcpf", self.counts_per_force), ("calcpt", self.counts_per_torque),
                    ("scalfu", self.force_unit), ("scaltu", self.torque_unit)]
        body = "".join(f"<{k}>{xml_text(v)}</{k}>" for k, v in elements)
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

