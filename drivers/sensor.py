"""The force/torque sensor contract every transport implements, its value types, a shared base and the registry.

Samples travel in numpy batches (:class:`WrenchBatch`), never one Python object per sample: at 7 kHz on two
cores a per-sample object costs more than the protocol itself.

Sensors are named by URL; the scheme picks the driver from :data:`SENSOR_TYPES` (modelled on python-can's
interface table: ``scheme → (module, class)``, imported only when a URL of that scheme is opened):

- ``netft://HOST[:RDT_PORT][?tcp_port=N&http_port=N&rate_hz=R&…]`` — ATI Net F/T (:mod:`drivers.netft`)
- ``can://INTERFACE/CHANNEL[?base=0x20&bitrate=250000&…]`` — ATI NETCANOEM on a python-can bus
  (:mod:`drivers.ati_can`)

A new sensor type is one driver module (a :class:`SensorBase` subclass with ``from_url``, ``parse_url`` and
``URL_FORM``) plus one row of :data:`SENSOR_TYPES`. Units come from :mod:`drivers.units` (one table for all).
This module imports none of its implementations.
"""

from __future__ import annotations

import importlib
import threading
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable
from urllib.parse import parse_qsl, urlsplit

import numpy as np

from ftacq.errors import DeviceError, DeviceTimeoutError, InputError, SensorFaultError

# Status word bits every driver uses in WrenchBatch.status (the Net F/T's layout, docs/protocols-ati.md "Status")
STATUS_SUMMARY = 0x8000_0000
STATUS_SATURATION = 0x0002_0000
STATUS_MONITOR_LATCH = 0x0001_0000
STATUS_HEALTHY_MASK = STATUS_SUMMARY | STATUS_MONITOR_LATCH
"""A status whose bits all lie in this mask is healthy (0, or the informational latch 0x80010000)."""

SENSOR_TYPES: dict[str, tuple[str, str, str]] = {
    "netft": ("drivers.netft", "NetFTSensor", "netft://HOST[:RDT_PORT][?tcp_port=N&http_port=N&rate_hz=R]"),
    "can": ("drivers.ati_can", "AtiCanSensor", "can://INTERFACE/CHANNEL[?base=0x20&bitrate=250000]"),
}
"""URL scheme → (module, class, short URL form). The module is imported only when a URL of its scheme is used."""

@dataclass(frozen=True)
class WrenchBatch:
    """A batch of N consecutive samples, oldest first.

    Attributes:
        time_s: (N,) receive time, seconds on the host's monotonic clock (``time.monotonic``).
        wrench: (N, 6) Fx, Fy, Fz [N], Tx, Ty, Tz [N·m] in the sensor frame, after any host or device bias.
        counts: (N, 6) int64 raw values as sent by the device (RDT counts, or gages for CAN).
        status: (N,) uint32 device status word per sample.
        sequence: (N,) int64 device sequence number (RDT rdt_sequence, or a host counter for polled CAN).
        saturated: (N,) bool, True where the sample is saturated or its status reports an error.
        device_time_s: (N,) float, the sample's time on the device's own clock, seconds (the Net F/T: its sample
            counter ``ft_sequence`` over its internal rate, so skipped samples show as gaps); NaN where the device
            has no sample clock (a polled CAN sensor: use ``time_s``). Defaults to NaN.
    """

    time_s: np.ndarray
    wrench: np.ndarray
    counts: np.ndarray
    status: np.ndarray
    sequence: np.ndarray
    saturated: np.ndarray
    device_time_s: np.ndarray = None  # type: ignore[assignment]  # NaN (N,) when not given: see __post_init__

    def __post_init__(self) -> None:
        if self.device_time_s is None:
            object.__setattr__(self, "device_time_s", np.full(np.shape(self.time_s)[:1], np.nan))

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    def select(self, index) -> "WrenchBatch":
        """Return the samples at ``index`` (a boolean mask or indices), every field alike."""
        return WrenchBatch(self.time_s[index], self.wrench[index], self.counts[index], self.status[index],
                           self.sequence[index], self.saturated[index], self.device_time_s[index])

    @staticmethod
    def empty() -> "WrenchBatch":
        """Return a batch with no samples."""
        return WrenchBatch(
            time_s=np.empty(0),
            wrench=np.empty((0, 6)),
            counts=np.empty((0, 6), dtype=np.int64),
            status=np.empty(0, dtype=np.uint32),
            sequence=np.empty(0, dtype=np.int64),
            saturated=np.empty(0, dtype=bool),
        )

    @staticmethod
    def concatenate(batches: "list[WrenchBatch]") -> "WrenchBatch":
        """Return the batches joined in order."""
        if not batches:
            return WrenchBatch.empty()
        return WrenchBatch(
            time_s=np.concatenate([b.time_s for b in batches]),
            wrench=np.concatenate([b.wrench for b in batches]),
            counts=np.concatenate([b.counts for b in batches]),
            status=np.concatenate([b.status for b in batches]),
            sequence=np.concatenate([b.sequence for b in batches]),
            saturated=np.concatenate([b.saturated for b in batches]),
            device_time_s=np.concatenate([b.device_time_s for b in batches]),
        )


