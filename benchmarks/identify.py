"""Benchmark the calibration core: identification time and compensation throughput / latency.

Prints (targets in brackets):
- identify (incl. robust refinement) on 48 poses [≤ 50 ms], 1 000 and 100 000 poses;
- batch compensation, one flange orientation per sample (N readings × N orientations) [≥ 20 M samples/s];
- batch compensation, one orientation for the whole batch;
- single-sample compensation latency, ``Calibration.compensate_sample`` and ``compensate`` [≤ 10 µs].

Usage: ``python benchmarks/identify.py [--quick]`` (quick: fewer repetitions, smaller batches).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ftacq.identification import identify  # noqa: E402
from tests.fakes.pose_records import (  # noqa: E402
    cone_orientations,
    random_orientations,
    simulate_record,
    special_orientations,
)
from tests.fakes.world import CellTruth  # noqa: E402


def best_time_s(function, repeats: int) -> float:
    """Return the best wall time in seconds of ``repeats`` calls."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repetitions and smaller batches (CI)")
    args = parser.parse_args(argv)
    repeats = 3 if args.quick else 10
    truth = CellTruth()

    print("identification (closed form + robust joint refinement, 1σ, diagnostics)")
    record48 = simulate_record(
        truth, np.concatenate([special_orientations(0.2, seed=1), cone_orientations(24, 40.0, seed=2)]), seed=3
    )
    identify(record48)  # warm-up (imports, caches)
    print(f"  48 poses (24 special + 24 in a 40° cone): {1e3 * best_time_s(lambda: identify(record48), repeats):8.1f} ms   [target ≤ 50 ms]")
    for n, reps in ((1_000, repeats), (100_000, 1)):
        record = simulate_record(truth, random_orientations(n, seed=n), seed=4)
        elapsed = best_time_s(lambda record=record: identify(record), reps)
        print(f"  {n:>7,} random poses:                     {1e3 * elapsed:8.1f} ms")

    print("compensation (float64)")
    calibration = truth.calibration()
    n = 200_000 if args.quick else 1_000_000
    rotations = random_orientations(n, seed=5)
    wrench = np.random.default_rng(6).normal(size=(n, 6))
    out = np.empty((n, 6))
    elapsed = best_time_s(lambda: calibration.compensate(wrench, rotations, out=out), repeats)
    print(f"  batch, one orientation per sample ({n:,}): {n / elapsed / 1e6:8.1f} M samples/s   [target ≥ 20 M/s]")
    elapsed = best_time_s(lambda: calibration.compensate(wrench, rotations[0], out=out), repeats)
    print(f"  batch, one orientation per batch  ({n:,}): {n / elapsed / 1e6:8.1f} M samples/s")
    one_wrench, one_rotation = wrench[0], rotations[0]
    calls = 20_000 if args.quick else 100_000
    start = time.perf_counter()
    for _ in range(calls):
        calibration.compensate_sample(one_wrench, one_rotation)
    per_call = (time.perf_counter() - start) / calls
    print(f"  single sample, compensate_sample (numpy in):  {1e6 * per_call:6.2f} µs   [target ≤ 10 µs]")
    wrench_list, rotation_list = one_wrench.tolist(), one_rotation.tolist()
    start = time.perf_counter()
    for _ in range(calls):
        calibration.compensate_sample(wrench_list, rotation_list)
    per_call = (time.perf_counter() - start) / calls
    print(f"  single sample, compensate_sample (lists in):  {1e6 * per_call:6.2f} µs")
    start = time.perf_counter()
    for _ in range(calls):
        calibration.compensate(one_wrench, one_rotation)
    per_call = (time.perf_counter() - start) / calls
    print(f"  single sample, compensate (numpy path):       {1e6 * per_call:6.2f} µs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
