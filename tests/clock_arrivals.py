"""Synthetic arrivals of a sensor with its own clock: numpy arrays, no sockets (tests/test_device_clock.py,
benchmarks/clock.py).

A 7 kHz sensor whose crystal runs ``rate_error`` off the host's sends its records in bursts through a queue, with
random delays and stalls, and some samples never arrive; :func:`reads_of` groups the arrivals into the batches a
driver read every 10 ms returns.
"""

from __future__ import annotations

import numpy as np

SENSOR_RATE_HZ = 7000.0


def bursting_sensor(duration_s: float, rate_error: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(device times, true host times, arrival stamps) of a 7 kHz sensor whose clock runs ``rate_error`` off the
    host's: records go out in bursts of 1-8 (each sent when its last sample is taken), travel 0-5 ms (uniform) and
    now and then 50-100 ms more (a stall), through a queue (nothing overtakes); 1 % of the samples and a few runs of
    up to 0.2 s are never received (skipped: gaps in device time)."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * SENSOR_RATE_HZ)
    device = np.arange(n) / SENSOR_RATE_HZ + 3.0
    true_host = 7000.0 + device * (1.0 + rate_error)
    ends = np.cumsum(rng.integers(1, 9, n))
    ends = ends[ends < n]
    burst = np.searchsorted(ends, np.arange(n), side="right")  # the burst each sample goes out in
    last = np.append(ends, n)[burst] - 1  # the burst's last sample: when it is sent
    delay = rng.uniform(0.0, 0.005, burst[-1] + 1)
    stalled = rng.random(delay.size) < 0.002
    delay[stalled] += rng.uniform(0.05, 0.1, int(stalled.sum()))
    arrival = np.maximum.accumulate(true_host[last] + delay[burst])
    kept = rng.random(n) > 0.01
    for start in rng.integers(0, n - 1500, 20):
        kept[start:start + int(rng.integers(10, 1500))] = False
    return device[kept], true_host[kept], arrival[kept]


def reads_of(arrival: np.ndarray, period_s: float = 0.01) -> list[np.ndarray]:
    """The samples each 10 ms read of the driver returns (those arrived since the last read)."""
    bounds = np.flatnonzero(np.diff(np.floor(arrival / period_s))) + 1
    return np.split(np.arange(arrival.size), bounds)
