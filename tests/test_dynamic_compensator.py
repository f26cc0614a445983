"""The live dynamic compensation's per-batch shortcuts give what the straightforward computation gives.

procedures/dynamic_compensation.py keeps the sensor clock's sums and envelope candidates between reads: compared
here, bit for bit, with a plain version of what it replaced.
"""

from __future__ import annotations

import numpy as np
import pytest

from procedures.dynamic_compensation import ENVELOPE_READS, PERIOD_FIT_SPAN_S, SensorClock


class PlainSensorClock:
    """The sensor clock as every read evaluated it before: sums in an array, all candidates re-evaluated."""

    def __init__(self, nominal_period_s: float | None) -> None:
        self.nominal = nominal_period_s
        self.restart()

    def restart(self) -> None:
        self.origin: tuple[float, float] | None = None
        self.sums = np.zeros(5)
        self.points = np.empty((ENVELOPE_READS, 2))
        self.count = 0
        self.last = -np.inf

    def host_times(self, arrival: np.ndarray, sequence: np.ndarray) -> np.ndarray:
        seq = np.asarray(sequence, dtype=float)
        if np.any(np.diff(seq) <= 0):
            return arrival
        if self.origin is not None and seq[0] - self.origin[0] <= self.last:
            self.restart()
        if self.origin is None:
            self.origin = (float(seq[0]), float(arrival[0]))
        s, a = seq - self.origin[0], arrival - self.origin[1]
        self.last = float(s[-1])
        self.sums += (s.size, s.sum(), a.sum(), (s * s).sum(), (s * a).sum())
        n, ss, sa, sss, ssa = self.sums
        if self.nominal is not None and self.last * self.nominal < PERIOD_FIT_SPAN_S:
            period = self.nominal
        else:
            denominator = n * sss - ss * ss
            if n < 50 or denominator <= 0:
                return arrival
            period = (n * ssa - ss * sa) / denominator
        best = int(np.argmin(a - s * period))
        self.points[self.count % ENVELOPE_READS] = s[best], a[best]
        self.count += 1
        points = self.points[:min(self.count, ENVELOPE_READS)]
        return self.origin[1] + s * period + float(np.min(points[:, 1] - points[:, 0] * period))


def sensor_reads(seconds: float, seed: int, restart_at_s: float | None = None):
    """(arrival, sequence) reads of 10-18 samples at 7 kHz with a jittered, coalesced arrival (and a restart)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * 7000)
    sequence = np.arange(n) + 17
    arrival = 500.0 + sequence / 7000.0 * (1 + 3e-5) + 0.0003 + rng.exponential(0.0004, n)
    arrival = np.maximum.accumulate(arrival)
    if restart_at_s is not None:
        k = int(restart_at_s * 7000)
        sequence[k:] -= sequence[k] - 1
    reads, i = [], 0
    while i < n:
        size = int(rng.integers(10, 19))
        reads.append((arrival[i:i + size].copy(), sequence[i:i + size].copy()))
        i += size
    return reads


@pytest.mark.parametrize("nominal", [1 / 7000, None])
def test_sensor_clock_gives_the_plain_evaluation_bit_for_bit(nominal):
    # 14 s: the nominal period, then the least-squares one (PERIOD_FIT_SPAN_S), with a restarted count at 12 s
    reads = sensor_reads(14.0, seed=2, restart_at_s=12.0)
    clock, plain = SensorClock(True, nominal), PlainSensorClock(nominal)
    for arrival, sequence in reads:
        np.testing.assert_array_equal(clock.host_times(arrival, sequence), plain.host_times(arrival, sequence))
