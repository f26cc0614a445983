"""The force/torque sensor contract every transport implements, and the URL factory.

Samples travel in numpy batches (:class:`WrenchBatch`), never one Python object per sample: at 7 kHz on two
cores a per-sample object costs more than the protocol itself.

Sensors are named by URL:

- ``netft://HOST[:RDT_PORT][?tcp_port=N&http_port=N&rate_hz=R&buffered=0&buffer_size=N&timeout_s=T]`` — ATI Net F/T
  (defaults 49152, 49151, 80; more keys in :mod:`drivers.netft`)
- ``can://INTERFACE/CHANNEL[?base=0x20&bitrate=250000]`` — ATI NETCANOEM on a python-can bus
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable
from urllib.parse import urlsplit

import numpy as np

from ftacq.errors import InputError

# Net F/T status word bits (specs/ati.md §1.8)
STATUS_SUMMARY = 0x8000_0000
STATUS_SATURATION = 0x0002_0000
STATUS_MONITOR_LATCH = 0x0001_0000
STATUS_HEALTHY_MASK = STATUS_SUMMARY | STATUS_MONITOR_LATCH
"""A status whose bits all lie in this mask is healthy (0, or the informational latch 0x80010000)."""


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
    """

    time_s: np.ndarray
    wrench: np.ndarray
    counts: np.ndarray
    status: np.ndarray
    sequence: np.ndarray
    saturated: np.ndarray

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

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
    """Counters of what a stream did wrong since the driver started (all monotonic counts)."""

    received: int = 0
    lost: int = 0
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

    def close(self) -> None:
        """Stop streaming and release sockets / the bus. Safe to call twice."""


def open_sensor(url: str, **options) -> ForceTorqueSensor:
    """Return an (unstarted) sensor driver for ``url`` (see the module docstring for the URL forms).

    Raises InputError with the expected form when the URL cannot be parsed.
    """
    parts = urlsplit(url)
    if parts.scheme == "netft":
        from drivers.netft import NetFTSensor

        return NetFTSensor.from_url(url, **options)
    if parts.scheme == "can":
        from drivers.ati_can import AtiCanSensor

        return AtiCanSensor.from_url(url, **options)
    raise InputError(
        f"sensor URL {url!r}: unknown scheme {parts.scheme!r}; expected "
        "netft://HOST[:RDT_PORT][?tcp_port=N&http_port=N] or can://INTERFACE/CHANNEL[?base=0x20&bitrate=250000]"
    )
