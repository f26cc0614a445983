"""Benchmark: the simulated wall time of a default calibration run (A 24 + E 24 + V 12 + drift revisit).

    .venv/bin/python benchmarks/procedure_run.py                 # UR5e floor, Net F/T, controller at time scale 10
    .venv/bin/python benchmarks/procedure_run.py --quick         # time scale 20 (faster, same figures)
    .venv/bin/python benchmarks/procedure_run.py --time-scale 1  # real time: about 3-4 minutes
    .venv/bin/python benchmarks/procedure_run.py --runs          # 20 consecutive runs: how many were aborted
    .venv/bin/python benchmarks/procedure_run.py --runs 5 --time-scale 0   # 5 runs, moves complete at once

``--runs [N]`` (N = 20 by default) runs N default calibrations one after another on one simulated cell whose
controller reports its joint angles with encoder jitter (1e-6 rad, as a real UR5e), each planned from where the
arm stopped after the previous one and with another seed for the E and V poses (seed 0, 1, …). It prints each
run's outcome (status, poses measured, wall time, verdict, the planned target closest to a joint limit, a failed
drift check) and the counts: goal 0 aborted.

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
CONSECUTIVE_RUNS = 20
"""``--runs`` without a number: consecutive calibrations run (issue 26's goal: 20 with encoder jitter, 0 aborted)."""


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
    parser.add_argument("--runs", type=int, nargs="?", const=CONSECUTIVE_RUNS, default=None, metavar="N",
                        help=f"run N consecutive calibrations with encoder jitter (default N {CONSECUTIVE_RUNS}; "
                             "time scale 20 unless given, 0 allowed) and count the aborted ones")
    args = parser.parse_args()
    if args.runs is not None:
        scale = args.time_scale if args.time_scale is not None else 20.0
        if args.runs < 1 or scale < 0:
            parser.error("--runs needs N >= 1 and --time-scale >= 0")
        return 0 if consecutive_runs(args.runs, scale, args.sensor) else 1
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


def consecutive_runs(runs: int, scale: float, sensor: str = "netft") -> bool:
    """Run ``runs`` default calibrations one after another on one simulated cell with encoder jitter, the controller
    ``scale`` times real time (0: moves complete at once); print each outcome and the counts. Returns True when
    none was aborted (every run "done")."""
    from ftacq.app.commands.calibrate import sim_sampling
    from ftacq.app.config import CellConfig
    from ftacq.errors import FtacqError
    from ftacq.kinematics import planning_limits_rad
    from procedures.acceptance import run_verdict
    from procedures.calibration_procedure import ProcedureOptions
    from tests.fakes.cell import SimulatedCell, run_calibration
    from tests.fakes.ur_simulator import ENCODER_NOISE_RAD

    t0 = time.monotonic()
    completed, skipped = 0, 0
    with SimulatedCell(sensor=sensor, time_scale=scale, encoder_noise_rad=ENCODER_NOISE_RAD) as cell:
        config = CellConfig().replace_section("robot", host=cell.robot_host).replace_section("sensor",
                                                                                             url=cell.sensor_url)
        scaled = sim_sampling(config.sampling, scale)
        config = config.replace_section("sampling", **{k: getattr(scaled, k) for k in (
            "settle_time_s", "settle_window_s", "average_time_s")})
        print(f"{runs} consecutive default calibrations, UR5e floor, {sensor}, controller time scale {scale:g}, "
              f"encoder jitter {ENCODER_NOISE_RAD:g} rad (1σ); cell start {time.monotonic() - t0:.1f} s", flush=True)
        for i in range(runs):
            run_config = config.replace_section("poses", seed=i)
            t1 = time.monotonic()
            try:
                plan, result = run_calibration(cell, run_config)
            except FtacqError as exc:  # planning refused: as aborted as a run that failed
                print(f"  run {i + 1:2d}/{runs} (seed {i}): not started, {type(exc).__name__}: {exc}", flush=True)
                continue
            wall = time.monotonic() - t1
            done = result.status == "done"
            completed += done
            skipped += bool(result.drift_skipped)
            lower, upper = planning_limits_rad(plan.settings.ur, 0.0)
            targets = np.vstack([plan.joint_targets_rad] + ([np.asarray(plan.revisit_target_rad)[None, :]]
                                                           if plan.revisit_target_rad is not None else []))
            closest = float(np.degrees(np.min(np.minimum(targets - lower, upper - targets))))
            verdict = run_verdict(result, plan, ProcedureOptions.from_config(run_config)).headline() \
                if result.identification is not None else "-"
            line = (f"  run {i + 1:2d}/{runs} (seed {i}): {result.status:<7} {len(result.measured)} poses in "
                    f"{wall:5.1f} s, closest target {closest:.1f}° inside a joint limit, verdict {verdict}")
            if not done:
                line += f"; {result.message}"
            if result.drift_skipped:
                line += f"; drift check skipped: {result.drift_skipped}"
            print(line, flush=True)
    total = time.monotonic() - t0
    aborted = runs - completed
    print(f"consecutive runs: {completed} completed, {aborted} aborted of {runs} (drift check skipped in {skipped}); "
          f"wall time {total:.0f} s ({total / runs:.1f} s per run) at time scale {scale:g} "
          f"[goal 0 aborted: {'OK' if aborted == 0 else 'MISSED'}]", flush=True)
    return aborted == 0


if __name__ == "__main__":
    sys.exit(main())
