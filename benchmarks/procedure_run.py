"""Benchmark: the simulated wall time of a default calibration run (A 24 + E 24 + V 12 + drift revisit).

    .venv/bin/python benchmarks/procedure_run.py                 # UR5e floor, Net F/T, controller at time scale 10
    .venv/bin/python benchmarks/procedure_run.py --quick         # time scale 20 (faster, same figures)
    .venv/bin/python benchmarks/procedure_run.py --time-scale 1  # real time: about 3-4 minutes

Runs the real procedure (real ur-rtde client and Net F/T driver) against the simulated cell. At real-time scale a
run takes minutes, so the controller runs ``X`` times faster and the figure at real-time scale is rebuilt from the
measured parts: X × (wall time spent moving) + per pose the real settle and averaging times (sampling does not
scale: it needs real sensor samples) + the measured overheads (connect, plan, per-pose command and read latency,
identification). Goal: ≤ 5 min for A + E + V. Also prints the planner's estimate for comparison, and the
accuracy of the run against the simulation's truth.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

DURATION_GOAL_S = 300.0


class Timer:
    """A procedure listener that adds up wall time per state."""

    def __init__(self) -> None:
        self.totals: dict[str, float] = {}
        self.counts: dict[str, int] = {}
        self._state = None
        self._since = time.monotonic()

    def __call__(self, event) -> None:
        from procedures import events

        if isinstance(event, events.StateChanged):
            now = time.monotonic()
            if self._state is not None:
                self.totals[self._state] = self.totals.get(self._state, 0.0) + now - self._since
            self.counts[event.state] = self.counts.get(event.state, 0) + 1
            self._state, self._since = event.state, now


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="controller at time scale 20")
    parser.add_argument("--time-scale", type=float, default=None, help="controller speed factor (default 10)")
    parser.add_argument("--sensor", choices=("netft", "can"), default="netft")
    args = parser.parse_args()
    scale = args.time_scale if args.time_scale is not None else (20.0 if args.quick else 10.0)
    if scale <= 0:
        parser.error("--time-scale must be > 0 (motion time is measured)")
    ok, lines = simulated_run_figures(scale, args.sensor)
    for line in lines:
        print(line, flush=True)
    return 0 if ok else 1


def simulated_run_figures(scale: float, sensor: str = "netft") -> tuple[bool, list[str]]:
    """Run a default calibration against the simulated cell with the controller ``scale`` (> 0) times real time.

    Returns (run completed, the lines to print): measured wall time per state, the run rebuilt at real-time
    scale against the 5 min goal, the planner's estimate and the accuracy against the simulation's truth.
    """
    from drivers.robot import MotionLimits
    from drivers.ur import URRobot
    from ftacq.app.commands.calibrate import sim_sampling
    from ftacq.app.config import CellConfig
    from ftacq.posesets import PLANNED_SETS
    from procedures.plan import make_plan
    from tests.fakes.cell import SimulatedCell, run_calibration

    t0 = time.monotonic()
    with SimulatedCell(sensor=sensor, time_scale=scale) as cell:
        t_cell = time.monotonic() - t0
        base = CellConfig()
        config = base.replace_section("robot", host=cell.robot_host).replace_section("sensor", url=cell.sensor_url)
        real_sampling = config.sampling
        scaled = sim_sampling(real_sampling, scale)
        config_run = config.replace_section("sampling", **{k: getattr(scaled, k) for k in (
            "settle_time_s", "settle_window_s", "average_time_s")})
        t1 = time.monotonic()
        with URRobot(cell.robot_host, MotionLimits(), model=cell.model_name) as robot:
            plan = make_plan(config.plan_settings(), robot.joint_positions())
        t_plan = time.monotonic() - t1
        timer = Timer()
        t2 = time.monotonic()
        _, result = run_calibration(cell, config_run, [timer], plan=plan)
        t_run = time.monotonic() - t2
    if result.status != "done":
        return False, [f"run failed: {result.message}"]
    poses = timer.counts.get("averaging", 0)
    moving = timer.totals.get("moving", 0.0)
    settling = timer.totals.get("settling", 0.0)
    averaging = timer.totals.get("averaging", 0.0)
    other = t_run - moving - settling - averaging
    def per_pose(s) -> float:  # settled after max(settle time, window) of stillness, then the averaging window
        return max(s.settle_time_s, s.settle_window_s) + s.average_time_s

    sampling_real = poses * per_pose(real_sampling)
    sampling_overhead = max(settling + averaging - poses * per_pose(scaled), 0.0)
    real_estimate = scale * moving + sampling_real + sampling_overhead + other + t_plan
    cal = result.identification.calibration
    truth = cell.truth
    v = result.validation
    lines: list[str] = []
    counts = ", ".join(f"{name} {plan.set_names.count(name)}" for name in PLANNED_SETS)
    lines.append(f"default run: {len(plan)} poses ({counts}) + drift revisit, "
          f"UR5e floor, {sensor}, controller time scale {scale:g}")
    lines.append(f"  measured wall time at scale {scale:g}: {t_run:.1f} s run (moving {moving:.1f} s, settling "
          f"{settling:.1f} s, averaging {averaging:.1f} s, other {other:.1f} s) + plan {t_plan:.1f} s "
          f"+ cell start {t_cell:.1f} s")
    lines.append(f"  simulated-controller motion time: {scale * moving:.1f} s (= {scale:g} × {moving:.2f} s)")
    lines.append(f"  run at real-time scale (rebuilt): {real_estimate:.0f} s = {real_estimate / 60:.1f} min "
          f"[goal ≤ {DURATION_GOAL_S / 60:.0f} min: {'OK' if real_estimate <= DURATION_GOAL_S else 'MISSED'}]; "
          f"planner estimate {plan.estimated_duration_s:.0f} s")
    lines.append(f"  speed {config.robot.joint_speed_rad_s} rad/s, acceleration {config.robot.joint_acceleration_rad_s2} "
          f"rad/s², per pose still for max(settle {real_sampling.settle_time_s} s, window "
          f"{real_sampling.settle_window_s} s) + average {real_sampling.average_time_s} s")
    lines.append(f"  accuracy: mass {cal.mass_kg:.4f} kg (true {truth.mass_kg}), validation RMS F "
          f"{np.linalg.norm(v.rms[:3]):.4f} N, T {np.linalg.norm(v.rms[3:]):.5f} N·m")
    return True, lines


if __name__ == "__main__":
    sys.exit(main())
