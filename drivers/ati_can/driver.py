"""ATI NETCANOEM ("F/T CAN Bus and Serial Bus Network Interface for OEM") over python-can (docs/protocols-ati.md,
"CAN").

The board answers requests only: the host sends ``ID = (base << 4) | opcode`` and the board replies on the IDs of
the reply opcodes, big-endian. It computes no wrench and no bias: the host reads the raw strain gages, subtracts
its own gage bias, multiplies by the calibration matrix and divides by counts per unit::

    wrench_device = M · (sg − gage_bias) / Cp      (Cp = CpF for Fx–Fz, CpT for Tx–Tz)

then this driver converts once to N and N·m from the board's unit codes (torque is often N-mm).

Any python-can bus works (socketcan, pcan, slcan through pyserial, virtual): pass one in, or name it by URL
``can://INTERFACE/CHANNEL[?base=0x20&bitrate=250000&rate_hz=R&calibration=0&timeout_s=T]`` and the driver opens
it with ``can.Bus(..., ignore_config=True)`` (no env vars or ``~/can.conf``). Request and reply share IDs, so the
driver ignores its own frames (``is_rx`` False) and checks each reply's opcode and length.

Threads: ``start()`` reads the board's identity and calibration in the caller's thread, then one named poll
thread requests gages at ``rate_hz`` and is the bus's only reader. The poll loop never raises: timeouts,
partial replies, late replies, foreign and malformed frames are counted in :class:`SensorHealth`.

Lifecycle, ``read`` and ``average`` come from :class:`drivers.sensor.SensorBase`; units from :mod:`drivers.units`;
the wire tables from :mod:`drivers.ati_can.protocol`; the bus (requests, replies, the frame classifier) from
:class:`drivers.ati_can.transport.CanTransport`, a mixin: the start-up requests, the poll loop and the host-side
bias share one bus, one lock and one frame classifier. Why ~590 lines: one class whose start-up, poll loop and
host-side bias share that lock and the pending samples.
"""

from __future__ import annotations

import collections
import logging
import struct
import threading
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import unquote, urlsplit

import numpy as np

from drivers.ati_can.protocol import (
    FIRMWARE_WITH_COUNTS,
    GAGE_MAX,
    GAGE_MIN,
    HOST_STATUS_GAGE_SATURATED,
    LEGACY_COUNTS_PER_UNIT,
    OP_COUNTS_PER_UNIT,
    OP_FIRMWARE,
    OP_GAGES,
    OP_GAGES_SECOND,
    OP_MATRIX,
    OP_SELECT_CALIBRATION,
    OP_SERIAL,
    OP_UNIT_CODES,
    STATUS_ERROR_MASK,
    STATUS_WATCHDOG_RESET,
    CanCalibration,
    decode_status,
)
from drivers.ati_can.transport import CanTransport
from drivers.sensor import (
    STATUS_SATURATION,
    SensorBase,
    SensorHealth,
    SensorInfo,
    WrenchBatch,
    check_range,
    query_items,
)
from drivers.units import FORCE_UNIT_CODES, FORCE_UNITS, TORQUE_UNIT_CODES, TORQUE_UNITS
from ftacq.errors import DeviceError, DeviceTimeoutError, InputError, SensorFaultError

logger = logging.getLogger(__name__)

# ------------------------------------------------------------------------ defaults
DEFAULT_BASE = 0x20
DEFAULT_BITRATE = 250_000
DEFAULT_RATE_HZ = 500.0
"""Default gage poll rate, Hz: one poll is ~300 bits on the wire, so 500 Hz uses ~60 % of 250 kbit/s."""
MAX_RATE_HZ = 10_000.0
MAX_BITRATE = 2_000_000
DEFAULT_REPLY_TIMEOUT_S = 0.1
"""Time a request waits for its reply frames, seconds (monotonic), as the SocketCAN C++ driver."""
DEFAULT_STARTUP_TIMEOUT_S = 0.5
"""Time each start-up request try waits for its reply, seconds (longer than a poll's: a loaded host may be slow
to schedule, and start-up happens once)."""
DEFAULT_BIAS_SAMPLES = 32
DEFAULT_BIAS_TIMEOUT_S = 2.0
MAX_PENDING_SAMPLES = 1_000_000
"""Samples kept for ``read`` if nobody reads (oldest dropped beyond this; ~33 min at 500 Hz)."""
RATE_WINDOW_S = 1.0
"""Window of the measured poll rate in ``SensorHealth.rate_hz``, seconds."""
MAX_CATCH_UP_POLLS = 5
"""A poll loop late by up to this many periods (scheduling jitter) catches up; later than that it skips."""
ERROR_BACKOFF_S = 0.05
"""Pause after a bus error (send failed, bus closed) before the next poll, seconds."""
CLOSE_JOIN_TIMEOUT_S = 2.0

