"""Micro-benchmark: the bridge's per-cycle log over a long run, the feed thread's side (procedures/bridge.py
``_Log.row``), beside the peer it replaced: one array grown by doubling (as before, preallocated for a minute).

    .venv/bin/python benchmarks/bridge_log.py              # 20 minutes of 500 Hz cycles
    .venv/bin/python benchmarks/bridge_log.py --minutes 60

Each call is timed with ``time.perf_counter``; the figure is the slowest calls and when in the run they came
(wall time of the calling thread: a copy inside the feed thread holds the controller's next cycles back for
that long; UR's own watchdog on the input pauses the program after 0.1 s without a new value). Also the memory
each keeps at the end.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RATE_HZ = 500.0


class DoublingLog:
    """The peer: the log as it was until this benchmark was written (one array; when full, a new one twice the
    size, filled with NaN, and the old rows copied in)."""

    def __init__(self, capacity: int, width: int) -> None:
        self.data = np.full((max(capacity, 1024), width), np.nan)
        self.count = 0

    def row(self) -> np.ndarray:
        if self.count == len(self.data):
            self.data = np.concatenate([self.data, np.full_like(self.data, np.nan)])
        row = self.data[self.count]
        self.count += 1
        return row

    def nbytes(self) -> int:
        return self.data.nbytes


def run(log, cycles: int) -> np.ndarray:
    times = np.empty(cycles)
    clock = time.perf_counter
    for i in range(cycles):
        start = clock()
        log.row()[0] = i
        times[i] = clock() - start
    return times


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=20.0, help="run length, minutes of 500 Hz cycles")
    args = parser.parse_args()
    from procedures.bridge import LOG_COLUMNS, LOG_KEEP_S, _Log

    cycles = int(args.minutes * 60 * RATE_HZ)
    print(f"bridge per-cycle log: {cycles} rows ({args.minutes:g} min at {RATE_HZ:g} Hz), {len(LOG_COLUMNS)} columns")
    chunked = _Log(int(LOG_KEEP_S * RATE_HZ))
    doubling = DoublingLog(int(60 * RATE_HZ * 1.2) + 1024, len(LOG_COLUMNS))
    for label, log in (("chunked (procedures/bridge.py)", chunked), ("doubling (the peer, as before)", doubling)):
        times = run(log, cycles)
        slowest = np.argsort(times)[::-1][:4]
        kept_mb = (sum(chunk.nbytes for chunk in chunked._kept[1]) if log is chunked else doubling.nbytes()) / 1e6
        print(f"  {label:32s} row() p50 {np.median(times) * 1e6:.2f} µs, calls over 1 ms {np.count_nonzero(times > 1e-3)}, "
              f"slowest {', '.join(f'{times[i] * 1e3:.1f} ms at {i / RATE_HZ / 60:.1f} min' for i in slowest)}; "
              f"kept {kept_mb:.0f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
