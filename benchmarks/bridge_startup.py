"""Benchmark: ``ftacq bridge --sim --seconds S --save FILE.rrd`` run N times as a user runs it (a viewer sink, so
that the start-up is slow and the controller's packages queue): how many runs exit 0, and each run's last line
(queued cycles skipped at the start, values and cycles while the input was enabled, late answers, sample ages).

    .venv/bin/python benchmarks/bridge_startup.py              # 10 runs of 3 s
    .venv/bin/python benchmarks/bridge_startup.py --runs 20 --seconds 5

Prints the machine's load average before each run: on a shared machine the figures depend on it.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FTACQ = Path(sys.executable).with_name("ftacq")
LAST_LINE = re.compile(r"values written in .*")
FIGURES = re.compile(r"\((?P<skipped>\d+) cycles queued.*?while the input was enabled: (?P<values>\d+) values in "
                     r"(?P<cycles>\d+) cycles, answered later than one cycle: (?P<late>\d+), (?P<ages>[^;]*)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=3.0)
    args = parser.parse_args()
    ok = 0
    with tempfile.TemporaryDirectory(prefix="ftacq-bridge-startup-") as folder:
        for run in range(1, args.runs + 1):
            load = os.getloadavg()[0]
            result = subprocess.run([str(FTACQ), "bridge", "--sim", "--seconds", f"{args.seconds:g}", "--save",
                                     str(Path(folder) / f"b{run}.rrd")], cwd=folder, capture_output=True, text=True,
                                    timeout=120 + args.seconds)
            ok += result.returncode == 0
            text = result.stdout + result.stderr
            figures = FIGURES.search(text)
            if figures:
                shown = (f"skipped at start {figures['skipped']}, while enabled {figures['values']} values / "
                         f"{figures['cycles']} cycles, late {figures['late']}, {figures['ages']}")
            else:
                shown = (LAST_LINE.search(text) or re.search(r".*\S", text) or re.search("", "")).group(0)[:200]
            error = next((line for line in text.splitlines() if line.startswith("ftacq: error")), "")
            print(f"run {run:2d}: exit {result.returncode}, load {load:.1f}: {shown}" + (f" | {error}" if error else ""))
    print(f"ftacq bridge --sim --seconds {args.seconds:g} --save: {ok} of {args.runs} runs exit 0")
    return 0


if __name__ == "__main__":
    sys.exit(main())