URL_FORM = "can://INTERFACE/CHANNEL[?base=0x20&bitrate=250000&rate_hz=500&calibration=0&timeout_s=0.1]"


class _BiasRequest:
    """A bias in progress: the poll thread adds valid gage samples until ``needed`` are in."""

    def __init__(self, needed: int, first_sequence: int) -> None:
        self.needed = needed
        self.first_sequence = first_sequence
        self.total = np.zeros(6)
        self.count = 0
        self.rejected = 0
        self.done = threading.Event()


class AtiCanSensor(CanTransport, SensorBase):
    """ATI NETCANOEM on a python-can bus, implementing :class:`drivers.sensor.ForceTorqueSensor`.

    Args:
        bus: a python-can bus to use (not shut down on close); or None to open ``interface``/``channel``.
        interface, channel, bitrate: used to open a bus when none is given (bit/s; informational otherwise).
        base: the board's 7-bit base ID (0x20 by default: IDs 0x200–0x20F).
        rate_hz: gage poll rate in Hz; None polls as fast as the bus answers.
        calibration_index: the calibration slot (0–15) to select at start.
        reply_timeout_s: seconds a gage poll waits for its reply frames.
        startup_timeout_s: seconds each try of a start-up request waits for its reply (3 tries).
        assume_unit_codes: (force, torque) unit codes for firmware older than 3.7, which cannot report them.
        bus_options: extra keyword arguments for ``can.Bus`` when the driver opens the bus (e.g. slcan's
            ``sleep_after_open`` in s, pcan's ``device_id``).

    The constructor does no I/O; ``start()`` opens the bus, reads firmware, selects the calibration, reads the
    matrix, counts per unit, units and serial number, and starts polling.

    Each polled sample is readable the moment its reply frames are in (the poll thread wakes the reader), so
    :meth:`prefer_low_latency` has nothing to shorten: it keeps and reports the hold asked for (the base's).
    """

    def __init__(
        self,
        bus=None,
        *,
        interface: str = "virtual",
        channel: str | None = None,
        base: int = DEFAULT_BASE,
        bitrate: int = DEFAULT_BITRATE,
        rate_hz: float | None = DEFAULT_RATE_HZ,
        calibration_index: int = 0,
        reply_timeout_s: float = DEFAULT_REPLY_TIMEOUT_S,
        startup_timeout_s: float = DEFAULT_STARTUP_TIMEOUT_S,
        assume_unit_codes: tuple[int, int] = (2, 3),
        bus_options: dict | None = None,
    ) -> None:
        super().__init__()
        check_range("base", base, 0, 0x7F)
        check_range("calibration_index", calibration_index, 0, 15)
        check_range("bitrate", bitrate, 1, MAX_BITRATE)
        if rate_hz is not None:
            check_range("rate_hz", rate_hz, 1e-3, MAX_RATE_HZ)
        check_range("reply_timeout_s", reply_timeout_s, 1e-4, 60.0)
        check_range("startup_timeout_s", startup_timeout_s, 1e-4, 60.0)
        if assume_unit_codes[0] not in FORCE_UNIT_CODES or assume_unit_codes[1] not in TORQUE_UNIT_CODES:
            raise InputError(f"assume_unit_codes {assume_unit_codes!r}: force code must be one of "
                             f"{sorted(FORCE_UNIT_CODES)}, torque code one of {sorted(TORQUE_UNIT_CODES)}")
        if bus is None and not channel:
            raise InputError("AtiCanSensor needs a python-can bus or a channel to open one")
        self._bus = bus
        self._owns_bus = bus is None
        self.interface = interface
        self.channel = channel if channel is not None else str(getattr(bus, "channel_info", bus))
        self.base = base
        self.bitrate = bitrate
        self.rate_hz = rate_hz
        self.calibration_index = calibration_index
        self.reply_timeout_s = reply_timeout_s
        self.startup_timeout_s = startup_timeout_s
        self.assume_unit_codes = assume_unit_codes
        self.bus_options = dict(bus_options or {})
        self.calibration: CanCalibration | None = None
        self.info = SensorInfo(transport="can", serial="", firmware="", force_unit="", torque_unit="",
                               counts_per_force=0.0, counts_per_torque=0.0, rate_hz=float(rate_hz or 0.0))
        self._health = SensorHealth()
        self._lock = threading.Condition()
        self._pending: collections.deque = collections.deque(maxlen=MAX_PENDING_SAMPLES)
        self._bias_table = [np.zeros(6)]
        self._bias_request: _BiasRequest | None = None
        self._gages_to_si = np.zeros((6, 6))
        self._sequence = 0
        self._last_board_status = 0
        self._silent = False
        self._last_sample_s: float | None = None
        self.send_errors = 0
        self.overflowed = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ construction from a URL

    URL_FORM = URL_FORM

    @classmethod
    def parse_url(cls, url: str) -> dict:
        """Return the constructor keyword arguments named by a ``can://`` URL (no I/O)."""
        return parse_can_url(url)

    @classmethod
    def from_url(cls, url: str, bus=None, **options) -> "AtiCanSensor":
        """Return an unstarted driver for ``can://INTERFACE/CHANNEL[?base=…&bitrate=…&rate_hz=…]``.

        ``CHANNEL`` is everything after the first slash, percent-decoded: ``can://socketcan/can0``,
        ``can://pcan/PCAN_USBBUS1``, ``can://slcan//dev/ttyACM0@115200`` (serial device and tty baud rate),
        ``can://virtual/test-1``. Query keys: ``base`` (0x00–0x7F, hex or decimal), ``bitrate`` (bit/s),
        ``rate_hz`` (poll rate, Hz), ``calibration`` (slot 0–15), ``timeout_s`` (reply timeout, s).
        ``bus`` (optional) is used instead of opening one; ``options`` override the URL's keys
        (constructor argument names). Raises InputError naming the part of the URL that is wrong.
        """
        kwargs = parse_can_url(url)
        kwargs.update(options)
        return cls(bus, **kwargs)

    # ------------------------------------------------------------------ lifecycle

    @property
    def label(self) -> str:
        return f"ATI CAN board (base {self.base:#04x}, {self.interface} {self.channel!r})"

    def _open(self) -> None:
        """Open the bus, read the board's identity and calibration, and start polling.

        Raises DeviceConnectionError when the bus cannot be opened, DeviceTimeoutError when the board does not
        answer, DeviceError when its answers are inconsistent (calibration echo, unit codes, counts per unit).
        """
        if self._bus is None:
            self._bus = self._open_bus()
        self._discover()
        self._started = True
        self._thread = threading.Thread(
            target=self._run, name=f"AtiCanSensor-{self.interface}-{self.channel}-{self.base:#04x}", daemon=False
        )
        self._thread.start()

    def _shutdown(self) -> None:
        """Stop polling, join the poll thread and shut down a bus this driver opened."""
        self._stop.set()
        with self._lock:
            self._lock.notify_all()
        if self._thread is not None:
            self._thread.join(CLOSE_JOIN_TIMEOUT_S)
            if self._thread.is_alive():
                logger.error("%s did not stop within %.1f s", self._thread.name, CLOSE_JOIN_TIMEOUT_S)
        self._shutdown_owned_bus()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "polling" if self._started else "not started"
        return (f"AtiCanSensor(interface={self.interface!r}, channel={self.channel!r}, base={self.base:#04x}, "
                f"bitrate={self.bitrate}, rate_hz={self.rate_hz}, calibration_index={self.calibration_index}, "
                f"{state})")

    # ------------------------------------------------------------------ the sensor contract

    def describe_status(self, status: int) -> str:
        names = decode_status(status & 0xFFFF)
        if status & STATUS_SATURATION:
            names = ["gage saturated", *names]
        return f"{status:#010x} ({', '.join(names) or 'ok'})"

    def _take(self) -> WrenchBatch:
        with self._lock:
            rows = list(self._pending)
            self._pending.clear()
        return self._to_batch(rows)

    def _wait_for_data(self, timeout_s: float) -> None:
        with self._lock:
            if not self._pending and not self._stop.is_set():
                self._lock.wait(timeout_s)

    def _silence_message(self, timeout_s: float | None) -> str:
        health = self.health()
        return (f"no sample from the {self.label} within {timeout_s} s: {health.timeouts} polls unanswered, "
                f"{health.received} samples received so far")

    def _begin_average(self) -> int:
        """Only polls requested after the call count (samples waiting or in flight are discarded)."""
        with self._lock:
            self._pending.clear()
            return self._sequence + 1  # a poll already in flight was requested before this call

    def _fresh(self, batch: WrenchBatch, first_sequence: int) -> WrenchBatch:
        fresh = batch.sequence >= first_sequence
        if fresh.all():
            return batch
        return batch.select(fresh)

    def _lost_between(self, before: SensorHealth, after: SensorHealth) -> int:
        """Polls in the window left unanswered, wholly (timeouts) or partly (lost)."""
        return (after.timeouts - before.timeouts) + (after.lost - before.lost)

    def bias(self, samples: int = DEFAULT_BIAS_SAMPLES, timeout_s: float = DEFAULT_BIAS_TIMEOUT_S) -> None:
        """Tare on the host: average the gages of the next ``samples`` valid polls (requested after this call)
        and subtract them from every later sample (the board computes no bias). Raises DeviceTimeoutError if they do not arrive within
        ``timeout_s`` seconds, SensorFaultError if the gages are saturated or the status reports an error."""
        self._require_started()
        check_range("samples", samples, 1, 100_000)
        with self._lock:
            request = _BiasRequest(samples, self._sequence + 1)
            self._bias_request = request
        if not request.done.wait(timeout_s) or request.count < request.needed:
            with self._lock:
                if self._bias_request is request:
                    self._bias_request = None
            if request.rejected and not request.count:
                raise SensorFaultError(
                    f"cannot bias the ATI CAN board: {request.rejected} samples saturated or with an error status "
                    f"(last status {self._last_board_status:#06x}: {', '.join(decode_status(self._last_board_status)) or 'gage saturated'})")
            raise DeviceTimeoutError(
                f"bias needs {samples} valid samples from the ATI CAN board (base {self.base:#04x}); got "
                f"{request.count} within {timeout_s} s")

    def clear_bias(self) -> None:
        """Forget the host bias: later samples are M·sg/Cp of the raw gages."""
        with self._lock:
            self._bias_table.append(np.zeros(6))

    @property
    def gage_bias(self) -> np.ndarray:
        """(6,) the host gage bias in use, gage counts."""
        with self._lock:
            return self._bias_table[-1].copy()

    def health(self) -> SensorHealth:
        """Return a snapshot of the counters: received, timeouts (polls with no reply), lost (polls with a
        partial reply), gaps (runs of unanswered polls) and longest_gap_s (host time across the longest),
        out_of_order (late replies to an earlier poll), duplicate, malformed (our IDs, wrong
        length), foreign (other IDs), saturated, status_errors, restarts (watchdog-reset bit rising),
        last_status and the measured poll rate_hz."""
        with self._lock:
            return self._health.snapshot()

    # ------------------------------------------------------------------ start-up

    def _discover(self) -> None:
        """Read firmware, select the calibration, read matrix, counts per unit, units, serial (§4.1 sequence)."""
        major, minor, build = struct.unpack(">BBH", self._request(OP_FIRMWARE, b"", "firmware version")[OP_FIRMWARE])
        firmware = f"{major}.{minor}.{build}"
        self._select_calibration()
        rows = []
        for axis in range(6):
            replies = self._request(OP_MATRIX, bytes([axis]), f"matrix row {axis}",
                                    (OP_MATRIX, OP_MATRIX + 1, OP_MATRIX + 2))
            rows.append(np.frombuffer(b"".join(replies[OP_MATRIX + k] for k in range(3)), dtype=">f4"))
        matrix = np.array(rows, dtype=np.float64)
        if not np.all(np.isfinite(matrix)) or np.linalg.matrix_rank(matrix) < 6:
            raise DeviceError(f"ATI CAN board sent an unusable calibration matrix (slot {self.calibration_index}): "
                              f"{matrix.tolist()}")
        if (major, minor) >= FIRMWARE_WITH_COUNTS:
            cpf, cpt = struct.unpack(">II", self._request(OP_COUNTS_PER_UNIT, b"", "counts per unit")[OP_COUNTS_PER_UNIT])
            force_code, torque_code = self._request(OP_UNIT_CODES, b"", "unit codes")[OP_UNIT_CODES]
        else:
            cpf = cpt = LEGACY_COUNTS_PER_UNIT
            force_code, torque_code = self.assume_unit_codes
            logger.warning("ATI CAN firmware %s < 3.7 reports no counts per unit or units: assuming 1e6 counts "
                           "per unit and unit codes %s", firmware, self.assume_unit_codes)
        if cpf <= 0 or cpt <= 0:
            raise DeviceError(f"ATI CAN board reports counts per unit CpF={cpf}, CpT={cpt}; both must be > 0")
        if force_code not in FORCE_UNIT_CODES or torque_code not in TORQUE_UNIT_CODES:
            raise DeviceError(f"ATI CAN board reports unknown unit codes force={force_code}, torque={torque_code} "
                              f"(known: force {sorted(FORCE_UNIT_CODES)}, torque {sorted(TORQUE_UNIT_CODES)})")
        serial = self._request(OP_SERIAL, b"", "serial number")[OP_SERIAL].rstrip(b"\x00 ").decode("ascii", "replace")
        force_unit, torque_unit = FORCE_UNIT_CODES[force_code], TORQUE_UNIT_CODES[torque_code]
        force_si, torque_si = FORCE_UNITS[force_unit], TORQUE_UNITS[torque_unit]
        self.calibration = CanCalibration(matrix, float(cpf), float(cpt), force_unit, torque_unit, force_si, torque_si)
        self._gages_to_si = self.calibration.gages_to_si
        self.info = SensorInfo(
            transport="can",
            serial=serial,
            firmware=firmware,
            force_unit=force_unit,
            torque_unit=torque_unit,
            counts_per_force=float(cpf),
            counts_per_torque=float(cpt),
            rate_hz=float(self.rate_hz or 0.0),
            extra={
                "interface": self.interface,
                "channel": self.channel,
                "base": f"{self.base:#04x}",
                "bitrate": self.bitrate,
                "calibration_index": self.calibration_index,
                "calibration_matrix": matrix.tolist(),
                "force_unit_code": int(force_code),
                "torque_unit_code": int(torque_code),
            },
        )

    def _select_calibration(self) -> None:
        echo = self._request(OP_SELECT_CALIBRATION, bytes([self.calibration_index]),
                             "set active calibration")[OP_SELECT_CALIBRATION]
        if echo[0] != self.calibration_index:
            raise DeviceError(f"ATI CAN board selected calibration {echo[0]} instead of {self.calibration_index}")

    # ------------------------------------------------------------------ the poll loop

    def _run(self) -> None:
        period_s = 1.0 / self.rate_hz if self.rate_hz else 0.0
        next_poll = time.monotonic()
        rate_start, rate_count = next_poll, 0
        try:
            while not self._stop.is_set():
                if period_s:
                    delay = next_poll - time.monotonic()
                    if delay > 0 and self._stop.wait(delay):
                        break
                    next_poll += period_s
                    now = time.monotonic()
                    if next_poll < now - MAX_CATCH_UP_POLLS * period_s:
                        next_poll = now  # far behind (silent board, slow bus): do not burst to catch up
                try:
                    if self._poll_once():
                        rate_count += 1
                except Exception as error:  # the loop never raises: count, log, back off
                    self.send_errors += 1
                    with self._lock:
                        self._health.timeouts += 1
                    if self.send_errors in (1, 10, 100) or self.send_errors % 1000 == 0:
                        logger.warning("CAN poll failed (%d so far): %r", self.send_errors, error)
                    self._stop.wait(ERROR_BACKOFF_S)
                now = time.monotonic()
                if now - rate_start >= RATE_WINDOW_S:
                    with self._lock:
                        self._health.rate_hz = rate_count / (now - rate_start)
                    rate_start, rate_count = now, 0
        except BaseException as error:  # only a bug gets here; close() re-raises it
            self._thread_error = error
            logger.exception("CAN poll thread failed")
            with self._lock:
                self._lock.notify_all()

    def _poll_once(self) -> bool:
        """Request the gages once; store the sample and return True, or count the failure and return False."""
        import can

        tally = SensorHealth()
        self._drain(tally)
        self._sequence += 1
        self._bus.send(can.Message(arbitration_id=self.base << 4 | OP_GAGES, data=b"", is_extended_id=False))
        replies = self._collect((OP_GAGES, OP_GAGES_SECOND), time.monotonic() + self.reply_timeout_s, tally)
        self._merge(tally)
        received_at = time.monotonic()
        if len(replies) < 2:
            with self._lock:
                if replies:
                    self._health.lost += 1
                else:
                    self._health.timeouts += 1
            if not self._silent:
                self._silent = True
                logger.warning("ATI CAN board (base %#04x) did not answer a gage request within %s s",
                               self.base, self.reply_timeout_s)
            return False
        if self._silent:
            self._silent = False
            logger.info("ATI CAN board (base %#04x) answers again", self.base)
            with self._lock:  # a run of unanswered polls between two samples is one gap
                self._health.gaps += 1
                if self._last_sample_s is not None:
                    self._health.longest_gap_s = max(self._health.longest_gap_s, received_at - self._last_sample_s)
        self._last_sample_s = received_at
        status, sg0, sg2, sg4 = struct.unpack(">Hhhh", replies[OP_GAGES])
        sg1, sg3, sg5 = struct.unpack(">hhh", replies[OP_GAGES_SECOND])
        gages = (sg0, sg1, sg2, sg3, sg4, sg5)
        saturated_gage = GAGE_MAX in gages or GAGE_MIN in gages
        restarted = bool(status & STATUS_WATCHDOG_RESET and not self._last_board_status & STATUS_WATCHDOG_RESET)
        # after a reset the board is back on slot 0: this sample used the wrong matrix if we selected another
        flagged = saturated_gage or bool(status & STATUS_ERROR_MASK) or (restarted and self.calibration_index != 0)
        with self._lock:
            health = self._health
            health.received += 1
            health.last_status = status
            if saturated_gage:
                health.saturated += 1
            if status & STATUS_ERROR_MASK:
                health.status_errors += 1
            if restarted:
                health.restarts += 1
            self._last_board_status = status
            request = self._bias_request
            if request is not None and self._sequence >= request.first_sequence:
                if flagged:
                    request.rejected += 1
                    if request.rejected >= request.needed and request.count == 0:
                        self._bias_request = None
                        request.done.set()  # bias() reports the fault without waiting for its timeout
                else:
                    request.total += gages
                    request.count += 1
                    if request.count >= request.needed:
                        self._bias_table.append(request.total / request.count)
                        self._bias_request = None
                        request.done.set()
            if len(self._pending) == self._pending.maxlen:
                self.overflowed += 1
            host_status = status | (HOST_STATUS_GAGE_SATURATED if saturated_gage else 0)
            self._pending.append((received_at, host_status, *gages, self._sequence, len(self._bias_table) - 1,
                                  flagged))
            self._lock.notify_all()
        if restarted and self.calibration_index != 0:
            self._reselect_after_reset()
        return True

    def _reselect_after_reset(self) -> None:
        """After a board reset the active calibration is slot 0 again: select ours (from the poll thread)."""
        import can

        tally = SensorHealth()
        self._drain(tally)
        self._bus.send(can.Message(arbitration_id=self.base << 4 | OP_SELECT_CALIBRATION,
                                   data=bytes([self.calibration_index]), is_extended_id=False))
        echo = self._collect((OP_SELECT_CALIBRATION,), time.monotonic() + self.reply_timeout_s, tally)
        self._merge(tally)
        if echo.get(OP_SELECT_CALIBRATION) == bytes([self.calibration_index]):
            logger.warning("ATI CAN board (base %#04x) reset: calibration %d selected again",
                           self.base, self.calibration_index)
        else:
            logger.error("ATI CAN board (base %#04x) reset and did not confirm calibration %d: readings use "
                         "slot 0's matrix until the driver is restarted", self.base, self.calibration_index)

    def _to_batch(self, rows: list[tuple]) -> WrenchBatch:
        """Convert pending rows to a WrenchBatch: wrench_si = K · (sg − bias), K = diag(SI/Cp) · M, once."""
        if not rows:
            return WrenchBatch.empty()
        table = np.array(rows, dtype=np.float64)
        gages = table[:, 2:8].astype(np.int64)
        with self._lock:
            biases = np.array(self._bias_table)
        bias = biases[table[:, 9].astype(np.intp)]
        wrench = (gages - bias) @ self._gages_to_si.T
        return WrenchBatch(
            time_s=table[:, 0].copy(),
            wrench=wrench,
            counts=gages,
            status=table[:, 1].astype(np.uint32),
            sequence=table[:, 8].astype(np.int64),
            saturated=table[:, 10].astype(bool),
            device_time_s=np.full(len(rows), np.nan),  # polled: the sensor has no sample clock of its own
        )

