"""``ftacq monitor``: stream raw and gravity-compensated wrenches, the arm and sensor health to Rerun.

    ftacq monitor --config CELL.toml --calibration CALIBRATION.json [viewer flags] [--seconds S] [--record FILE.csv]
    ftacq monitor --sim [viewer flags] [--seconds S] [--sim-drift N_PER_H] [--sim-warmup N_PER_H]
                  [--sim-swap-tool S] [--auto-tare]

The monitor only reads the robot (its state, at the reader's own rate); it never moves it. With a calibration it
checks that the calibration belongs to the sensor (refused unless --force) and runs the live drift tracker and the
at-rest check (procedures/bias_health.py); --auto-tare applies the tracked bias offset.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ftacq.app.helptext import examples

if TYPE_CHECKING:
    from ftacq.dynamics.clock import SampleClock
    from procedures.bias_health import DriftCompensator
    from procedures.dynamic_compensation import DynamicCompensator
    from procedures.monitor import HealthCheck
    from procedures.static_compensation import StaticCompensator

DEFAULT_SIM_MODEL = "UR5e"
FIRST_STATE_TIMEOUT_S = 1.0
"""Longest wait for the RTDE state stream's first package before the sensor starts, s (samples before it are left
uncompensated: no pose of their time)."""
SIM_SENSOR_RATE_HZ = 7000.0
SIM_JOG_RATE_HZ = 30.0
"""How often the simulated technician looks at the clock (pushes, tool swap, the next jog)."""
SIM_JOG_AMPLITUDE_RAD = np.array([0.35, 0.15, 0.2, 0.7, 0.7, 1.2])
"""Peak joint excursions (rad) of the simulated technician's jog around the start configuration."""
SIM_JOG_SPEED_RAD_S, SIM_JOG_ACCELERATION_RAD_S2 = 0.8, 2.0
"""The simulated technician jogs with moveJ moves from the pendant (the controller's motion profile), so the simulated
sensor reads the tool's inertial wrench as on a real arm."""
SIM_JOG_TARGETS = (1.0, -0.6, 0.3, -1.0, 0.6, -0.3)
"""The jog visits start + f × SIM_JOG_AMPLITUDE_RAD for these f in turn."""
SIM_PHASE_S = 8.0
"""The simulated technician jogs for this long, then holds the arm still for as long (the drift tracker learns only
while the arm is still)."""
SIM_CONTACT_START_S = 3.0
SIM_CONTACT_DURATION_S = 2.0
SIM_CONTACT_WRENCH = np.array([0.0, 6.0, -15.0, 0.3, 0.0, 0.0])
"""The simulated push on the tool (sensor frame, N and N·m), SIM_CONTACT_START_S into every still phase, held
SIM_CONTACT_DURATION_S with a hand's 5 % tremble at 4 Hz."""
SIM_WARMUP_TAU_S = 600.0
"""--sim-warmup: the simulated sensor's warm-up time constant, s (ATI asks for a 30 min warm-up: about 3 τ)."""
SIM_SWAPPED_TOOL = (1.0, (0.01, -0.005, 0.05))
"""--sim-swap-tool puts this tool (kg, centre of mass in the sensor frame, m) on the simulated sensor."""


