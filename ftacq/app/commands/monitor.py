"""``ftacq monitor``: stream raw and gravity-compensated wrenches, the arm and sensor health to Rerun.

    ftacq monitor --config CELL.toml --calibration CALIBRATION.json [viewer flags] [--seconds S] [--record FILE.csv]
    ftacq monitor --sim [viewer flags] [--seconds S]

The monitor only reads the robot (its state, at the reader's own rate); it never moves it.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import threading
import time
from pathlib import Path

import numpy as np

from ftacq.errors import InputError

DEFAULT_SIM_MODEL = "UR5e"
SIM_SENSOR_RATE_HZ = 7000.0
SIM_JOG_RATE_HZ = 30.0
SIM_JOG_AMPLITUDE_RAD = np.array([0.35, 0.15, 0.2, 0.7, 0.7, 1.2])
"""Peak joint excursions (rad) of the simulated technician's jog around the start configuration."""
SIM_JOG_PERIOD_S = np.array([23.0, 17.0, 19.0, 11.0, 7.0, 13.0])
SIM_CONTACT_EVERY_S = 8.0
SIM_CONTACT_DURATION_S = 2.0
SIM_CONTACT_WRENCH = np.array([0.0, 6.0, -15.0, 0.3, 0.0, 0.0])
"""The simulated push on the tool (sensor frame, N and N·m) every SIM_CONTACT_EVERY_S seconds."""


class SimulatedTechnician:
    """Jogs the simulated arm and pushes on the tool, through the simulator's own back door (``--sim`` only).

    On a real cell the technician jogs the arm from the pendant; the monitor itself never moves the robot.
    Owns the thread "ftacq-sim-technician" (started by :meth:`start`, joined by :meth:`close`).
    """

    def __init__(self, cell, period_s: float = 1.0 / SIM_JOG_RATE_HZ) -> None:
        self.cell = cell
        self.period_s = period_s
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
        while not self._stop.wait(max(0.0, next_s - time.monotonic())):
            next_s += self.period_s
            t = time.monotonic() - start_s
            try:
                self.cell.controller.set_joint_positions(
                    q_start + SIM_JOG_AMPLITUDE_RAD * np.sin(2 * np.pi * t / SIM_JOG_PERIOD_S))
                pushing = (t % SIM_CONTACT_EVERY_S) > SIM_CONTACT_EVERY_S - SIM_CONTACT_DURATION_S
                self.cell.set_contact(SIM_CONTACT_WRENCH if pushing else np.zeros(6))
            except Exception as error:  # noqa: BLE001 - the demo stops jogging; the monitor goes on
                self.error = error
                return


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``monitor`` sub-command."""
    from ftacq.app.dashboard.sinks import add_sink_args

    parser = subparsers.add_parser(
        "monitor",
        help="stream raw and compensated wrenches to the live Rerun dashboard",
        description="Stream the sensor at full rate, compensate gravity with the robot's latest orientation and "
                    "show raw and compensated wrenches, the arm in 3-D and sensor health in Rerun. Reads the "
                    "robot, never moves it. Stop with Ctrl-C or --seconds.",
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
    from ftacq.kinematics import ur_model
    from procedures.monitor import GravityCompensator, LiveMonitor

    if args.seconds is not None and not args.seconds > 0:
        raise InputError(f"--seconds {args.seconds}: must be a positive number of seconds")
    with contextlib.ExitStack() as stack:
        calibration = None
        if args.calibration is not None:
            from ftacq.calfile import load_calibration

            calibration = load_calibration(args.calibration)
        if args.sim:
            from ftacq.app.simcell import simulated_cell

            cell = stack.enter_context(simulated_cell(sensor="netft", rate_hz=SIM_SENSOR_RATE_HZ))
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
        if args.sim and not args.sim_still:
            stack.callback(SimulatedTechnician(cell).start().close)
        sensor.start()

        dashboard.dashboard.log_text(
            f"ftacq {__version__} monitor: {source}, sensor {sensor_url}, robot {robot_host} ({model.name}), "
            + ("compensating" if calibration is not None else "no calibration: raw only"))
        if calibration is None:
            print("ftacq monitor: no --calibration given: showing raw wrenches only", file=sys.stderr)
        header = [f"ftacq {__version__} monitor recording", f"source: {source}", f"sensor: {sensor_url}",
                  f"robot: {robot_host} ({model.name})",
                  f"calibration: {args.calibration or ('simulated cell ground truth' if args.sim else 'none')}",
                  "units: s, N, N·m, m, rad; wrenches in the sensor frame, pose = base_T_flange"]
        readout = LiveReadout()
        stack.callback(readout.close)
        monitor = LiveMonitor(sensor, robot=robot,
                              compensator=GravityCompensator(calibration) if calibration is not None else None,
                              listeners=[dashboard, readout], record_path=args.record, record_header=header)
        summary = monitor.run(duration_s=args.seconds)
        readout.close()
        dashboard.flush()
        dashboard.dashboard.log_text(f"monitor stopped: {summary.samples} samples, {summary.lost} lost, "
                                     f"{summary.dropped_samples} dropped for the viewer")
    print(format_summary(summary))
    return 0
