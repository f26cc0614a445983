"""Fuzz every input a user can hand ftacq, for longer than the suite does; print inputs tried and escapes.

    python benchmarks/fuzz.py [--examples N] [--seed S] [--identify]

An escape is an exception that is not ftacq's own (a traceback instead of a one-line message); the figure to
report is ``escapes = 0``. Inputs come from tests/fuzz_inputs.py (pose CSV, calibration JSON, CELL.toml, sensor
URLs). ``--identify`` also runs the closed-form identification on every pose record that parses.
"""

from __future__ import annotations

import argparse
import collections
import sys
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hypothesis import HealthCheck, given, seed, settings  # noqa: E402

from ftacq.errors import FtacqError  # noqa: E402
from tests.fuzz_inputs import Targets  # noqa: E402


def fuzz(name: str, strategy, target, examples: int, random_seed: int) -> tuple[int, int, collections.Counter, dict]:
    """Run ``examples`` inputs through ``target``; return (inputs, escapes, refused by error type, first escapes)."""
    counts = {"inputs": 0, "escapes": 0}
    refused: collections.Counter = collections.Counter()
    first: dict[str, tuple[str, str]] = {}

    @seed(random_seed)
    @settings(max_examples=examples, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(text=strategy)
    def run(text: str) -> None:
        counts["inputs"] += 1
        try:
            target(text)
        except FtacqError as error:
            refused[type(error).__name__] += 1
        except Exception as error:  # noqa: BLE001 - an escape: what this script counts
            counts["escapes"] += 1
            kind = f"{type(error).__name__}: {str(error)[:80]}"
            first.setdefault(kind, (text[:200], traceback.format_exc(limit=-3)))

    run()
    return counts["inputs"], counts["escapes"], refused, first


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=5000, help="inputs per kind (default %(default)s)")
    parser.add_argument("--seed", type=int, default=int(time.time()), help="random seed (default: the time)")
    parser.add_argument("--identify", action="store_true", help="also identify (closed form) every parsed record")
    args = parser.parse_args()
    targets = Targets(identify=args.identify)
    total_inputs = total_escapes = 0
    print(f"fuzz: {args.examples} inputs per kind, seed {args.seed}")
    try:
        for name, (strategy, target) in targets.all().items():
            started = time.perf_counter()
            inputs, escapes, refused, first = fuzz(name, strategy, target, args.examples, args.seed)
            elapsed = time.perf_counter() - started
            total_inputs += inputs
            total_escapes += escapes
            accepted = inputs - escapes - sum(refused.values())
            print(f"  {name:17s} inputs {inputs:6d}  accepted {accepted:6d}  refused {sum(refused.values()):6d}  "
                  f"escapes {escapes:4d}  ({elapsed:.1f} s; refused as {dict(refused)})")
            for kind, (text, trace) in first.items():
                print(f"    ESCAPE {kind}\n      input: {text!r}\n" + "".join(f"      {line}\n" for line in
                                                                           trace.splitlines()[-4:]))
    finally:
        targets.close()
    print(f"total: inputs {total_inputs}, escapes {total_escapes}")
    return 1 if total_escapes else 0


if __name__ == "__main__":
    sys.exit(main())