_URL_KEYS: dict[str, tuple[str, Callable[[str], Any]]] = {
    "base": ("base", lambda v: int(v, 0)),
    "bitrate": ("bitrate", int),
    "rate_hz": ("rate_hz", float),
    "calibration": ("calibration_index", int),
    "timeout_s": ("reply_timeout_s", float),
}


def parse_can_url(url: str) -> dict:
    """Return the constructor keyword arguments named by a ``can://`` URL (see ``AtiCanSensor.from_url``).

    Raises InputError with the expected form and the offending part of the URL.
    """
    import can

    try:
        parts = urlsplit(url)
    except ValueError as error:
        raise InputError(f"sensor URL {url!r}: {error}; expected {URL_FORM}") from None
    if parts.scheme != "can":
        raise InputError(f"sensor URL {url!r}: scheme must be 'can'; expected {URL_FORM}")
    interface = parts.netloc
    if not interface:
        raise InputError(f"sensor URL {url!r}: missing INTERFACE; expected {URL_FORM}")
    if interface not in can.VALID_INTERFACES:
        raise InputError(f"sensor URL {url!r}: unknown python-can interface {interface!r}; one of "
                         f"{', '.join(sorted(can.VALID_INTERFACES))}")
    channel = unquote(parts.path[1:]) if parts.path.startswith("/") else ""
    if not channel:
        raise InputError(f"sensor URL {url!r}: missing CHANNEL after the interface; expected {URL_FORM}")
    kwargs: dict = {"interface": interface, "channel": channel}
    for key, value in query_items(url, parts.query, _URL_KEYS):
        name, convert = _URL_KEYS[key]
        try:
            kwargs[name] = convert(value)
        except ValueError:
            raise InputError(f"sensor URL {url!r}: {key}={value!r} is not a number") from None
    limits = {"base": (0, 0x7F), "bitrate": (1, MAX_BITRATE), "rate_hz": (1e-3, MAX_RATE_HZ),
              "calibration_index": (0, 15), "reply_timeout_s": (1e-4, 60.0)}
    for name, (low, high) in limits.items():
        if name in kwargs and not low <= kwargs[name] <= high:
            key = next(k for k, (n, _) in _URL_KEYS.items() if n == name)
            raise InputError(f"sensor URL {url!r}: {key}={kwargs[name]!r} is out of range {low}..{high}")
    return kwargs
