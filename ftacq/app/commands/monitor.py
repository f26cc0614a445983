"""``ftacq monitor``: stream raw and gravity-compensated wrenches, the arm and sensor health to Rerun.

    ftacq monitor --config CELL.toml --calibration CALIBRATION.json [viewer flags] [--seconds S]
                  [--record FILE.csv|FILE.mcap] [--ros2 [--ros2-namespace NS] [--ros2-domain-id N] …]
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
from pathlib import Path
from typing import TYPE_CHECKING


from ftacq.app.helptext import examples
from ftacq.app.sim_technician import SIM_WARMUP_TAU_S

if TYPE_CHECKING:
    from procedures.dynamic_compensation import DynamicCompensator
    from procedures.static_compensation import StaticCompensator

def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``monitor`` sub-command."""
    from ftacq.app.dashboard.sinks import add_sink_args

    parser = subparsers.add_parser(
        "monitor",
        help="stream raw and compensated wrenches to the live Rerun dashboard",
        description="Stream the sensor at full rate, compensate gravity with the robot's latest orientation and "
                    "show raw and compensated wrenches, the arm in 3-D and sensor health in Rerun. Reads the "
                    "robot, never moves it. Stop with Ctrl-C or --seconds.",
        **examples("ftacq monitor --sim --seconds 20 --ros2 --record monitor.mcap",
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
    parser.add_argument("--model",
                        help="with --sim: the simulated UR model (default UR5e; a CB3 one streams at 125 Hz)")
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
                        help="also write the samples (raw, flange pose, compensated) to this CSV (thinned to fit "
                             "1 GB/h: --record-rate); FILE.mcap: a ROS 2 bag of the --ros2 messages, the joint states "
                             "and the calibration (docs/ros2.md)")
    add_sink_args(parser)
    from ftacq.app.file_budget import add_budget_args

    add_budget_args(parser)
    from ftacq.app.ros2_outputs import add_ros2_args

    add_ros2_args(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the monitor; return 0 when it stopped as asked (--seconds or Ctrl-C). A client of the Python API's
    session (:func:`ftacq.app.session.open_cell`) with the dashboard and the live readout as listeners."""
    from ftacq import __version__
    from ftacq.app.dashboard import Dashboard, DashboardListener, close_recording, open_recording
    from ftacq.app.readout import LiveReadout, format_summary
    from ftacq.app.ros2_outputs import check_ros2_args, is_bag, prefer_low_latency, ros2_listeners
    from ftacq.app.session import SimOptions, open_cell
    from ftacq.errors import InputError
    from ftacq.validation import check_number, check_output_file

    if args.seconds is not None:
        check_number(args.seconds, "--seconds", low=0.0, low_exclusive=True)
    # output paths before any device is opened: a run whose record cannot be kept does not start
    if args.record is not None:
        check_output_file(args.record, "--record")
    if getattr(args, "save", None) is not None:
        check_output_file(args.save, "--save")
    check_ros2_args(args)
    if args.model is not None:
        if not args.sim:
            raise InputError(f"--model {args.model}: only with --sim (CELL.toml's robot.model names a real cell's arm)")
        from ftacq.kinematics import ur_model

        try:
            args.model = ur_model(args.model).name
        except ValueError as error:
            raise InputError(f"--model: {error}") from None
    sim = SimOptions(jog=not args.sim_still, drift_n_per_h=args.sim_drift, warmup_n_per_h=args.sim_warmup,
                     swap_tool_after_s=args.sim_swap_tool, model=args.model) if args.sim else False
    with contextlib.ExitStack() as stack:
        viewer: list[DashboardListener] = []
        ros2_reports: list[list[str]] = []

        def open_viewer(cell):
            """The viewer first (spawning one takes seconds): the sensor's samples are counted from its start."""
            recording = open_recording(args)
            stack.callback(close_recording, recording)
            dashboard = DashboardListener(Dashboard(recording), model=cell.model)
            dashboard.set_calibration(cell.calibration)
            cell.add_listener(dashboard)
            viewer.append(dashboard)
            listeners, report = ros2_listeners(args, stack, lambda: cell.calibration,
                                               cell.tare if cell.calibration is not None else None,
                                               lambda: cell.sensor_rate_hz)
            for listener in listeners:  # --ros2, --record X.mcap
                cell.add_listener(listener)
            ros2_reports.append(report)  # filled as the stack closes

            def before_start() -> None:  # the sensor is open (its rate known) and about to stream
                from ftacq.app.dashboard.sinks import is_saved
                from ftacq.app.file_budget import apply_save_budget

                for line in apply_save_budget(args, cell.sensor_rate_hz, dashboard.dashboard, is_saved(recording)):
                    print(f"ftacq monitor: {line}", file=sys.stderr)
                dashboard.dashboard.start_clock()  # the time axis starts with the sensor's stream
            return before_start

        cell = stack.enter_context(open_cell(args.config, calibration=args.calibration, sim=sim,
                                             record=None if is_bag(args.record) else args.record,
                                             record_rate_hz=args.record_rate, auto_tare=args.auto_tare, force=args.force, who="ftacq monitor",
                                             prepare=open_viewer))
        dashboard = viewer[0]
        if args.ros2:  # each sample published as soon as it can be (reads on data, no wait for robot states)
            prefer_low_latency(cell, args.ros2_read_period)
        for note in cell.notes:
            print(f"ftacq monitor: {note}", file=sys.stderr)
        if cell.drift_text is not None:
            dashboard.dashboard.log_text(cell.drift_text)
        dashboard.dashboard.log_text(
            f"ftacq {__version__} monitor: {cell.source}, sensor {cell.sensor_url}, robot {cell.robot_host} "
            f"({cell.model.name}), " + ("compensating" if cell.calibration is not None else "no calibration: raw only"))
        if cell.calibration is None:
            print("ftacq monitor: no --calibration given: showing raw wrenches only", file=sys.stderr)
        readout = LiveReadout()
        stack.callback(readout.close)
        cell.add_listener(readout)
        summary = cell.run(args.seconds)
        readout.close()
        dashboard.flush()
        dashboard.dashboard.log_text(f"monitor stopped: {summary.samples} samples, {summary.lost} lost, "
                                     f"{summary.dropped_samples} dropped for the viewer")
    print(format_summary(summary))
    for line in (line for report in ros2_reports for line in report):
        print(line)
    compensator, live = cell.drift, cell.compensator
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
