"""Benchmark: compensation while the arm moves (issue 12), one run on the simulated cell, figures side by side.

    .venv/bin/python benchmarks/dynamics.py [--jog-s 15] [--monitor-s 15] [--model UR5e] [--version 3.15.7.106331]
    .venv/bin/python benchmarks/dynamics.py --live-minutes 5 [--burners 2] [--every-s 20] [--sensor-rate-error 150e-6]
        [--sim-priority N]

With ``--live-minutes``: the run of issue 27 instead (benchmarks/dynamics_live.py): minutes of ``ftacq monitor``
with dynamic compensation on a cell whose devices keep their own clocks, a 4.2 kg tool, a separate-process jog,
per-minute figures, optionally beside CPU-burning processes. Without it, as before:

The simulated cell (UR5e controller in real time, Net F/T at 7 kHz, the 1.35 kg demo tool with its inertia, the
sensor 35 mm from the flange) is calibrated with the real drivers: the static poses (controller at time scale 0),
then the excitation stage at real-time scale (``procedures/excitation.py``, joints up to 1 rad/s and 2 rad/s²).
Then a different jog at technician speeds (moveJs to random targets, up to 1 rad/s and 2 rad/s², wrist included,
no contact) is recorded and compensated with the static and with the dynamic model: the error of the compensated
wrench (the truth is zero) beside the at-rest per-sample noise floor. Finally ``ftacq monitor`` runs as its own
process against the cell while the arm jogs, with the dynamic calibration: its sample rate, losses and CPU.

The simulated cell's ``motion_noise_gain`` (extra sensor noise proportional to joint speed, a stand-in for
vibration no rigid-body model removes) is 0 here: with it the sensor's own noise during a 1 rad/s jog is three
times the at-rest noise and the first goal could not be met by any model.

Goals: dynamic RMS ≤ 1.5× the at-rest noise while the static model's is ≥ 5×; inertia within 10 % (Frobenius);
excitation ≤ 60 s at real-time scale; live dynamic compensation at 7 kHz, 0 lost, monitor < 50 % of one core.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.robot import MotionLimits  # noqa: E402
from drivers.sensor import open_sensor  # noqa: E402
from drivers.ur import URRobot  # noqa: E402
from drivers.ur_stream import URStateStream  # noqa: E402
from ftacq.calfile import save_calibration  # noqa: E402
from ftacq.dynamics import compensate_moving, identify_dynamics  # noqa: E402
from ftacq.dynamics.model import SensorDynamics, predict_moving  # noqa: E402
from ftacq.dynamics.timing import interpolate_rows  # noqa: E402
from ftacq.kinematics import ur_model  # noqa: E402
from ftacq.kinematics.trapezoid import trapezoid_duration_s  # noqa: E402
from procedures.excitation import ExcitationPlan, plan_excitation, record_excitation  # noqa: E402
from procedures.plan import PlanSettings, check_path  # noqa: E402
from tests.fakes.cell import SimulatedCell, fast_config, run_calibration  # noqa: E402
from tests.fakes.world import CellTruth  # noqa: E402

SPEED, ACCELERATION = 1.0, 2.0
SENSOR_RATE_HZ = 7000.0
JOG_AMPLITUDE_RAD = np.array([0.3, 0.25, 0.3, 1.0, 1.0, 1.5])


def jog_plan(settings: PlanSettings, start: np.ndarray, duration_s: float, seed: int) -> ExcitationPlan:
    """Random checked moveJs around ``start`` for about ``duration_s`` at the technician's speeds, back to start."""
    rng = np.random.default_rng(seed)
    targets, q, total = [], start, 0.0
    while total < duration_s:
        candidate = start + JOG_AMPLITUDE_RAD * rng.uniform(-1.0, 1.0, 6)
        if check_path(settings, q, candidate):
            continue
        total += trapezoid_duration_s(float(np.max(np.abs(candidate - q))), SPEED, ACCELERATION)
        targets.append(candidate)
        q = candidate
    targets.append(start)
    return ExcitationPlan(start, np.array(targets), SPEED, ACCELERATION, total, seed)


def rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jog-s", type=float, default=15.0, help="length of the jog compensated (s)")
    parser.add_argument("--monitor-s", type=float, default=15.0, help="length of the live monitor run (s)")
    parser.add_argument("--save-motion", type=Path, metavar="DIR", help="also write the excitation and the jog as "
                        "motion CSVs there (ftacq identify --motion reads them)")
    parser.add_argument("--live-minutes", type=float, default=0.0, metavar="M",
                        help="run the live benchmark of issue 27 for M minutes instead (benchmarks/dynamics_live.py)")
    parser.add_argument("--burners", type=int, default=0, help="with --live-minutes: CPU-burning processes beside it")
    parser.add_argument("--every-s", type=float, default=20.0, help="with --live-minutes: one jog move every S s")
    parser.add_argument("--sensor-rate-error", type=float, default=150e-6,
                        help="with --live-minutes: the sensor's clock rate error (default 150e-6)")
    parser.add_argument("--sensor-backlog-s", type=float, default=0.02,
                        help="with --live-minutes: the simulated sensor skips what it could not send within this, s")
    parser.add_argument("--seed", type=int, default=7, help="with --live-minutes: the jog's seed")
    parser.add_argument("--model", default="UR5e", help="the simulated arm (default UR5e; UR5: a CB3 at 125 Hz)")
    parser.add_argument("--version", help="the simulated controller's software (default the model's: 3.15 for a CB3, "
                                          "5.11 else); e.g. a UR5 at 5.11.1.108318 streams 500 Hz: the rate alone")
    parser.add_argument("--keep", type=Path, metavar="DIR", help="with --live-minutes: keep the monitor's record, "
                        "its stderr and the jog's moves there")
    parser.add_argument("--sim-priority", type=int, default=0, metavar="N",
                        help="with --live-minutes: run the simulated controller and Net F/T sender at SCHED_FIFO N "
                             "(a real controller and box never stall behind the host's other programs)")
    args = parser.parse_args()
    if args.live_minutes > 0:
        import dynamics_live

        return dynamics_live.main(args.live_minutes, args.every_s, args.burners, args.sensor_rate_error,
                                  args.sensor_backlog_s, args.seed, args.keep, args.sim_priority, args.model,
                                  args.version)
    truth = CellTruth(motion_noise_gain=0.0)
    model = ur_model(args.model)
    settings = PlanSettings(joint_speed_rad_s=SPEED, joint_acceleration_rad_s2=ACCELERATION)
    lines = []
    with SimulatedCell(truth=truth, time_scale=0.0, rate_hz=SENSOR_RATE_HZ, model=args.model,
                       version=args.version) as cell:
        config = fast_config(cell, random_count=12, validation_count=4, average_time_s=0.3)
        _, result = run_calibration(cell, config)
        static = replace(result.identification.calibration, sensor_offset=np.array(truth.sensor_offset_m))
        cell.controller.set_time_scale(1.0)
        with URRobot(cell.robot_host, MotionLimits(SPEED, ACCELERATION), model=args.model) as robot, \
                URStateStream(cell.robot_host) as stream:
            sensor = open_sensor(cell.sensor_url)
            sensor.start()
            try:
                # at-rest noise floor (per sample)
                sensor.read(timeout_s=0.5)
                rest = []
                end = time.monotonic() + 2.0
                while time.monotonic() < end:
                    rest.append(sensor.read(timeout_s=0.5).wrench)
                rest = np.concatenate(rest)
                noise = rest.std(axis=0)
                # excitation stage at real-time scale
                plan = plan_excitation(settings, robot.joint_positions())
                started = time.monotonic()
                record = record_excitation(plan, robot, sensor, stream)
                excitation_s = time.monotonic() - started
                identified = identify_dynamics(static, record, model)
                dynamic = identified.calibration
                # a different jog, recorded and compensated with both models
                jog = jog_plan(settings, robot.joint_positions(), args.jog_s, seed=11)
                jog_record = record_excitation(jog, robot, sensor, stream)
            finally:
                sensor.close()
        if args.save_motion:
            from ftacq.dynamics.motionfile import write_motion_csv

            args.save_motion.mkdir(parents=True, exist_ok=True)
            write_motion_csv(args.save_motion / "excitation.csv", record, args.model)
            write_motion_csv(args.save_motion / "jog.csv", jog_record, args.model)
        # errors during the jog (only while moving: |q̇| > 0 around the sample)
        t_sensor = jog_record.sensor_time_s - identified.lag_s
        moving_robot = np.abs(jog_record.qd).max(axis=1) > 1e-6
        moving = interpolate_rows(t_sensor, jog_record.robot_time_s, moving_robot.astype(float))[:, 0] > 0.999
        dynamics = SensorDynamics.for_calibration(model, dynamic)
        contact_dynamic = compensate_moving(dynamic, jog_record.wrench, jog_record.q, jog_record.qd, jog_record.qdd,
                                            dynamics=dynamics, sensor_time_s=t_sensor,
                                            robot_time_s=jog_record.robot_time_s)
        still = predict_moving(dynamics, dynamic, jog_record.q, np.zeros_like(jog_record.qd),
                               np.zeros_like(jog_record.qdd))
        contact_static = jog_record.wrench - interpolate_rows(t_sensor, jog_record.robot_time_s, still)
        # live monitor as its own process while the arm jogs again
        with tempfile.TemporaryDirectory() as folder:
            cal_path, cell_toml = Path(folder) / "calibration.json", Path(folder) / "CELL.toml"
            save_calibration(cal_path, dynamic)
            cell_toml.write_text(f'[robot]\nhost = "{cell.robot_host}"\nmodel = "{args.model}"\n[sensor]\nurl = "{cell.sensor_url}"\n',
                                 encoding="utf-8")
            env = dict(os.environ, PYTHONPATH=str(ROOT))
            monitor = subprocess.Popen([sys.executable, "-m", "ftacq.app.cli", "monitor", "--config", str(cell_toml),
                                        "--calibration", str(cal_path), "--seconds", str(args.monitor_s)],
                                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
            import psutil

            process = psutil.Process(monitor.pid)
            with URRobot(cell.robot_host, MotionLimits(SPEED, ACCELERATION), model=args.model) as robot:
                live_jog = jog_plan(settings, robot.joint_positions(), args.monitor_s + 5, seed=23)
                launched, first, last = time.monotonic(), None, None
                for target in live_jog.targets_rad:
                    if monitor.poll() is not None:
                        break
                    try:
                        times = process.cpu_times()
                    except psutil.NoSuchProcess:
                        break
                    sample = (times.user + times.system, time.monotonic())
                    if first is None and sample[1] - launched > 5.0:  # after start-up (imports, connections)
                        first = sample
                    last = sample
                    robot.move_joints(target, SPEED, ACCELERATION)
            out, err = monitor.communicate(timeout=60)
            cpu_fraction = (last[0] - first[0]) / max(last[1] - first[1], 1e-9) if first and last else float("nan")
            summary = [line for line in out.splitlines() if line.startswith("ftacq monitor:")]

    floor_f, floor_t = rms(noise[:3]), rms(noise[3:])
    rms_static_f, rms_static_t = rms(contact_static[moving, :3]), rms(contact_static[moving, 3:])
    rms_dyn_f, rms_dyn_t = rms(contact_dynamic[moving, :3]), rms(contact_dynamic[moving, 3:])
    error = np.linalg.norm(dynamic.inertia - truth.inertia) / np.linalg.norm(truth.inertia)
    lines.append(f"jog: {moving.sum()} moving samples at {SENSOR_RATE_HZ:g} Hz, joints up to {SPEED:g} rad/s and "
                 f"{ACCELERATION:g} rad/s² (wrist included), no contact; peak |q̇| {np.abs(jog_record.qd).max():.2f} "
                 f"rad/s, |q̈| {np.abs(jog_record.qdd).max():.2f} rad/s²")
    lines.append(f"{'':28}{'force RMS (max) N':>22}{'torque RMS (max) N·m':>26}{'× noise F':>11}{'× noise T':>11}")
    lines.append(f"{'at-rest noise (per sample)':28}{floor_f:>22.4f}{floor_t:>26.5f}{1.0:>11.2f}{1.0:>11.2f}")
    for name, contact, f, t in (("static model", contact_static, rms_static_f, rms_static_t),
                                ("dynamic model", contact_dynamic, rms_dyn_f, rms_dyn_t)):
        lines.append(f"{name:28}{f'{f:.4f} ({np.abs(contact[moving, :3]).max():.3f})':>22}"
                     f"{f'{t:.5f} ({np.abs(contact[moving, 3:]).max():.4f})':>26}{f / floor_f:>11.2f}{t / floor_t:>11.2f}")
    lines.append(f"goal: dynamic ≤ 1.5× noise -> F {'met' if rms_dyn_f <= 1.5 * floor_f else 'NOT met'}, "
                 f"T {'met' if rms_dyn_t <= 1.5 * floor_t else 'NOT met'}; static ≥ 5× noise -> "
                 f"F {'met' if rms_static_f >= 5 * floor_f else 'NOT met'}, "
                 f"T {'met' if rms_static_t >= 5 * floor_t else 'NOT met'}")
    lines.append(f"identified: inertia error {100 * error:.2f} % (Frobenius; goal ≤ 10 %), mass error "
                 f"{1e3 * (dynamic.mass_kg - truth.mass_kg):+.3f} g, centre of mass error "
                 f"{1e3 * np.linalg.norm(dynamic.center_of_mass - np.array(truth.center_of_mass_m)):.3f} mm, "
                 f"lag {1e3 * identified.lag_s:.2f} ms, condition {identified.condition_number:.3g}")
    lines.append("  inertia identified (g·m²): " + np.array2string(1e3 * dynamic.inertia, precision=4, suppress_small=True).replace("\n", ""))
    lines.append("  inertia true (g·m²):       " + np.array2string(1e3 * truth.inertia, precision=4, suppress_small=True).replace("\n", ""))
    lines.append(f"excitation stage: {excitation_s:.1f} s wall time at real-time scale (plan {plan.estimated_duration_s:.1f} s; "
                 f"goal ≤ 60 s); {len(record.sensor_time_s)} sensor and {len(record.robot_time_s)} robot samples")
    lines.append(f"simulated sensor: {cell.physics.timeline_restarts} restarts of its sample timeline, "
                 f"{getattr(cell.netft, 'skipped_backlog', 0)} records skipped by the fake (a descheduled process)")
    lines.append(f"live monitor (own process, dynamic calibration, arm jogging): CPU {100 * cpu_fraction:.1f} % of one core "
                 f"(goal < 50 %)")
    lines += ["  " + line for line in summary]
    lines += ["  " + line for line in err.splitlines() if "dynamic compensation" in line]
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