class SimulatedTechnician:
    """Jogs the simulated arm, holds it still, pushes on the tool, and (``swap_after_s``) swaps the tool, through
    the simulator's own back door (``--sim`` only).

    On a real cell the technician jogs the arm from the pendant; the monitor itself never moves the robot.
    Owns the thread "ftacq-sim-technician" (started by :meth:`start`, joined by :meth:`close`).
    """

    def __init__(self, cell, period_s: float = 1.0 / SIM_JOG_RATE_HZ, jog: bool = True,
                 swap_after_s: float | None = None) -> None:
        self.cell = cell
        self.period_s = period_s
        self.jog = jog
        self.swap_after_s = swap_after_s
        self.swapped = False
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ftacq-sim-technician")

    def start(self) -> "SimulatedTechnician":
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop jogging, remove the push, join the thread."""
        self._stop.set()
        self._thread.join()
        self.cell.set_contact(np.zeros(6))

    def _run(self) -> None:
        q_start = np.asarray(self.cell.initial_q, dtype=float)
        start_s = time.monotonic()
        next_s = start_s
        move, move_end_s, q_now = 0, 0.0, q_start
        while not self._stop.wait(max(0.0, next_s - time.monotonic())):
            next_s += self.period_s
            t = time.monotonic() - start_s
            try:
                if self.swap_after_s is not None and not self.swapped and t >= self.swap_after_s:
                    self.cell.swap_tool(*SIM_SWAPPED_TOOL)
                    self.swapped = True
                if not self.jog:
                    continue
                phase_s = t % (2 * SIM_PHASE_S)
                if phase_s < SIM_PHASE_S:  # jogging: the next move if the previous one is over and this one fits
                    self.cell.set_contact(np.zeros(6))
                    if t < move_end_s:
                        continue
                    target = q_start + SIM_JOG_TARGETS[move % len(SIM_JOG_TARGETS)] * SIM_JOG_AMPLITUDE_RAD
                    if phase_s + jog_duration_s(q_now, target) <= SIM_PHASE_S:
                        move_end_s = t + self.cell.controller.jog(target, SIM_JOG_SPEED_RAD_S,
                                                                  SIM_JOG_ACCELERATION_RAD_S2)
                        q_now, move = target, move + 1
                else:  # holding still; a hand pushes on the tool for a while
                    hold_s = phase_s - SIM_PHASE_S
                    pushing = SIM_CONTACT_START_S <= hold_s < SIM_CONTACT_START_S + SIM_CONTACT_DURATION_S
                    tremble = 1.0 + 0.05 * np.sin(2 * np.pi * 4.0 * t)
                    self.cell.set_contact(SIM_CONTACT_WRENCH * tremble if pushing else np.zeros(6))
            except Exception as error:  # noqa: BLE001 - the demo stops jogging; the monitor goes on
                self.error = error
                return


def jog_duration_s(q_from: np.ndarray, q_to: np.ndarray) -> float:
    """Duration (s) of a moveJ with the simulated technician's speed and acceleration (trapezoid or triangle)."""
    length = float(np.max(np.abs(np.asarray(q_to) - np.asarray(q_from))))
    v, a = SIM_JOG_SPEED_RAD_S, SIM_JOG_ACCELERATION_RAD_S2
    return length / v + v / a if length >= v * v / a else 2.0 * np.sqrt(length / a)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``monitor`` sub-command."""
    from ftacq.app.dashboard.sinks import add_sink_args

    parser = subparsers.add_parser(
        "monitor",
        help="stream raw and compensated wrenches to the live Rerun dashboard",
        description="Stream the sensor at full rate, compensate gravity with the robot's latest orientation and "
                    "show raw and compensated wrenches, the arm in 3-D and sensor health in Rerun. Reads the "
                    "robot, never moves it. Stop with Ctrl-C or --seconds.",
        **examples("ftacq monitor --sim --seconds 20",
                   "ftacq monitor --config CELL.toml --calibration runs/20260101-120000/calibration.json",
                   "ftacq monitor --config CELL.toml --calibration calibration.json --record monitor.csv --seconds 60"),
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--config", type=Path, metavar="CELL.toml",
                        help="cell configuration (robot.host, robot.model, sensor.url)")
    source.add_argument("--sim", action="store_true",
                        help="run against the simulated cell (UR controller + Net F/T at 7 kHz on loopback); a "
                             "simulated technician jogs the arm and pushes on the tool every 8 s")
    parser.add_argument("--calibration", type=Path, metavar="CALIBRATION.json",
                        help="calibration from `ftacq calibrate`/`ftacq identify` (needed for compensation with "
                             "--config; --sim defaults to the simulated cell's ground truth)")
    parser.add_argument("--seconds", type=float, metavar="S",
                        help="stop after S seconds (default: run until Ctrl-C)")
    parser.add_argument("--sim-still", action="store_true", help="with --sim: leave the simulated arm still")
    parser.add_argument("--sim-drift", type=float, default=0.0, metavar="N_PER_H",
                        help="with --sim: the simulated sensor's force biases drift by this much per hour (N/h; "
                             "torque 1/50 of it in N·m/h)")
    parser.add_argument("--sim-warmup", type=float, default=0.0, metavar="N_PER_H",
                        help="with --sim: the simulated sensor warms up from power-on: its force biases move as "
                             f"A (1 − e^(−t/τ)), τ {SIM_WARMUP_TAU_S / 60:g} min, starting at this rate (N/h; A = "
                             "rate × τ; torque 1/30 of it in N·m/h)")
    parser.add_argument("--sim-swap-tool", type=float, metavar="S",
                        help="with --sim: after S seconds put another tool on the simulated sensor without telling "
                             "the software (the at-rest warning should follow at the next stillness)")
    parser.add_argument("--auto-tare", action="store_true",
                        help="subtract the live drift tracker's bias estimate from the compensated stream (off by "
                             "default: the tracker then only reports; see docs/drift-and-tare.md)")
    parser.add_argument("--force", action="store_true",
                        help="monitor even when the calibration was made with another sensor (serial, units or "
                             "counts per unit differ)")
    parser.add_argument("--record", type=Path, metavar="FILE.csv",
                        help="also write every sample (raw, flange pose, compensated) to this CSV")
    add_sink_args(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the monitor; return 0 when it stopped as asked (--seconds or Ctrl-C)."""
    from drivers.sensor import open_sensor
    from drivers.ur import URStateReader
    from ftacq import __version__
    from ftacq.app.dashboard import Dashboard, DashboardListener, close_recording, open_recording
    from ftacq.app.readout import LiveReadout, format_summary
    from ftacq.dynamics.clock import SampleClock
    from ftacq.kinematics import ur_model
    from procedures.monitor import LiveMonitor

    from ftacq.validation import check_number, check_output_file

    if args.seconds is not None:
        check_number(args.seconds, "--seconds", low=0.0, low_exclusive=True)
    # output paths before any device is opened: a run whose record cannot be kept does not start
    if args.record is not None:
        check_output_file(args.record, "--record")
    if getattr(args, "save", None) is not None:
        check_output_file(args.save, "--save")
    with contextlib.ExitStack() as stack:
        calibration = None
        if args.calibration is not None:
            from ftacq.calfile import load_calibration

            calibration = load_calibration(args.calibration)
        if args.sim:
            from ftacq.app.simcell import simulated_cell

            from ftacq.app.simcell import simulated_truth

            drift_n_per_s = args.sim_drift / 3600.0
            warmup_n = args.sim_warmup / 3600.0 * SIM_WARMUP_TAU_S
            truth = simulated_truth(drift_n_per_s=(drift_n_per_s, -drift_n_per_s, drift_n_per_s),
                                    drift_nm_per_s=(drift_n_per_s / 50, -drift_n_per_s / 50, drift_n_per_s / 50),
                                    thermal_step_n=(warmup_n, -warmup_n, warmup_n),
                                    thermal_step_nm=(warmup_n / 30, -warmup_n / 30, warmup_n / 30),
                                    thermal_step_at_s=0.0, thermal_time_constant_s=SIM_WARMUP_TAU_S)
            cell = stack.enter_context(simulated_cell(truth=truth, sensor="netft", rate_hz=SIM_SENSOR_RATE_HZ))
            robot_host, sensor_url = cell.robot_host, cell.sensor_url
            model_name = getattr(cell, "model_name", DEFAULT_SIM_MODEL)
            if calibration is None:
                calibration = cell.truth.calibration()
            source = "simulated cell"
        else:
            from ftacq.app.config import load_config

            config = load_config(args.config)
            robot_host, model_name, sensor_url = config.robot.host, config.robot.model, config.sensor.url
            source = str(args.config)
        model = ur_model(model_name)

        # the viewer first (spawning one takes seconds): the sensor's samples are counted from its start
        recording = open_recording(args)
        stack.callback(close_recording, recording)
        dashboard = DashboardListener(Dashboard(recording), model=model)
        dashboard.set_calibration(calibration)

        sensor = open_sensor(sensor_url)
        stack.callback(sensor.close)
        robot = URStateReader(robot_host, model=model)
        stack.callback(robot.close)
        robot.start()
        if args.sim and (not args.sim_still or args.sim_swap_tool is not None):
            stack.callback(SimulatedTechnician(cell, jog=not args.sim_still,
                                               swap_after_s=args.sim_swap_tool).start().close)
        live = None
        sample_clock = SampleClock()  # one sensor clock for the record and the compensation
        if calibration is not None:  # its state stream before the sensor's: the first samples have states around them
            live = _choose_compensator(calibration, model, robot_host, stack, sample_clock)
        dashboard.dashboard.start_clock()  # the time axis starts with the sensor's stream
        sensor.start()
        compensator: DriftCompensator | None = None
        checks: list[HealthCheck] = []
        if calibration is not None:
            compensator, checks, health_text = _drift_health(calibration, sensor.info, args)
            print(f"ftacq monitor: {health_text}", file=sys.stderr)
            dashboard.dashboard.log_text(health_text)

        dashboard.dashboard.log_text(
            f"ftacq {__version__} monitor: {source}, sensor {sensor_url}, robot {robot_host} ({model.name}), "
            + ("compensating" if calibration is not None else "no calibration: raw only"))
        if calibration is None:
            print("ftacq monitor: no --calibration given: showing raw wrenches only", file=sys.stderr)
        header = [f"ftacq {__version__} monitor recording", f"source: {source}", f"sensor: {sensor_url}",
                  f"robot: {robot_host} ({model.name})",
                  f"calibration: {args.calibration or ('simulated cell ground truth' if args.sim else 'none')}",
                  "units: s, N, N·m, m, rad; wrenches in the sensor frame, pose = base_T_flange",
                  "times: time_s = receive time; sample_time_s = the sensor's own clock (device_time_s) on the host "
                  "monotonic clock through the minimum-delay line, clock_uncertainty_s its uncertainty "
                  "(docs/dynamics.md, How the clocks are aligned)"]
        readout = LiveReadout()
        stack.callback(readout.close)
        if compensator is not None:  # (the drift compensator: built above with the calibration)
            compensator.moving = live  # the drift tracker's compensation, with the robot's state at the samples' time
        monitor = LiveMonitor(sensor, robot=robot,
                              compensator=compensator, checks=checks,
                              listeners=[dashboard, readout], record_path=args.record, record_header=header,
                              sample_clock=sample_clock)
        summary = monitor.run(duration_s=args.seconds)
        readout.close()
        dashboard.flush()
        dashboard.dashboard.log_text(f"monitor stopped: {summary.samples} samples, {summary.lost} lost, "
                                     f"{summary.dropped_samples} dropped for the viewer")
    print(format_summary(summary))
    if compensator is not None and hasattr(compensator, "health"):
        print(format_drift(compensator))
    if live is not None and (live.uncompensated_batches or getattr(live, "static_batches", 0)
                             or getattr(live, "held_samples", 0) or getattr(live, "catch_up_batches", 0)
                             or getattr(live, "waits", 0)):
        print(_compensation_summary(live))
    return 0