@dataclass(frozen=True)
class WrenchAverage:
    """The mean of a window of samples at one still pose.

    Attributes:
        mean: (6,) N and N·m. std: (6,) sample standard deviation, same units.
        count: samples averaged (saturated samples are excluded and counted separately).
        saturated: samples excluded because saturated or with an error status.
        lost: samples the device sent that never arrived during the window.
        duration_s: host time spanned by the window.
    """

    mean: np.ndarray
    std: np.ndarray
    count: int
    saturated: int
    lost: int
    duration_s: float


@dataclass
class SensorHealth:
    """Counters of what a stream did wrong since the driver started (counts, except as noted).

    ``lost`` counts samples the device produced that were never delivered; ``gaps`` the losses (one run of
    consecutive lost samples is one gap) and ``longest_gap_s`` the longest host time across one gap, seconds.
    ``socket_drops``: datagrams the host's kernel dropped at the receive socket (its buffer full: the receive thread
    was late), where the driver and the system can tell (Net F/T on Linux), else 0; ``ring_overflows``: datagrams
    the receive thread dropped because the reader fell behind its ring. Both are among ``lost``.
    """

    received: int = 0
    lost: int = 0
    gaps: int = 0
    longest_gap_s: float = 0.0
    duplicate: int = 0
    out_of_order: int = 0
    malformed: int = 0
    foreign: int = 0
    stalled: int = 0
    saturated: int = 0
    status_errors: int = 0
    timeouts: int = 0
    restarts: int = 0
    reconnects: int = 0
    socket_drops: int = 0
    ring_overflows: int = 0
    last_status: int = 0
    rate_hz: float = 0.0

    def snapshot(self) -> "SensorHealth":
        """Return a copy safe to hand to another thread."""
        return SensorHealth(**self.__dict__)


@dataclass(frozen=True)
class SensorInfo:
    """What the device says about itself (units are the device's; the driver converts to SI).

    ``serial``, ``model``, ``firmware``, the units and counts per unit identify the sensor in a calibration file
    (:func:`ftacq.provenance.sensor_record`); empty strings where the device does not tell.
    """

    transport: str
    serial: str
    firmware: str
    force_unit: str
    torque_unit: str
    counts_per_force: float
    counts_per_torque: float
    rate_hz: float
    extra: dict = field(default_factory=dict)
    model: str = ""


