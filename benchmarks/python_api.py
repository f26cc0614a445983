"""Benchmark: CPU of the Python API's stream (``ftacq.open_cell``, ftacq/app/session.py) against the simulated cell.

    .venv/bin/python benchmarks/python_api.py [--seconds 10]

The simulated cell (UR5e controller and Net F/T at 7 kHz, their own processes), the arm still, its true calibration
(static compensation, the drift tracker). The same stream read two ways, each in a cell of its own after a 1 s
warm-up: ``cell.batches()`` (the caller's thread reads, a ``Batch`` per read) and the loop of ``cell.run()`` (what
``ftacq monitor`` does, here without listeners). Prints samples per second and this process's CPU (``time.process_time``: the
driver's receive thread, the state reader and stream, the monitor) as a share of one core. Figures in
benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import ftacq  # noqa: E402


def measure(mode: str, seconds: float) -> tuple[float, float]:
    """(samples per second, CPU % of one core) over ``seconds`` of the stream read by ``mode``."""
    with ftacq.open_cell(sim=True) as cell:
        list(cell.batches(seconds=1.0))  # warm-up: the first read holds what the driver buffered since the start
        counted = cell.summary.samples
        cpu_s, wall_s = time.process_time(), time.monotonic()
        if mode == "batches":
            samples = sum(len(batch) for batch in cell.batches(seconds=seconds))
        else:  # the loop cell.run() runs (LiveMonitor.stream), timed without the closing that follows it
            cell.monitor.stream(seconds)
            samples = cell.summary.samples - counted
        cpu_s, wall_s = time.process_time() - cpu_s, time.monotonic() - wall_s
    return samples / wall_s, 100.0 * cpu_s / wall_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f}")
    for mode in ("batches", "run"):
        rate_hz, cpu = measure(mode, args.seconds)
        print(f"cell.{mode}(): {rate_hz:.0f} samples/s, CPU {cpu:.1f} % of one core")


if __name__ == "__main__":
    main()