def _compensation_summary(live: DynamicCompensator | StaticCompensator) -> str:
    """A line on the reads that were not compensated as the calibration allows (dynamic fallbacks, none at all)."""
    from procedures.static_compensation import StaticCompensator

    uncompensated = (f"{live.uncompensated_batches} had no robot state near their samples and were left "
                     "uncompensated (empty contact columns in the record)")
    if isinstance(live, StaticCompensator):
        total = live.compensated_batches + live.uncompensated_batches
        return f"static compensation: of {total} reads, {uncompensated}"
    total = live.static_batches + live.uncompensated_batches + live.dynamic_batches
    return (f"dynamic compensation: {live.catch_up_batches} of {total} reads were older than the kept predictions "
            f"and were predicted from the robot states of their time; {live.static_batches} fell outside the robot "
            f"states and were compensated statically (pose at the samples' time); {uncompensated}; {live.held_samples} samples "
            f"were newer than the newest robot state (its prediction held for them; up to "
            f"{1e3 * live.held_max_s:.1f} ms ahead); {live.waits} reads waited for the robot states of their time "
            f"(longest {1e3 * live.waited_max_s:.1f} ms, {live.wait_timeouts} in vain)")


def _choose_compensator(calibration, model, robot_host: str, stack: contextlib.ExitStack,
                        sample_clock: SampleClock) -> DynamicCompensator | StaticCompensator:
    """The live compensator on its own RTDE state stream (every state, on the host clock through the controller's
    own clock), saying which on stderr: the dynamic one when the calibration has inertia, else the static one; both
    compensate each sample with the robot's state at its time (the sensor's clock: ``sample_clock``, shared with the
    record) and leave a batch uncompensated when no state is near it."""
    from drivers.ur_stream import URStateStream

    stream = URStateStream(robot_host)
    stack.callback(stream.close)
    stream.start()
    stream.wait_for_samples(1, FIRST_STATE_TIMEOUT_S)  # a controller still silent then: its samples come later
    if not calibration.has_dynamics:
        from procedures.static_compensation import StaticCompensator

        print("ftacq monitor: static compensation (the pose at each sample's time): this calibration has no inertia, "
              "so the wrench is exact only while the arm is still (run ftacq calibrate --dynamic to identify the "
              "tool's inertia)", file=sys.stderr)
        return StaticCompensator(calibration, model, stream, clock=sample_clock)
    from procedures.dynamic_compensation import STATE_WAIT_S, DynamicCompensator

    compensator = DynamicCompensator(calibration, model, stream, clock=sample_clock, state_wait_s=STATE_WAIT_S)
    print(f"ftacq monitor: dynamic compensation (tool inertia from the calibration; sensor lag "
          f"{1e3 * compensator.lag_s:.2f} ms): acceleration from target_qdd {1e3 * compensator.servo_lag_s:.2f} ms "
          "earlier (the arm's lag behind its target) while the arm follows the controller's trajectory, else a "
          "filtered derivative of actual_qd", file=sys.stderr)
    return compensator