@runtime_checkable
class ForceTorqueSensor(Protocol):
    """What the procedure and the dashboard need from a sensor, whatever the transport.

    Lifecycle: construct (no I/O), ``start()`` (connect, discover, stream), ``read``/``average``,
    ``close()`` (idempotent; stops the stream). Also a context manager.
    """

    info: SensorInfo

    def start(self) -> None:
        """Connect, read units and counts per unit, and start streaming. Raises DeviceConnectionError."""

    def read(self, timeout_s: float | None = 1.0) -> WrenchBatch:
        """Return every sample received since the last call (possibly many); wait up to ``timeout_s``
        seconds for at least one. Raises DeviceTimeoutError when none arrives in time."""

    def average(self, duration_s: float, timeout_s: float | None = None) -> WrenchAverage:
        """Collect fresh samples for ``duration_s`` seconds and return their mean and standard deviation."""

    def bias(self) -> None:
        """Tare: later samples read zero at the current load."""

    def health(self) -> SensorHealth:
        """Return a snapshot of the stream's health counters."""

    def prefer_low_latency(self, max_hold_s: float | None) -> float | None:
        """Make received samples readable at most ``max_hold_s`` seconds after they arrive (None: the driver's own
        hold again); return the hold asked before, for the caller to put back (a hint; see
        :meth:`SensorBase.prefer_low_latency`)."""

    def close(self) -> None:
        """Stop streaming and release sockets / the bus. Safe to call twice."""


POLL_S = 0.05
"""Longest a reader blocks before re-checking the driver's state, seconds."""
AVERAGE_GRACE_S = 1.0
"""Extra time ``average`` allows beyond its window before giving up, seconds."""


def check_range(name: str, value: object, low: float, high: float) -> None:
    """Raise InputError naming ``name`` when ``value`` is not a real number in [low, high] (bools are not)."""
    if (isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating))
            or not low <= value <= high):
        raise InputError(f"{name} = {value!r} is out of range {low}..{high}")


def query_items(url: str, query: str, known: "dict | set | tuple") -> list[tuple[str, str]]:
    """Return the ``key=value`` pairs of a sensor URL's query, refusing unknown and repeated keys (InputError)."""
    seen: set[str] = set()
    items = parse_qsl(query, keep_blank_values=True)
    for key, _ in items:
        if key not in known:
            raise InputError(f"sensor URL {url!r}: unknown query key {key!r}; known keys: {', '.join(known)}")
        if key in seen:
            raise InputError(f"sensor URL {url!r}: query key {key!r} given twice")
        seen.add(key)
    return items


