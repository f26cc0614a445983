"""Benchmark: the monitor's per-read compensation and ROS 2 messages in a scripted replay (no devices, no threads).

    .venv/bin/python benchmarks/monitor_replay.py                 # thread CPU and calls per read
    .venv/bin/python benchmarks/monitor_replay.py --save a.npz    # also the outputs, to compare two trees bit for bit
    .venv/bin/python benchmarks/monitor_replay.py --compare a.npz b.npz

What ``ftacq monitor --ros2`` does per read after the sensor's decode, on a deterministic script: reads of 14 samples
(a 2 ms burst of a 7 kHz Net F/T) with one new 500 Hz robot state each (procedures.bridge.CycleStates, the host
clock as the RTDE stream puts it), the arm moving, then still for 4 s (stillness verdicts both ways), then moving;
per read the drift compensator (dynamic compensation, stillness, the drift tracker every 10 ms) and the 1 kHz
wrench messages (window means, CDR bytes). Prints thread CPU per read (µs, p50 / mean: the machine's load moves
it, so compare two trees in turn) and calls per read (Python functions and C functions, numpy's included: the
work itself, whatever the load). ``--servo-lag-ms``: the arm follows its target this late (q̈ interpolated).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

READS = 5800
SAMPLES_PER_READ = 14
STILL_READS = (2300, 4300)


def replay(servo_lag_s: float, count_calls: bool = False) -> dict:
    """Run the script; return the outputs, thread CPU µs per read and calls per read."""
    from drivers.sensor import WrenchBatch
    from ftacq.drift_health import BiasHealth
    from ftacq.kinematics import ur_model
    from procedures import events
    from procedures.bias_health import DriftCompensator
    from procedures.bridge import CycleStates
    from procedures.dynamic_compensation import DynamicCompensator
    from procedures.ros2_stream import Ros2Messages
    from tests.fakes.world import CellTruth
    from tests.test_dynamic_compensator import cycles

    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m), inertia=truth.inertia)
    states = CycleStates(capacity=4096)
    compensator = DynamicCompensator(calibration, ur_model("UR5e"), states, servo_lag_s=servo_lag_s)
    drift = DriftCompensator(BiasHealth(calibration), moving=compensator)
    messages = Ros2Messages("ft_sensor", 1000.0, sample_period_s=lambda: 1 / 7000)
    messages.clock.offset_s = 1.7e9
    rng = np.random.default_rng(0)
    script = list(cycles(READS + 200, 3, departs=True))
    still_q = script[STILL_READS[0]].q
    calls = [0]

    def count(frame, event, arg) -> None:
        if event == "call" or event == "c_call":
            calls[0] += 1

    compensated, stills, cpu_us, cdr = [], [], [], []
    for i, cycle in enumerate(script):
        if STILL_READS[0] <= i < STILL_READS[1]:
            cycle = replace(cycle, q=still_q + rng.normal(0, 2e-5, 6), qd=np.zeros(6), target_qd=np.zeros(6),
                            target_qdd=np.zeros(6))
        states.append(cycle)
        if i < 200:
            continue
        device_s = 0.4 + ((i - 200) * SAMPLES_PER_READ + np.arange(SAMPLES_PER_READ)) / 7000.0
        batch = WrenchBatch(time_s=80.0 + device_s + 3e-4, wrench=rng.normal(0, 1, (SAMPLES_PER_READ, 6)),
                            counts=np.zeros((SAMPLES_PER_READ, 6), dtype=np.int64),
                            status=np.zeros(SAMPLES_PER_READ, dtype=np.uint32),
                            sequence=np.arange(SAMPLES_PER_READ), saturated=np.zeros(SAMPLES_PER_READ, dtype=bool),
                            device_time_s=device_s)
        robot = events.RobotState(0.0, cycle.q, np.array([0.3, 0.1, 0.5, 0.1, 3.0, 0.2]) + 1e-6 * i)
        if count_calls:
            sys.setprofile(count)
        start = time.thread_time_ns()
        contact = drift.compensate(batch, robot)
        drift.track()
        sample_time_s = compensator.clock.host_times(batch.time_s, batch.device_time_s)
        out = messages(events.WrenchSamples(batch=batch, compensated=contact, sample_time_s=sample_time_s))
        cpu_us.append((time.thread_time_ns() - start) / 1e3)
        if count_calls:
            sys.setprofile(None)
        compensated.append(contact if contact is not None else np.full((SAMPLES_PER_READ, 6), np.nan))
        stills.append(drift.still_now)
        cdr += [name.encode() + b"".join(data) + stamps.tobytes() for name, _, data, stamps in out]
    return {"compensated": np.concatenate(compensated), "still": np.array(stills),
            "cdr": np.frombuffer(b"".join(cdr), dtype=np.uint8), "cpu_us": np.array(cpu_us[100:]),
            "calls_per_read": calls[0] / len(cpu_us)}


def compare(first: Path, second: Path) -> None:
    a, b = np.load(first), np.load(second)
    for key in ("compensated", "still", "cdr"):
        same = a[key].shape == b[key].shape and np.array_equal(a[key], b[key], equal_nan=key == "compensated")
        print(f"{key}: {'bit-identical' if same else 'DIFFERENT'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--servo-lag-ms", type=float, default=0.0)
    parser.add_argument("--save", type=Path, help="write the outputs (.npz) for --compare")
    parser.add_argument("--compare", type=Path, nargs=2, metavar="NPZ")
    args = parser.parse_args()
    if args.compare:
        compare(*args.compare)
        return
    run = replay(args.servo_lag_ms / 1e3)
    calls = replay(args.servo_lag_ms / 1e3, count_calls=True)["calls_per_read"]
    cpu = run["cpu_us"]
    print(f"{len(cpu)} reads: thread CPU µs per read p50 {np.median(cpu):.0f} mean {cpu.mean():.0f}; "
          f"calls per read {calls:.1f}; still in {run['still'].mean():.0%} of reads")
    if args.save:
        np.savez(args.save, compensated=run["compensated"], still=run["still"], cdr=run["cdr"])


if __name__ == "__main__":
    main()
