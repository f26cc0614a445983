"""Benchmark: the CPU each read costs ``ftacq monitor``'s loop, with and without ``--ros2``, by stage.

    .venv/bin/python benchmarks/monitor_read.py            # 8 s per run
    .venv/bin/python benchmarks/monitor_read.py --seconds 4 --ros2-only

The cell is benchmarks/ros2.py's (the simulated UR controller and Net F/T at 7 kHz each in their own process, the
arm still; ``ftacq monitor --config CELL.toml --calibration CAL.json``: dynamic compensation, drift tracking) and the
monitor runs in this process. Each stage of the loop is wrapped here and timed on the acquisition thread's CPU
clock (``time.thread_time``: what the thread spent, not what it waited or was preempted), µs per read, p50 and mean:

- read: the sensor's ``read`` (the samples decoded; its wait for data is not CPU);
- compensate: the compensator (dynamic model, flange orientation) and the drift tracker with its stillness check
  (``still`` on its own);
- published: the listeners' hand-over (with ``--ros2`` the ROS 2 messages and their DDS writes);
- clock: the samples' times on the host clock (ftacq.timebase.SampleClock);
- checks: the health checks (the drift tracker's events); periodic: the arm's and the stream's periodic events;
- step: the whole read (the above and the record's hand-over).

A stage's p99 and max show work that lands on some reads only (a refit, a periodic event).

Reads per second are the loop's rate: ``--ros2`` reads on data (ftacq.app.ros2_outputs.ROS2_READ_PERIOD_S), more
and smaller reads than the 10 ms period without it, so a fixed cost per read weighs more.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
import tempfile
import time
import uuid
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

STAGES = ("step", "read", "clock", "compensate", "still", "published", "checks", "periodic")


@contextlib.contextmanager
def timed_stages():
    """Wrap the loop's stages (module docstring); yield {stage: [thread CPU µs per call]}."""
    from drivers.sensor import SensorBase
    from procedures.bias_health import DriftCompensator
    from procedures.delivery import Fanout
    from procedures.dynamic_compensation import DynamicCompensator
    from ftacq.timebase import SampleClock
    from procedures.monitor import LiveMonitor

    cpu: dict[str, list[float]] = defaultdict(list)
    patches = [(LiveMonitor, "step", "step"), (SensorBase, "read", "read"), (SampleClock, "host_times", "clock"),
               (DriftCompensator, "compensate", "compensate"), (DynamicCompensator, "still_over", "still"),
               (Fanout, "__call__", "published"), (LiveMonitor, "_run_checks", "checks"),
               (LiveMonitor, "_publish_periodic", "periodic")]
    originals = [getattr(owner, name) for owner, name, _ in patches]

    def timed(function, stage):
        times = cpu[stage]

        def wrapper(*args, **kwargs):
            start = time.thread_time_ns()
            try:
                return function(*args, **kwargs)
            finally:
                times.append((time.thread_time_ns() - start) / 1e3)
        return wrapper

    try:
        for (owner, name, stage), original in zip(patches, originals):
            setattr(owner, name, timed(original, stage))
        yield cpu
    finally:
        for (owner, name, _), original in zip(patches, originals):
            setattr(owner, name, original)


def run(cell_args: list[str], seconds: float, ros2: bool, folder: Path) -> dict[str, list[float]]:
    """One ``ftacq monitor`` run (its viewer recording in ``folder``); the CPU µs of each stage per call."""
    from drivers.ros2.node import LOCALHOST_CONFIG
    from ftacq.app.cli import main as ftacq_main

    command = ["monitor", *cell_args, "--seconds", str(seconds), "--save", str(folder / f"{uuid.uuid4().hex[:6]}.rrd")]
    if ros2:
        token = uuid.uuid4()
        command += ["--ros2", "--ros2-domain-id", str(1 + token.int % 200), "--ros2-namespace", f"/m{token.hex[:8]}"]
        os.environ["CYCLONEDDS_URI"] = LOCALHOST_CONFIG
    out = io.StringIO()
    with timed_stages() as cpu, contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = ftacq_main(command)
    if code != 0:
        raise SystemExit(f"ftacq monitor exited {code}: {out.getvalue()[-2000:]}")
    return {stage: list(values) for stage, values in cpu.items()}


def main() -> None:
    from ros2 import cell_outside

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--ros2-only", action="store_true", help="only the run with --ros2")
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.1f}; {args.seconds:g} s per run")
    with tempfile.TemporaryDirectory() as folder, cell_outside(Path(folder)) as cell_args:
        for ros2 in ([True] if args.ros2_only else [False, True]):
            cpu = run(cell_args, args.seconds, ros2, Path(folder))
            steps = np.array(cpu["step"][5:])  # the first reads hold the start-up's backlog
            print(f"{'--ros2' if ros2 else 'without --ros2'}: {len(steps) / args.seconds:.0f} reads/s, loop CPU "
                  f"{steps.sum() / 1e4 / args.seconds:.1f} % of one core; µs of CPU per call, p50 / mean / p99 / max:")
            for stage in STAGES:
                values = np.array(cpu.get(stage, [0.0])[5:] or [0.0])
                print(f"  {stage:11s} {np.median(values):7.0f} / {values.mean():7.0f} / "
                      f"{np.percentile(values, 99):7.0f} / {values.max():7.0f}")
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