class SensorBase:
    """What every driver shares: lifecycle, ``read`` with a deadline, ``average``, and the status text.

    Lifecycle: the constructor does no I/O; :meth:`start` calls the driver's ``_open`` (connect, discover, start
    its thread) and, if that fails, :meth:`close`; :meth:`close` is idempotent, calls ``_shutdown`` and re-raises
    (as DeviceError) an unexpected error that ended the driver's thread. Also a context manager.

    A driver implements ``_open``, ``_shutdown``, ``_take`` (every sample received since the last call, oldest
    first, as one batch), ``_wait_for_data(timeout_s)``, ``health``, ``describe_status`` and ``label`` (for
    messages); it may refine ``_begin_average`` / ``_fresh`` / ``_lost_between`` (what counts as a fresh sample and
    as lost while averaging).
    """

    info: SensorInfo
    URL_FORM = ""

    @classmethod
    def parse_url(cls, url: str) -> dict:
        """Check ``url`` without touching the network; return the constructor's keyword arguments."""
        raise NotImplementedError

    @classmethod
    def from_url(cls, url: str, **options: Any) -> "SensorBase":
        """Return an unstarted driver for ``url``; ``options`` override the URL's keys."""
        raise NotImplementedError

    def __init__(self) -> None:
        self._started = False
        self._closed = False
        self._thread_error: BaseException | None = None
        self._lifecycle_lock = threading.Lock()
        self._max_hold_s: float | None = None

    # ------------------------------------------------------------------ hooks

    @property
    def label(self) -> str:
        """The device as messages name it, e.g. ``Net F/T 192.168.1.1:49152``."""
        return type(self).__name__

    def bias(self) -> None:
        """Tare the sensor at the current load (device-specific)."""
        raise NotImplementedError

    @property
    def max_hold_s(self) -> float | None:
        """The longest hold (s) a reader asked for with :meth:`prefer_low_latency`; None: the driver's own."""
        return self._max_hold_s

    def prefer_low_latency(self, max_hold_s: float | None) -> float | None:
        """Hint from a reader that acts on the newest sample each cycle (``ftacq bridge``): make received samples
        readable at most ``max_hold_s`` (s) after they arrive; None gives the driver's own hold back. Returns the
        hold asked before (None: the driver's own), which the reader passes back when it is done: a shorter hold
        costs CPU (more wake-ups a second) for as long as it stays, and the driver outlives the reader (the
        monitor after a bridge run, a dashboard). Drivers that hold samples back to save CPU apply it in
        :meth:`_apply_hold` (at once, and when they open); the others already deliver at once and only keep the
        value."""
        previous = self._max_hold_s
        self._max_hold_s = None if max_hold_s is None else max(0.0, float(max_hold_s))
        self._apply_hold()
        return previous

    def _apply_hold(self) -> None:
        """Make :attr:`max_hold_s` (None: the driver's own hold) the longest received samples wait (hook)."""

    def _open(self) -> None:
        raise NotImplementedError

    def _shutdown(self) -> None:
        raise NotImplementedError

    def _take(self) -> WrenchBatch:
        raise NotImplementedError

    def _wait_for_data(self, timeout_s: float) -> None:
        raise NotImplementedError

    def health(self) -> SensorHealth:
        raise NotImplementedError

    def describe_status(self, status: int) -> str:
        """Return ``0x… (names)`` of a status word (drivers name their bits)."""
        return f"{status:#010x}"

    def _begin_average(self) -> Any:
        """Discard what is waiting; return a token :meth:`_fresh` uses to keep only samples requested after."""
        self._take()
        return None

    def _fresh(self, batch: WrenchBatch, token: Any) -> WrenchBatch:
        return batch

    def _lost_between(self, before: SensorHealth, after: SensorHealth) -> int:
        return after.lost - before.lost

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> None:
        """Connect, read units and counts per unit, and start streaming. Raises DeviceError and subclasses."""
        if self._closed:
            raise DeviceError(f"{type(self).__name__}.start() after close(); make a new driver")
        if self._started:
            return
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Stop streaming and release sockets / the bus. Safe to call twice."""
        with self._lifecycle_lock:
            if self._closed:
                return
            self._closed = True
        self._shutdown()
        if self._thread_error is not None:
            raise DeviceError(f"{self.label}: driver thread failed: {self._thread_error!r}") from self._thread_error

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        if getattr(self, "_started", False) and not getattr(self, "_closed", True):
            warnings.warn(f"{self!r} was not closed", ResourceWarning, stacklevel=2)

    def _require_started(self) -> None:
        if not self._started or self._closed:
            raise DeviceError(f"{self!r}: call start() before reading (and not after close())")

    def _raise_if_dead(self) -> None:
        if self._thread_error is not None:
            raise DeviceError(f"{self.label}: driver thread failed: {self._thread_error!r}") from self._thread_error

    def _silence_message(self, timeout_s: float | None) -> str:
        health = self.health()
        return (f"no sample from the {self.label} within {timeout_s} s ({health.received} received so far, "
                f"{health.timeouts} timeouts, {health.reconnects} reconnects)")

    # ------------------------------------------------------------------ the contract

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
                raise DeviceTimeoutError(self._silence_message(timeout_s))
            self._wait_for_data(POLL_S if remaining is None else min(remaining, POLL_S))

    def average(self, duration_s: float, timeout_s: float | None = None) -> WrenchAverage:
        """Collect fresh samples for ``duration_s`` seconds and return their mean and sample standard deviation.

        Samples already waiting are discarded. Samples with an error status (saturation included) are excluded
        and counted in ``saturated``; ``lost`` counts samples lost during the window. Raises DeviceTimeoutError
        when no sample arrives by ``timeout_s`` (default duration + 1 s) and SensorFaultError when every sample
        was flagged.
        """
        self._require_started()
        check_range("duration_s", duration_s, 0.0, 3600.0)
        timeout_s = duration_s + AVERAGE_GRACE_S if timeout_s is None else timeout_s
        token = self._begin_average()
        before = self.health()
        start = time.monotonic()
        batches: list[WrenchBatch] = []
        fresh_count = 0
        while True:
            now = time.monotonic()
            if (now - start >= duration_s and fresh_count) or now - start >= timeout_s:
                break
            wait = min(max(start + duration_s - now, 0.0), start + timeout_s - now)
            try:
                batch = self._fresh(self.read(timeout_s=max(wait, 1e-3)), token)
            except DeviceTimeoutError:
                continue
            batches.append(batch)
            fresh_count += len(batch)
        batch = WrenchBatch.concatenate(batches)
        lost = self._lost_between(before, self.health())
        if len(batch) == 0:
            raise DeviceTimeoutError(f"no sample from the {self.label} within {timeout_s:.3g} s while averaging "
                                     f"({lost} lost)")
        good = ~batch.saturated
        count = int(good.sum())
        if count == 0:
            raise SensorFaultError(f"all {len(batch)} samples in the {duration_s} s window were saturated or had "
                                   f"an error status (last status {self.describe_status(int(batch.status[-1]))})")
        wrench = batch.wrench[good]
        return WrenchAverage(mean=wrench.mean(axis=0), std=wrench.std(axis=0, ddof=1) if count > 1 else np.zeros(6),
                             count=count, saturated=int(len(batch) - count), lost=int(lost),
                             duration_s=float(batch.time_s[-1] - batch.time_s[0]) if len(batch) > 1 else 0.0)


# ---------------------------------------------------------------------------- the registry

def _scheme(url: str) -> str:
    try:
        scheme = urlsplit(url).scheme
    except ValueError as error:
        raise InputError(f"sensor URL {url!r}: {error}") from None
    if scheme not in SENSOR_TYPES:
        forms = " or ".join(form for _, _, form in SENSOR_TYPES.values())
        raise InputError(f"sensor URL {url!r}: unknown scheme {scheme!r}; expected {forms}")
    return scheme


def sensor_class(url: str) -> type[SensorBase]:
    """Return the driver class for ``url``'s scheme (imported now). Raises InputError for an unknown scheme."""
    module_name, class_name, _ = SENSOR_TYPES[_scheme(url)]
    return getattr(importlib.import_module(module_name), class_name)


def parse_sensor_url(url: str) -> dict:
    """Check a sensor URL without touching the network (scheme, host or channel, every key and its range);
    return the driver's constructor arguments.

    Raises InputError naming the part of the URL that is wrong."""
    if not isinstance(url, str):
        raise InputError(f"sensor URL {url!r}: must be a string such as "
                         + " or ".join(form for _, _, form in SENSOR_TYPES.values()))
    cls = sensor_class(url)
    kwargs = cls.parse_url(url)
    cls.from_url(url)  # the constructor checks ranges and does no I/O
    return kwargs


def open_sensor(url: str, **options) -> ForceTorqueSensor:
    """Return an (unstarted) sensor driver for ``url``; ``options`` override the URL's keys.

    Raises InputError with the expected form when the URL cannot be parsed.
    """
    return sensor_class(url).from_url(url, **options)


__all__ = ["ForceTorqueSensor", "SensorBase", "SensorHealth", "SensorInfo", "WrenchAverage", "WrenchBatch",
           "SENSOR_TYPES", "open_sensor", "parse_sensor_url", "sensor_class", "check_range", "query_items",
           "STATUS_SUMMARY", "STATUS_SATURATION", "STATUS_MONITOR_LATCH", "STATUS_HEALTHY_MASK"]