def _drift_health(calibration, sensor_info,
                  args: argparse.Namespace) -> tuple[DriftCompensator, list[HealthCheck], str]:
    """Check the calibration belongs to the sensor (refused unless --force) and build the drift tracker's
    compensator and health check; return (compensator, checks, a line saying when the biases were measured)."""
    from ftacq.drift import MAX_PRIOR_AGE_S
    from ftacq.drift_health import BiasHealth
    from ftacq.provenance import age_s, biases_measured_utc, require_same_sensor
    from procedures.bias_health import DriftCheck, DriftCompensator

    note = require_same_sensor(calibration, sensor_info, args.force, "ftacq monitor")
    if note:
        print(f"ftacq monitor: {note}", file=sys.stderr)
    measured = biases_measured_utc(calibration)
    age = age_s(measured)
    health = BiasHealth(calibration, age_s=MAX_PRIOR_AGE_S if age is None else age, auto_tare=args.auto_tare)
    compensator = DriftCompensator(health)
    history = calibration.metadata.get("bias_history") or []
    method = history[-1].get("method", "calibration") if history else "calibration"
    text = (f"biases from {method}, measured {measured or 'at an unknown time'}"
            + (f" ({age / 3600.0:.1f} h ago)" if age is not None else " (the first rest windows set the offset)")
            + f"; drift tracker on, {'applied (--auto-tare)' if args.auto_tare else 'reporting only'}")
    return compensator, [DriftCheck(compensator)], text


