"""Thinning a sample stream for a file: keep every k-th sample so that an hour fits a size budget.

The live dashboard shows every sample; what a long run writes to disk (``ftacq monitor --record`` CSV, ``--save``
.rrd) keeps every k-th, k chosen from the sensor's rate, the file's bytes per sample and the budget
(:func:`every_for`), unless the user names a rate. :class:`Decimator` keeps the phase across batches, so the kept
samples are evenly spaced however the driver batches them (numpy index arrays, no per-sample Python work).
"""

from __future__ import annotations

import math

import numpy as np

DEFAULT_BUDGET_BYTES_PER_H = 1.0e9
"""What one file of a long recording may grow by per hour, by default (1 GB/h)."""
CSV_BYTES_PER_SAMPLE = 290.0
"""A ``monitor --record`` CSV row with a robot and a calibration (25 columns), bytes (7 kHz, 20 s: 40 MB)."""
RRD_BYTES_PER_SAMPLE = 165.0
"""A saved dashboard recording per sensor sample (raw and compensated wrench, the arm, health), bytes (7 kHz,
20 s: 22.8 MB)."""


def every_for(sensor_rate_hz: float, bytes_per_sample: float, rate_hz: float | None = None,
              budget_bytes_per_h: float = DEFAULT_BUDGET_BYTES_PER_H) -> int:
    """Return k (keep every k-th sample): for ``rate_hz`` (samples per second to keep; 0 = every sample) when
    given, else the smallest k whose file fits ``budget_bytes_per_h``."""
    if not sensor_rate_hz or sensor_rate_hz <= 0:
        return 1
    if rate_hz is not None:
        return 1 if rate_hz <= 0 else max(1, math.ceil(sensor_rate_hz / rate_hz - 1e-9))
    return max(1, math.ceil(sensor_rate_hz * bytes_per_sample * 3600.0 / budget_bytes_per_h - 1e-9))


def size_text(sensor_rate_hz: float, every: int, bytes_per_sample: float) -> str:
    """Return e.g. "every 8th sample (875 of 7000 per s), about 0.91 GB/h"."""
    kept = sensor_rate_hz / every
    which = "every sample" if every == 1 else f"every {every}{_ordinal(every)} sample"
    return f"{which} ({kept:.0f} of {sensor_rate_hz:.0f} per s), about {kept * bytes_per_sample * 3600 / 1e9:.2g} GB/h"


def _ordinal(n: int) -> str:
    return "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")


class Decimator:
    """Keeps every ``every``-th sample of a stream that arrives in batches (the first sample of the stream, then
    every ``every``-th after it, across batch boundaries)."""

    def __init__(self, every: int = 1) -> None:
        self.every = max(1, int(every))
        self._seen = 0

    def keep(self, count: int) -> np.ndarray:
        """Return the indices (into a batch of ``count`` samples) to keep."""
        first = (-self._seen) % self.every
        self._seen += count
        return np.arange(first, count, self.every)


__all__ = ["DEFAULT_BUDGET_BYTES_PER_H", "CSV_BYTES_PER_SAMPLE", "RRD_BYTES_PER_SAMPLE", "Decimator", "every_for",
           "size_text"]
