"""Benchmark: the calibration procedure's pose plan: joint travel of the chosen order and the run's duration.

    .venv/bin/python benchmarks/procedure.py              # every UR model on a floor mount, UR5e on wall and ceiling
    .venv/bin/python benchmarks/procedure.py --quick      # the default cell only (UR5e, floor)
    .venv/bin/python benchmarks/procedure.py --plan-only  # without the simulated run

For each cell: the weighted joint travel of the planned order (nearest neighbour + 2-opt, from the UR "home"
configuration) against the listing order of the paper (A01…A24, then E, then V) with the same shortest joint
moves (goal: ≥ 30 % shorter), and the estimated wall time of a default A + E + V run at real-time scale from
trapezoidal moveJ profiles at the configured speed/acceleration plus settle and averaging time per pose and the
drift-check revisit (goal: ≤ 5 min). Also the time the planner itself took.

Then the measured figure: a default run with the real drivers against the simulated cell (controller 10× real
time, 20× with ``--quick``; ``benchmarks/procedure_run.py``), its wall time rebuilt at real-time scale
(goal: ≤ 5 min). ``--plan-only`` skips it. The figures are functions ``(quick: bool) -> list[str]`` in
:data:`FIGURES`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from procedures.plan import PlanSettings, home_configuration_rad, make_plan  # noqa: E402

TRAVEL_GOAL = 0.30  # at least this fraction shorter than the listing order
DURATION_GOAL_S = 300.0
QUICK_CELLS = (("UR5e", "floor"),)
FULL_CELLS = tuple((model, "floor") for model in ("UR3e", "UR5e", "UR10e", "UR16e", "UR20", "UR30", "UR3", "UR5",
                                                  "UR10")) + (("UR5e", "wall"), ("UR5e", "ceiling"))


def plan_figures(quick: bool) -> list[str]:
    """Return one line per cell: poses, travel (chosen vs listing), estimated duration, planning time."""
    lines = [f"{'cell':<16} {'poses':>5} {'travel rad':>10} {'listing rad':>11} {'shorter':>8} "
             f"{'est. run':>9} {'planning':>9}  goals"]
    for model, mount in QUICK_CELLS if quick else FULL_CELLS:
        t0 = time.perf_counter()
        plan = make_plan(PlanSettings(model=model, mount=mount), home_configuration_rad(mount))
        planning_s = time.perf_counter() - t0
        shorter = 1.0 - plan.joint_travel_rad / plan.listing_travel_rad
        goals = ("ok" if shorter >= TRAVEL_GOAL else "TRAVEL") + "/" + (
            "ok" if plan.estimated_duration_s <= DURATION_GOAL_S else "DURATION")
        lines.append(f"{model + ' ' + mount:<16} {len(plan):>5} {plan.joint_travel_rad:>10.1f} "
                     f"{plan.listing_travel_rad:>11.1f} {100 * shorter:>7.0f}% {plan.estimated_duration_s:>8.0f}s "
                     f"{planning_s:>8.2f}s  {goals}")
    settings = PlanSettings()
    lines.append(f"(speed {settings.joint_speed_rad_s} rad/s, acceleration {settings.joint_acceleration_rad_s2} "
                 f"rad/s², settle {settings.settle_time_s} s + average {settings.average_time_s} s per pose; goals: "
                 f"travel ≥ {100 * TRAVEL_GOAL:.0f} % shorter, run ≤ {DURATION_GOAL_S:.0f} s)")
    return lines


def simulated_run(quick: bool) -> list[str]:
    """Return the lines of a default run against the simulated cell, rebuilt at real-time scale."""
    from benchmarks.procedure_run import simulated_run_figures

    _, lines = simulated_run_figures(20.0 if quick else 10.0)
    return lines


FIGURES: list[Callable[[bool], list[str]]] = [plan_figures, simulated_run]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="the default cell only; the simulated run at controller time scale 20")
    parser.add_argument("--plan-only", action="store_true", help="plan figures only, no simulated run")
    args = parser.parse_args(argv)
    for figure in FIGURES[:1] if args.plan_only else FIGURES:
        print(f"== {figure.__name__} ==")
        for line in figure(args.quick):
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
