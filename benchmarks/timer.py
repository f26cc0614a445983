"""Benchmark: can this machine hold a 2 ms real-time cycle at all? The floor under every bridge figure.

    .venv/bin/python benchmarks/timer.py [--seconds 30] [--period-ms 2] [--priority 95]

A Python thread at SCHED_FIFO ``--priority`` (where allowed) sleeps to each 2 ms deadline on CLOCK_MONOTONIC and
records how late it woke; beside it, the peer for the same measurement, rt-tests' ``cyclictest`` (C, mlockall), when
it is on PATH (Debian: ``apt install rt-tests``). Run it with nothing else on the machine. A wake-up later than one
period is a cycle that no program on this machine could have fed: on a virtual machine whose host takes the virtual
CPU away ("steal"), that floor is not zero.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time

import numpy as np


def python_lateness_s(seconds: float, period_s: float, priority: int) -> tuple[np.ndarray, str]:
    """Lateness (s) of each wake-up of this thread, and how it was scheduled."""
    scheduling = "normal"
    if priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            scheduling = f"SCHED_FIFO {priority}"
        except (OSError, AttributeError) as error:
            scheduling = f"normal (SCHED_FIFO refused: {error})"
    n = int(seconds / period_s)
    late = np.empty(n)
    due = time.monotonic()
    for i in range(n):
        due += period_s
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        late[i] = time.monotonic() - due
    if priority > 0 and scheduling.startswith("SCHED_FIFO"):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return late, scheduling


def cyclictest_lateness_us(seconds: float, period_s: float, priority: int) -> np.ndarray | None:
    """cyclictest's histogram (µs) expanded to one lateness per wake-up, or None when it is not installed."""
    if shutil.which("cyclictest") is None:
        return None
    loops = int(seconds / period_s)
    out = subprocess.run(["cyclictest", "-m", "-q", "-p", str(priority), "-i", str(int(period_s * 1e6)), "-l",
                          str(loops), "-h", "100000"], capture_output=True, text=True, timeout=seconds * 2 + 30).stdout
    values, counts = [], []
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0].isdigit() and int(parts[1]) > 0:
            values.append(int(parts[0]))
            counts.append(int(parts[1]))
    return np.repeat(np.array(values, dtype=float), counts) if values else None


def summary(label: str, late_ms: np.ndarray, period_ms: float, seconds: float) -> str:
    over = int(np.sum(late_ms > period_ms))
    return (f"  {label}: p50 {np.percentile(late_ms, 50):.3f} ms, p99 {np.percentile(late_ms, 99):.3f} ms, p99.9 "
            f"{np.percentile(late_ms, 99.9):.3f} ms, max {late_ms.max():.2f} ms; {int(np.sum(late_ms > 1.0))} wake-ups "
            f"> 1 ms late, {over} > one period ({over * 60.0 / seconds:.0f} a minute)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--period-ms", type=float, default=2.0)
    parser.add_argument("--priority", type=int, default=95)
    args = parser.parse_args()
    period_s = args.period_ms / 1000.0
    print(f"timer lateness, {args.period_ms:g} ms period, {args.seconds:g} s each, load average "
          f"{os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    late, scheduling = python_lateness_s(args.seconds, period_s, args.priority)
    print(summary(f"Python thread, {scheduling}", late * 1000.0, args.period_ms, args.seconds))
    peer = cyclictest_lateness_us(args.seconds, period_s, args.priority)
    if peer is None:
        print("  cyclictest: not on PATH (rt-tests), no peer figure")
    else:
        print(summary(f"cyclictest -m -p {args.priority} (C)", peer / 1000.0, args.period_ms, args.seconds))
    return 0


if __name__ == "__main__":
    sys.exit(main())