def format_drift(compensator) -> str:
    """Return the tracker's last word: offset since the file ± 1σ, rate, windows used and refused."""
    tracker = compensator.health.tracker
    if not tracker.accepted:
        return (f"drift tracker: no estimate: {tracker.rejected_contact} rest windows refused as contact, "
                f"{tracker.rejected_gate} by the gate" if tracker.rejected_contact + tracker.rejected_gate else
                "drift tracker: no estimate: the arm was never still long enough (0.5 s settle + 0.5 s windows)")
    from ftacq.sigma_text import format_with_sigma

    offset, sigma = tracker.offset(tracker.time_s), tracker.sigma(tracker.time_s)
    return ("drift tracker: biases moved since the calibration file by F ["
            + ", ".join(format_with_sigma(o, s) for o, s in zip(offset[:3], sigma[:3])) + "] N, T ["
            + ", ".join(format_with_sigma(o, s) for o, s in zip(offset[3:], sigma[3:])) + "] N·m; rate F ["
            + ", ".join(f"{r:+.3f}" for r in tracker.rate_per_h[:3]) + f"] N/h; rest windows used {tracker.accepted},"
            f" refused as contact {tracker.rejected_contact}, by the gate {tracker.rejected_gate}"
            + (f", re-acquired {tracker.reacquired}×" if tracker.reacquired else "")
            + ("; a step stands against it (not drift: check the tool, then `ftacq tare`)" if tracker.step else "")
            + (("; applied (--auto-tare)" if compensator.health.trusted else
                f"; not applied now (--auto-tare suspended: {compensator.health.distrust_reason})")
               if compensator.health.auto_tare else "; not applied (use --auto-tare, or `ftacq tare`)"))
