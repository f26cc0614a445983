"""A probe of the machine's own scheduling stalls, run beside a timing benchmark (benchmarks/bridge.py).

    .venv/bin/python benchmarks/stall_probe.py [--period-ms 0.5] [--priority 99]

One thread at SCHED_FIFO ``--priority`` (where allowed) wakes every ``--period-ms`` on CLOCK_MONOTONIC until stdin
closes, then prints one JSON line: the wake-ups later than :data:`REPORT_LATE_S` as [scheduled time s, lateness s],
the number of wake-ups, its scheduling. A real-time thread that does nothing else is late only when the machine
itself did not run it (another real-time thread, interrupts, or, in a virtual machine, the host taking the virtual
CPU away: "steal"). A cycle missed by the bridge while the probe was stalled is the machine's, not the code's. The
peer for the same figure is rt-tests' ``cyclictest`` (benchmarks/timer.py prints both).
"""

from __future__ import annotations

import argparse
import json
import os
import select
import sys
import threading
import time

REPORT_LATE_S = 0.0005


def probe(period_s: float, stop: threading.Event, late: list[list[float]], counter: list[int]) -> None:
    """Wake every ``period_s`` until ``stop``; keep the wake-ups later than REPORT_LATE_S."""
    due = time.monotonic()
    n = 0
    while not stop.is_set():
        due += period_s
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        lateness = time.monotonic() - due
        n += 1
        if lateness > REPORT_LATE_S:
            late.append([due, lateness])
            if lateness > period_s:
                due = time.monotonic()  # a stall: start again from now, one record for the whole stall
    counter.append(n)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--period-ms", type=float, default=0.5)
    parser.add_argument("--priority", type=int, default=99)
    args = parser.parse_args()
    scheduling = "normal"
    if args.priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.priority))
            scheduling = f"SCHED_FIFO {args.priority}"
        except (OSError, AttributeError) as error:
            scheduling = f"normal (SCHED_FIFO refused: {error})"
    stop, late, counter = threading.Event(), [], []
    thread = threading.Thread(target=probe, args=(args.period_ms / 1000.0, stop, late, counter), daemon=True)
    print(json.dumps({"ready": True, "scheduling": scheduling}), flush=True)
    thread.start()
    while True:  # until the benchmark closes our stdin
        ready, _, _ = select.select([sys.stdin], [], [], 1.0)
        if ready and not sys.stdin.readline():
            break
    stop.set()
    thread.join(1.0)
    print(json.dumps({"late": late, "wakeups": counter[0] if counter else 0, "scheduling": scheduling,
                      "period_s": args.period_ms / 1000.0}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
