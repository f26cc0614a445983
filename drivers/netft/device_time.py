"""The Net F/T's own sample time: its sample counter ``ft_sequence`` over the box's internal rate. Pure: no sockets.

``ft_sequence`` (docs/protocols-ati.md, "RDT sequences") counts the box's internal samples (7000 a second, +n per
record at ``comrdtrate`` = 7000/n Hz), runs on across streams (a start or a bias does not reset it) and restarts only
when the box powers up. Unlike ``rdt_sequence`` it counts the samples the host never received, so a sample's device
time ``ft_sequence / internal rate`` shows a skipped sample as a gap instead of compressing the clock, and it is the
clock the host ↔ device mapping (:class:`ftacq.timebase.DeviceClock`) follows.

The 32-bit counter wraps after 7.1 days at 7 kHz: :class:`SampleCounterClock` unwraps it by the signed difference
(mod 2³²) between consecutive records, so a wrap is a step forward; a power cycle (the counter back near zero) is a
step back by the box's whole uptime, which the mapping takes as a restart.
"""

from __future__ import annotations

import numpy as np

from drivers.netft.protocol import HALF_RANGE, INTERNAL_RATE_HZ, UINT32_MASK


class SampleCounterClock:
    """Device times (s) of records from their ``ft_sequence``, in delivery order (one reader thread).

    Args: internal_rate_hz (the box's ``runrate``, Hz: the counter's rate)."""

    def __init__(self, internal_rate_hz: float = INTERNAL_RATE_HZ) -> None:
        self.internal_rate_hz = float(internal_rate_hz)
        self._last_raw: int | None = None
        self._last_count = 0
        """The unwrapped counter of the last record (an int: exact however long the box runs)."""

    def device_times(self, ft_sequence: np.ndarray) -> np.ndarray:
        """Return the records' device times (N,), s: the unwrapped counter over the internal rate."""
        raw = np.asarray(ft_sequence, dtype=np.int64)
        if raw.size == 0:
            return np.empty(0)
        first, last = int(raw[0]), int(raw[-1])
        if self._last_raw is not None and 0 <= first - self._last_raw < HALF_RANGE and 0 <= last - first < HALF_RANGE:
            # the usual batch: no wrap from the last record nor inside the batch (a step back inside it stays signed)
            start = self._last_count + first - self._last_raw
            counts = raw - first
            counts += start
            self._last_raw, self._last_count = last, int(counts[-1])
            return counts / self.internal_rate_hz
        previous = first if self._last_raw is None else self._last_raw
        steps = np.diff(raw, prepend=previous)
        steps &= UINT32_MASK
        steps[steps >= HALF_RANGE] -= 1 << 32  # signed steps: a wrap is forward, an older record backward
        if self._last_raw is None:
            self._last_count = int(raw[0])
        counts = np.cumsum(steps)
        counts += self._last_count
        self._last_raw, self._last_count = int(raw[-1]), int(counts[-1])
        return counts / self.internal_rate_hz
