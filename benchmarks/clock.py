"""Benchmark: the host ↔ device clock mapping (ftacq/timebase.py) on synthetic arrivals, accuracy and CPU.

    .venv/bin/python benchmarks/clock.py [--minutes 10]

No sockets: the arrivals of tests/clock_arrivals.py (a 7 kHz sensor ±150 ppm off the host, bursts of 1-8 records
through a queue, 0-5 ms delays, 50-100 ms stalls, 1 % of the samples and a few 0.2 s runs skipped) read every 10 ms
(the monitor) and every 2 ms (the bridge), and the UR controller's packages of tests/fakes/drifting_link.py ±200 ppm
off, one at a time (the bridge's cycle states). Per minute of the run: the largest error of the mapped sample
times against the truth (the first 10 s left out: the mapping settles), and the CPU per read (``time.thread_time``,
which other jobs on a shared machine do not inflate as they do wall time).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftacq.timebase import DeviceClock, SampleClock  # noqa: E402
from tests.clock_arrivals import bursting_sensor, reads_of  # noqa: E402
from tests.fakes.drifting_link import MIN_DELAY_S, simulate  # noqa: E402

SETTLE_S = 10.0


def per_minute(device_s: np.ndarray, error_s: np.ndarray) -> str:
    minute = ((device_s - device_s[0]) // 60.0).astype(int)
    keep = device_s - device_s[0] >= SETTLE_S
    worst = [np.abs(error_s[keep & (minute == m)]).max() * 1e3 for m in range(minute.max() + 1)
             if np.any(keep & (minute == m))]
    return " ".join(f"{w:.3f}" for w in worst)


def sensor(minutes: float, rate_error: float, read_s: float) -> str:
    device, truth, arrival = bursting_sensor(60.0 * minutes, rate_error, seed=3)
    reads = [(arrival[r], device[r], r) for r in reads_of(arrival, read_s)]
    clock = SampleClock()
    mapped = np.empty_like(device)
    spent = time.thread_time()
    for stamps, times, rows in reads:
        mapped[rows] = clock.host_times(stamps, times)
    spent = time.thread_time() - spent
    late = (mapped - arrival).max()
    return (f"sensor {rate_error * 1e6:+.0f} ppm, {read_s * 1e3:.0f} ms reads: max |error| per minute (ms) "
            f"{per_minute(device, mapped - truth)}; later than arrival: {max(late, 0.0) * 1e3:.3f} ms; "
            f"{spent / len(reads) * 1e6:.1f} µs CPU per read; rate error found {clock.rate_error * 1e6:+.2f} ppm")


def controller(minutes: float, drift: float) -> str:
    link = simulate(drift, 60.0 * minutes, np.random.default_rng(11))
    clock = DeviceClock()
    stamps, arrivals = link.timestamp_s.tolist(), link.arrival_s.tolist()
    mapped = np.empty(len(stamps))
    spent = time.thread_time()
    for k, (stamp, arrival) in enumerate(zip(stamps, arrivals)):
        clock.observe_one(stamp, arrival)
        mapped[k] = clock.map_time(stamp)
    spent = time.thread_time() - spent
    error = mapped - (link.true_host_s + MIN_DELAY_S)
    return (f"controller {drift * 1e6:+.0f} ppm, one package at a time: max |error| per minute (ms) "
            f"{per_minute(link.timestamp_s, error)}; {spent / len(stamps) * 1e6:.1f} µs CPU per package")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    args = parser.parse_args()
    for rate_error in (150e-6, -150e-6):
        print(sensor(args.minutes, rate_error, 0.01))
    print(sensor(args.minutes, 150e-6, 0.002))
    for drift in (200e-6, -200e-6):
        print(controller(args.minutes, drift))
    return 0


if __name__ == "__main__":
    sys.exit(main())
