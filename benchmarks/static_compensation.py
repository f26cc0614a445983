"""Benchmark: the live static compensation at the samples' time (procedures/static_compensation.py), CPU per read.

    .venv/bin/python benchmarks/static_compensation.py [--seconds 30] [--behind 0.1]

No sockets: the monitor's reads as they come at 7 kHz (70 samples every 10 ms, the sensor's own clock) and the
controller's 500 Hz states (procedures.bridge.CycleStates, on the host clock as the RTDE stream puts them) of an arm
turning on every joint; each read is compensated when the state stream is ``--behind`` s further (a monitor that
fell behind: more rows to read, the same work per sample). Prints the CPU per read (median, mean, p99 of
``time.process_time`` around ``compensate``; the record's per-sample pose apart) and the share of one core at 100
reads per second, beside the newest-pose compensation it replaced (one ``Calibration.compensate`` with one
rotation). Figures in benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.sensor import WrenchBatch  # noqa: E402
from drivers.ur_ft_input import ControllerCycle  # noqa: E402
from ftacq.kinematics import flange_pose, ur_model  # noqa: E402
from procedures.bridge import CycleStates  # noqa: E402
from procedures.monitor import flange_R_base_from_pose  # noqa: E402
from procedures.static_compensation import StaticCompensator  # noqa: E402
from tests.fakes.world import CellTruth  # noqa: E402

RATE_HZ, BATCH, STATE_PERIOD_S = 7000.0, 70, 0.002
PERIODS_S = np.array([1.7, 1.3, 1.9, 0.9, 0.7, 1.1])


def joint_angles(t: float) -> np.ndarray:
    return np.array([0.1, -1.2, 1.0, -1.4, -1.6, 0.2]) + 0.6 * np.sin(2 * np.pi * t / PERIODS_S)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="data compensated, s (default 30)")
    parser.add_argument("--behind", type=float, default=0.1, help="the state stream is this far ahead, s")
    args = parser.parse_args()
    model = ur_model("UR5e")
    calibration = CellTruth().calibration()
    states = CycleStates(capacity=4096)
    compensator = StaticCompensator(calibration, model, states)
    reads = int(args.seconds * RATE_HZ / BATCH)
    rng = np.random.default_rng(1)
    next_state = 0
    costs, pose_costs, newest_costs = np.empty(reads), np.empty(reads), np.empty(reads)
    for k in range(reads):
        device = (k * BATCH + np.arange(BATCH)) / RATE_HZ
        while next_state * STATE_PERIOD_S <= device[-1] + args.behind:
            t = next_state * STATE_PERIOD_S
            states.append(ControllerCycle(timestamp_s=t, q=joint_angles(t), qd=np.zeros(6), tcp_force=np.zeros(6),
                                          runtime_state=2, safety_status_bits=1, received_s=100.0 + t + 2e-4,
                                          tcp_pose=np.zeros(6), target_qd=np.zeros(6), target_qdd=np.zeros(6)))
            next_state += 1
        batch = WrenchBatch(time_s=100.0 + device + 2e-4 + rng.exponential(1e-4, BATCH), wrench=rng.normal(size=(BATCH, 6)),
                            counts=np.zeros((BATCH, 6), dtype=np.int64), status=np.zeros(BATCH, dtype=np.uint32),
                            sequence=np.arange(BATCH, dtype=np.int64), saturated=np.zeros(BATCH, dtype=bool),
                            device_time_s=device)
        start = time.process_time()
        out = compensator.compensate(batch)
        middle = time.process_time()
        compensator.sample_flange_pose()
        costs[k], pose_costs[k] = middle - start, time.process_time() - middle
        assert out is not None
        start = time.process_time()
        calibration.compensate(batch.wrench, flange_R_base_from_pose(flange_pose(model, states.window(last=1).q[-1])))
        newest_costs[k] = time.process_time() - start
    settled = costs[reads // 10:]
    print(f"{reads} reads of {BATCH} samples, states {args.behind * 1e3:.0f} ms ahead; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"at the samples' time: median {np.median(settled) * 1e6:.0f} µs, mean {settled.mean() * 1e6:.0f} µs, "
          f"p99 {np.percentile(settled, 99) * 1e6:.0f} µs per read = {settled.mean() * 100 * 100:.1f} % of one core "
          f"at 100 reads/s; forward kinematics {compensator.orientations.computed} of {next_state} states")
    pose = pose_costs[reads // 10:]
    print(f"the record's pose per sample (--record only): median {np.median(pose) * 1e6:.0f} µs, "
          f"mean {pose.mean() * 1e6:.0f} µs per read")
    newest = newest_costs[reads // 10:]
    print(f"newest pose (before): median {np.median(newest) * 1e6:.0f} µs, mean {newest.mean() * 1e6:.0f} µs")


if __name__ == "__main__":
    main()
