"""``ftacq bridge``: stream the calibrated sensor into the UR controller's external F/T input (docs/bridge.md).

    ftacq bridge --config CELL.toml --calibration CAL.json [--seconds S] [--feed compensated|raw]
    ftacq bridge --config CELL.toml --calibration CAL.json --check
    ftacq bridge --sim [--seconds S] [--feed ...] [--check]

Never moves the arm. By default it uploads ur-rtde's control program (to make the enable call and set the
payload), which replaces a program running on the controller; ``--enable program`` only feeds, and prints the two
URScript lines a PolyScope program runs itself (docs/bridge.md, "From a PolyScope program").
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ftacq.bridge_convention import FEEDS
from ftacq.errors import FtacqError, InputError

SIM_SENSOR_RATE_HZ = 7000.0
SIM_REALTIME_PRIORITY = 85
"""SCHED_FIFO priority of the simulated controller and Net F/T (--sim): real ones keep their cycle whatever the
computer does; at normal priority on a busy computer the simulated controller missed 100 ms (normal scheduling
where refused)."""
SIM_PROCESS_PRIORITY = 70
"""With --sim the simulated Net F/T, its driver and the viewer share this process and its interpreter lock: all
its threads run at SCHED_FIFO 70 while feeding (the feed thread 80), so that none is preempted by other programs
while it holds the lock (at a load average of 20-30 on 2 cores the newest sample stayed over 50 ms old)."""
READOUT_PERIOD_S = 0.5


class BridgeStoppedError(FtacqError):
    """The watchdog stopped the feed (the message says why; the input was disabled)."""


class CheckFailedError(FtacqError):
    """``--check`` found the controller disagreeing with the convention."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``bridge`` sub-command."""
    parser = subparsers.add_parser(
        "bridge",
        help="feed the compensated sensor into the UR controller's external F/T input (force mode, get_tcp_force)",
        description="Read the sensor at full rate, compensate, low-pass filter and write one wrench per controller "
                    "cycle (500 Hz e-Series, 125 Hz CB3) into the controller's external F/T input, with the payload "
                    "and the enable arguments of the convention in docs/bridge.md. A watchdog stops feeding and "
                    "disables the input when the sensor goes silent, saturates or the wrench jumps. Never moves "
                    "the arm. Stop with Ctrl-C or --seconds. Run --check first on a new cell.",
        epilog="examples:\n  ftacq bridge --config cell.toml --calibration runs/<run>/calibration.json --check\n"
               "  ftacq bridge --config cell.toml --calibration runs/<run>/calibration.json\n"
               "  ftacq bridge --sim --seconds 10",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--config", type=Path, metavar="CELL.toml",
                        help="cell configuration (robot.host, robot.model, sensor.url, tool.sensor_offset_m, "
                             "tool.sensor_body_mass_kg)")
    source.add_argument("--sim", action="store_true",
                        help="the simulated cell (UR controller + Net F/T at 7 kHz on loopback); a simulated "
                             "technician jogs the arm and pushes on the tool (not with --check)")
    parser.add_argument("--calibration", type=Path, metavar="CAL.json",
                        help="calibration from ftacq calibrate / identify (required with --config; --sim uses the "
                             "simulated cell's ground truth, the tool's inertia included)")
    parser.add_argument("--feed", choices=FEEDS, default=FEEDS[0],
                        help="compensated: ftacq removes the tool's gravity; raw: the controller does, from the "
                             "payload set from the calibration (default %(default)s)")
    parser.add_argument("--enable", choices=("ur-rtde", "program"), default="ur-rtde",
                        help="who sets the payload and enables the input: ur-rtde (uploads its control program; "
                             "default) or program (your PolyScope program runs the printed URScript lines; ftacq "
                             "only feeds)")
    parser.add_argument("--seconds", type=float, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    from procedures.realtime import REALTIME_PRIORITY

    parser.add_argument("--realtime-priority", type=_priority, default=None, metavar="N",
                        help=f"real-time (SCHED_FIFO) priority of the feed thread, 1-99, 0 = normal scheduling "
                             f"(default {REALTIME_PRIORITY}; docs/bridge.md \"Timing\"; needs CAP_SYS_NICE or an "
                             "rtprio limit, else the feed runs at normal priority and says so)")
    parser.add_argument("--check", action="store_true",
                        help="with the arm still: feed known wrenches, read back actual_TCP_force and say whether "
                             "frame, signs and payload handling match the convention")
    from ftacq.app.dashboard import add_sink_args

    add_sink_args(parser)
    parser.set_defaults(func=run)


def _priority(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 0 <= value <= 99:
        raise argparse.ArgumentTypeError(f"{value} is outside 0-99 (0 = normal scheduling)")
    return value


def _load(args: argparse.Namespace, stack: contextlib.ExitStack):
    """Return (host, model name, sensor URL, calibration, sensor offset (m), sensor body mass (kg), cell or None)."""
    calibration = None
    if args.calibration is not None:
        from ftacq.calfile import load_calibration

        calibration = load_calibration(args.calibration)
    if args.sim:
        from ftacq.app.simcell import simulated_cell

        cell = stack.enter_context(simulated_cell(sensor="netft", rate_hz=SIM_SENSOR_RATE_HZ,
                                                  realtime_priority=SIM_REALTIME_PRIORITY))
        truth = cell.truth
        offset = np.asarray(getattr(truth, "sensor_offset_m", (0.0, 0.0, 0.0)), dtype=float)
        if calibration is None:  # the ground truth, tool inertia included: the jogging arm is compensated dynamically
            from ftacq.app.simcell import true_calibration

            calibration = true_calibration(truth)
        return cell.robot_host, cell.model_name, cell.sensor_url, calibration, offset, 0.0, cell
    from ftacq.app.config import load_config

    if calibration is None:
        raise InputError("ftacq bridge --config needs --calibration CAL.json (the tool the sensor carries)")
    config = load_config(args.config)
    offset = np.asarray(config.tool.sensor_offset_m or (0.0, 0.0, 0.0), dtype=float)
    if config.tool.sensor_offset_m is None:
        print(f"ftacq bridge: {args.config}: tool.sensor_offset_m is not set: assuming the sensor's measuring "
              "point is on the flange (torques about the TCP are off by the adapter's lever otherwise)",
              file=sys.stderr)
    return (config.robot.host, config.robot.model, config.sensor.url, calibration, offset,
            config.tool.sensor_body_mass_kg, None)


def run(args: argparse.Namespace) -> int:
    """Run the bridge (or --check); return 0 when it stopped as asked."""
    from drivers.robot import MotionLimits
    from drivers.ur import URRobot
    from drivers.ur_ft_input import URForceTorqueInput
    from ftacq.bridge_convention import ENABLE_EXTERNAL_FT_SENSOR, enable_function_for, plan_feed
    from ftacq.kinematics import ur_model
    from procedures.bridge import ROBOT_STATE_RATE_HZ

    if args.seconds is not None and not args.seconds > 0:
        raise InputError(f"--seconds {args.seconds}: must be a positive number of seconds")
    with contextlib.ExitStack() as stack:
        host, model_name, sensor_url, calibration, offset, body_kg, cell = _load(args, stack)
        model = ur_model(model_name)
        robot = None
        if args.enable == "ur-rtde":
            robot = URRobot(host, MotionLimits(), model=model, leave_external_ft_input=True,
                            frequency_hz=ROBOT_STATE_RATE_HZ)
            stack.callback(robot.close)
            robot.start()
        client = stack.enter_context(URForceTorqueInput(host))
        function = enable_function_for(client.version)
        flange_p_tcp = np.zeros(3)
        if function == ENABLE_EXTERNAL_FT_SENSOR:  # fed about the TCP (docs/bridge.md): where is it?
            from ftacq.kinematics import forward_kinematics

            cycle = client.next_cycle(timeout_s=1.0)
            base_T_flange = forward_kinematics(model, cycle.q)
            flange_p_tcp = base_T_flange[:3, :3].T @ (cycle.tcp_pose[:3] - base_T_flange[:3, 3])
        plan = plan_feed(calibration, args.feed, offset, sensor_body_kg=body_kg, function=function,
                         flange_p_tcp_m=flange_p_tcp)
        version = ".".join(str(v) for v in client.version or ())
        print(f"ftacq bridge: controller {host} ({model.name}, software {version}) at {client.frequency_hz:g} Hz; "
              f"feed {plan.feed}; {plan.function}(True, {plan.sensor_mass_kg:.4g} kg, "
              f"{np.round(plan.sensor_measuring_offset_m, 4).tolist()} m, {np.round(plan.sensor_cog_m, 4).tolist()} m);"
              f" payload {plan.payload_kg:.4g} kg at {np.round(plan.payload_cog_m, 4).tolist()} m", file=sys.stderr)
        if robot is None:
            print("ftacq bridge: --enable program: the PolyScope program must run, before it relies on the input "
                  "(and ftacq bridge must already be feeding: the controller pauses the program 0.1 s without "
                  "input):\n" + plan.urscript(), file=sys.stderr)
        if args.check:
            return _check(client, robot, plan, model, calibration)
        if cell is not None:
            from ftacq.app.sim_technician import SimulatedTechnician

            stack.callback(SimulatedTechnician(cell).start().close)
        return _feed(args, stack, sensor_url, client, robot, plan, calibration, model)


def _check(client, robot, plan, model, calibration) -> int:
    from ftacq import STANDARD_GRAVITY_M_S2
    from procedures.bridge_check import run_check

    gravity = np.asarray(calibration.gravity_base, dtype=float)
    gravity_base = gravity / np.linalg.norm(gravity) * STANDARD_GRAVITY_M_S2
    report = run_check(client, robot, plan, model, gravity_base)
    for line in report.lines():
        print(line)
    if not report.ok:
        raise CheckFailedError("ftacq bridge --check: the controller does not read the input as the convention says "
                               "(see the lines above)")
    return 0


def _feed(args, stack, sensor_url, client, robot, plan, calibration, model) -> int:
    from drivers.sensor import open_sensor
    from procedures.bridge import Bridge, BridgeSettings
    from procedures.realtime import softirq_advice, softirq_threads

    sensor = open_sensor(sensor_url)
    stack.callback(sensor.close)
    sensor.start()
    listeners: list = [_Readout()]
    if any(getattr(args, flag, None) for flag in ("spawn", "connect", "serve", "save")):
        from ftacq.app.dashboard import Dashboard, DashboardListener, close_recording, open_recording
        from procedures.delivery import BackgroundListener

        recording = open_recording(args)
        stack.callback(close_recording, recording)
        background = BackgroundListener([DashboardListener(Dashboard(recording, view="bridge"), model=model)])
        stack.callback(background.close)
        listeners.append(background)
    settings = BridgeSettings()
    if args.realtime_priority is not None:
        settings = replace(settings, realtime_priority=args.realtime_priority)
    bridge = Bridge(sensor, client, robot, plan, calibration, model, settings, listeners=tuple(listeners))
    if args.sim:
        from procedures.realtime import ask_realtime_all_threads

        print(f"ftacq bridge: --sim: this process's threads {ask_realtime_all_threads(SIM_PROCESS_PRIORITY)}",
              file=sys.stderr)
    advice = softirq_advice(softirq_threads())
    if advice:
        print(f"ftacq bridge: hint: {advice}", file=sys.stderr)
    print(f"ftacq bridge: sensor {sensor_url} at {bridge.sensor_rate_hz:.0f} Hz, {bridge.compensation} compensation, "
          f"low-pass {bridge.cutoff_hz:g} Hz (delay {bridge.filter.delay_s * 1000:.1f} ms); feeding (Ctrl-C to stop)",
          file=sys.stderr)
    summary = bridge.run(duration_s=args.seconds)
    print(summary_line(summary))
    if summary.trip:
        state = ("disabled" if summary.disabled else "left to the controller") if summary.enabled else \
            "left to the program" if robot is None else "never enabled"
        raise BridgeStoppedError(f"the watchdog stopped the feed: {summary.trip}; nothing more was written and the "
                                 f"external input is {state}")
    return 0


def summary_line(summary) -> str:
    """The run's last line: what was fed while the input was enabled (procedures.bridge.BridgeSummary)."""
    head = (f"ftacq bridge: {summary.written} values written in {summary.cycles} controller cycles over "
            f"{summary.duration_s:.1f} s")
    if summary.skipped_at_start:
        head += f" ({summary.skipped_at_start} cycles queued before the feed began skipped)"
    tail = f"; feed thread {summary.feed_priority}; filter delay {summary.filter_delay_s * 1000:.1f} ms"
    if not np.isfinite(summary.enabled_from_s):
        return (f"{head}; the external input was never enabled" + tail
                + ("; stopped by Ctrl-C" if summary.interrupted else ""))
    staleness = summary.staleness_s(while_enabled=True)
    if len(staleness):
        p50, p99 = np.percentile(staleness, [50, 99]) * 1000
        newest = f" (the newest {len(staleness)})" if len(summary.log) < summary.cycles else ""
        ages = (f"newest sample age at write p50 {p50:.1f} ms, p99 {p99:.1f} ms{newest}, max "
                f"{summary.max_sample_age_s * 1000:.1f} ms")
    else:
        ages = "no sample age (nothing written)"
    if summary.enabled:
        state = "disabled" if summary.disabled else "NOT disabled (the controller pauses the program by itself)"
    else:
        state = "left to the program"
    return (f"{head}; while the input was enabled: {summary.enabled_written} values in {summary.enabled_cycles} "
            f"cycles, answered later than one cycle: {summary.late_answers}, {ages}{tail}; external input {state}"
            + ("; stopped by Ctrl-C" if summary.interrupted else ""))


class _Readout:
    """A one-line live readout on stderr about twice a second (cycles, |F|, |T| fed)."""

    def __init__(self) -> None:
        self._last_s = 0.0
        self._lock = threading.Lock()
        self.cycles = 0

    def __call__(self, event) -> None:
        from procedures.events import FedWrenches, Notice

        if isinstance(event, Notice):
            print(f"ftacq bridge: {event.text}", file=sys.stderr)
            return
        if not isinstance(event, FedWrenches) or not len(event.fed):
            return
        with self._lock:
            self.cycles += event.cycles
            now = time.monotonic()
            if now - self._last_s < READOUT_PERIOD_S:
                return
            self._last_s = now
        fed = event.fed[-1]
        print(f"  fed |F| {np.linalg.norm(fed[:3]):6.2f} N  |T| {np.linalg.norm(fed[3:]):6.3f} N·m  "
              f"({self.cycles} cycles)", file=sys.stderr)
