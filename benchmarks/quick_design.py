"""Benchmark: the quick calibration's design (procedures.quick.design_quick) on the default simulated cell, in a fresh
process each run, with one OpenBLAS thread (what the ``ftacq`` command sets) and with two (OpenBLAS's default on
this 2-core machine): the design's wall time and CPU time, and the process's CPU in all.

    .venv/bin/python benchmarks/quick_design.py [--runs 3]

Prints one line per setting: design wall / CPU s (median of the runs), and that every run designed the same plan.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

DESIGN = """
import json, time
import numpy as np
from ftacq.app.config import config_from_dict
from procedures.plan import home_configuration_rad
from procedures.quick import design_quick
settings = config_from_dict({"robot": {"host": "x", "model": "UR5e", "mount": "floor"}}, "benchmark").plan_settings()
wall, cpu = time.perf_counter(), time.process_time()
plan = design_quick(settings, home_configuration_rad("floor"))
print(json.dumps({"wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu,
                  "plan": [np.round(plan.hold_s, 6).tolist(), round(float(plan.information_logdet), 9)]}))
"""


def run(threads: int) -> dict:
    env = dict(os.environ, OPENBLAS_NUM_THREADS=str(threads), PYTHONPATH=str(ROOT))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run([sys.executable, "-c", DESIGN], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600, check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result["process_cpu_s"] = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="runs per setting (default %(default)s)")
    args = parser.parse_args()
    plans = set()
    for threads in (1, 2):
        results = [run(threads) for _ in range(args.runs)]
        plans.update(json.dumps(r["plan"]) for r in results)
        median = {key: sorted(r[key] for r in results)[len(results) // 2] for key in ("wall_s", "cpu_s", "process_cpu_s")}
        print(f"OpenBLAS threads {threads}: design {median['wall_s']:.2f} s wall, {median['cpu_s']:.2f} s CPU; "
              f"process {median['process_cpu_s']:.2f} s CPU (median of {args.runs})")
    print("the same plan every run" if len(plans) == 1 else f"PLANS DIFFER: {len(plans)} designs")
    return 0 if len(plans) == 1 else 1


if __name__ == "__main__":
    sys.exit(main())
