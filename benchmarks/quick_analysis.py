"""Benchmark: the quick calibration's analysis (procedures.quick_analysis.analyse_quick: settling, the joint fit with
and without the drift's columns, the verdict) on a recording of the default plan synthesized from the simulated
cell's physics (tests/fakes/quick_records.py: ring-down after every stop, noise growing with speed), with one
OpenBLAS thread (what the ``ftacq`` command sets).

    .venv/bin/python benchmarks/quick_analysis.py [--runs 3]

Prints the rows fitted, the analysis's wall and CPU time per run (s) and that every run gave the same result (the
mass to the last digit and the Gauss-Newton iterations), so that a faster analysis is seen to be the same one.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()

    from ftacq.app.config import config_from_dict
    from ftacq.mounts import mount_of
    from procedures.plan import home_configuration_rad
    from procedures.quick import design_quick
    from procedures.quick_analysis import analyse_quick
    from tests.fakes.quick_records import synthesize_recording
    from tests.fakes.world import CellTruth

    settings = config_from_dict({"robot": {"host": "x", "model": "UR5e", "mount": "floor"}},
                                "benchmark").plan_settings()
    plan = design_quick(settings, home_configuration_rad("floor"))
    truth = CellTruth()
    recording = synthesize_recording(plan, truth, settings.ur, seed=1)
    results = set()
    for run in range(args.runs):
        wall, cpu = time.perf_counter(), time.process_time()
        analysis = analyse_quick(recording, plan, settings.ur, np.array(truth.sensor_offset_m),
                                 np.array(mount_of("floor").down_base), completed=True)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        results.add((repr(analysis.result.calibration.mass_kg), analysis.result.iterations, analysis.verdict.status))
        print(f"run {run + 1}: {analysis.rows.sum()} rows, analysis {wall:.2f} s wall, {cpu:.2f} s CPU "
              f"({analysis.verdict.status}, {analysis.result.iterations} iterations)")
    print(f"same result every run: {len(results) == 1} {sorted(results)[0]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
