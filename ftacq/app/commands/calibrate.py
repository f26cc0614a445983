"""``ftacq calibrate``: plan, check, confirm, move, settle, average, record; identify, validate, report.

    ftacq calibrate --config CELL.toml [--dry-run] [--yes] [--resume RUN_DIR] [--out DIR] [viewer flags]
    ftacq calibrate --sim [--sensor netft|can] [--dry-run] [--yes] [--resume RUN_DIR] [--out DIR] [--time-scale X]

The robot never moves without a checked plan that the user confirmed (``--yes`` confirms in advance; without a
terminal on stdin and without ``--yes`` the command refuses to move). ``--dry-run`` prints the plan and moves
nothing. Every measured pose is kept in the run folder; an interrupted or failed run ends with the command that
resumes it. Exit status: 0 done, 1 fault (data kept), 2 bad input, 130 interrupted (data kept).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from ftacq.app.dashboard.sinks import add_sink_args
from ftacq.app.confirm import confirm_motion
from ftacq.fit_options import DRIFT_MODELS
from ftacq.app.helptext import examples
from ftacq.errors import AbortedError, InputError, InterruptedByUser
from ftacq.mounts import MOUNT_FORMS, MOUNTS

if TYPE_CHECKING:
    from procedures.events import Listener

log = logging.getLogger(__name__)

DEFAULT_SIM_TIME_SCALE = 10.0
"""--sim runs the simulated controller this many times faster than real time (the plan shows real time)."""
SIM_MIN_AVERAGE_TIME_S = 0.1
SIM_MIN_SETTLE_WINDOW_S = 0.02


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``calibrate`` sub-command."""
    parser = subparsers.add_parser(
        "calibrate", help="run the calibration procedure (plan, move, measure, identify, validate)",
        description="Plan and check the pose set, print it, ask for confirmation, move the robot through it "
                    "(moveJ at the configured speed and acceleration), average the sensor at each still pose, "
                    "then identify and validate the calibration. Writes RUN_DIR/poses.csv (one row per pose, "
                    "as measured), run.json, calibration.json and report.md. Ctrl-C stops the robot and keeps "
                    "the data; resume with --resume RUN_DIR.",
        **examples("ftacq calibrate --sim --yes  # the whole procedure on the simulated cell",
                   "ftacq calibrate --config CELL.toml --dry-run  # print the checked plan, move nothing",
                   "ftacq calibrate --resume runs/20260101-120000  # finish a stopped run"))
    parser.add_argument("--config", type=Path, metavar="CELL.toml",
                        help="cell configuration (ftacq config init); with --sim, its poses, sampling and robot "
                             "model are simulated (robot.host and sensor.url are replaced by the simulated cell's)")
    parser.add_argument("--sim", action="store_true",
                        help="start the simulated cell (UR controller + Net F/T or CAN sensor on loopback) and "
                             "calibrate it end to end; prints the identified parameters beside the true ones")
    parser.add_argument("--dry-run", action="store_true", help="print the checked plan and stop; move nothing")
    parser.add_argument("--yes", "-y", action="store_true", help="confirm the plan without asking")
    parser.add_argument("--resume", type=Path, metavar="RUN_DIR",
                        help="continue a stopped or failed run: same plan, measured poses are not measured again")
    parser.add_argument("--dynamic", action="store_true",
                        help="after the poses, run the excitation stage (a checked, confirmed motion recorded with "
                             "the robot state) and identify the tool's inertia: the calibration then compensates "
                             "while the arm moves (docs/dynamics.md)")
    parser.add_argument("--quick", action="store_true",
                        help="quick calibration: one planned, checked, confirmed continuous motion of about a minute; "
                             "every parameter (inertia included) identified from it, judged on still validation "
                             "poses, replayed with the viewer flags; --yes saves a PASS, otherwise you are asked "
                             "(docs/quick.md)")
    parser.add_argument("--drift", choices=DRIFT_MODELS, default="auto",
                        help="model a linear drift of the sensor's zero over the run: linear, none, or auto (when "
                             "the residuals trend with time beyond the drift thresholds; default); docs/verdict.md")
    add_sensor_check_args(parser)
    parser.add_argument("--out", type=Path, metavar="DIR",
                        help="parent folder of the run folder (default: output.folder of the config, 'runs')")
    sim = parser.add_argument_group("simulation (--sim)")
    sim.add_argument("--sensor", choices=("netft", "can"), default="netft",
                     help="simulated sensor transport (default %(default)s)")
    sim.add_argument("--time-scale", type=float, default=None, metavar="X",
                     help=f"simulated time runs X times faster than real time (0 = instant moves; default "
                          f"{DEFAULT_SIM_TIME_SCALE:g}); settle and averaging times shrink by the same factor")
    sim.add_argument("--model", default="UR5e", help="simulated UR model without --config (default %(default)s)")
    sim.add_argument("--mount", default=MOUNTS[0], metavar="MOUNT",
                     help=f"simulated mount without --config: {MOUNT_FORMS} (default %(default)s)")
    sim.add_argument("--sim-wrong-tool", action="store_true",
                     help="fault: the validation poses are measured with a part (0.2 kg) left in the gripper, "
                          "unknown to ftacq; the verdict must be FAIL")
    sim.add_argument("--sim-bad-sensor", action="store_true",
                     help="fault: the simulated sensor's own calibration is off (Fz 4 %% high, Fx 1.5 %% low, 2 %% of "
                          "Fx on Fy, Tx 2 %% high); the verdict's sensor line must be FAIL, naming Fz")
    viewer = parser.add_argument_group("live view")
    viewer.add_argument("--rerun", action="store_true",
                        help="draw the procedure in the Rerun dashboard (sink chosen by the flags below)")
    add_sink_args(parser)
    parser.set_defaults(func=run)


# ------------------------------------------------------------------------------------------------ helpers


def add_sensor_check_args(parser: argparse.ArgumentParser) -> None:
    """The sensor check's options (``ftacq calibrate`` and ``ftacq identify``; docs/verdict.md)."""
    parser.add_argument("--sensor-check", action=argparse.BooleanOptionalAction, default=None,
                        help="fit the sensor's force gains and cross-talk beside the calibration (the verdict's sensor "
                             "line; default: CELL.toml sensor.check, on)")
    parser.add_argument("--reference-mass", metavar="KG[±SIGMA]",
                        help="the tool's mass weighed on a scale: the sensor check then finds the gains' absolute "
                             "scale (default: CELL.toml tool.reference_mass_kg; without: only their ratios)")
    parser.add_argument("--sensor-accuracy", type=float, metavar="PERCENT",
                        help="the sensor's stated accuracy (its certificate), %% per axis (default: CELL.toml "
                             "sensor.accuracy_percent, 1.25)")


def sensor_check_options(args: argparse.Namespace, options) -> dict:
    """Return the sensor check's fields of ``options`` (ProcedureOptions, or None: only check the arguments) as the
    command line overrides them. Raises InputError for a bad value."""
    from ftacq.sensor_check import parse_reference_mass
    from ftacq.validation import check_number

    out: dict = {}
    if getattr(args, "sensor_check", None) is not None:
        out["sensor_check"] = bool(args.sensor_check)
    if getattr(args, "sensor_accuracy", None) is not None:
        out["sensor_accuracy_percent"] = check_number(args.sensor_accuracy, "--sensor-accuracy", low=0.01, high=50.0)
    if getattr(args, "reference_mass", None) is not None:
        try:
            reference = parse_reference_mass(args.reference_mass)
        except ValueError as error:
            raise InputError(f"--reference-mass: {error}") from None
        out["reference_mass_kg"], out["reference_sigma_kg"] = reference.mass_kg, reference.sigma_kg
    return out


def _sim_config(args: argparse.Namespace):
    from ftacq.app.config import config_from_dict

    # validated like a file's values: `--model UR99` is a one-line error, not a traceback later
    return config_from_dict({"robot": {"host": "(simulated)", "model": args.model, "mount": args.mount}},
                            "--sim (--model/--mount)")


def sim_sampling(sampling, time_scale: float):
    """Return the sampling settings scaled to a simulation running ``time_scale`` times faster (0 = instant)."""
    from dataclasses import replace

    factor = 0.0 if time_scale <= 0 else 1.0 / time_scale
    return replace(sampling, settle_time_s=sampling.settle_time_s * factor,
                   settle_window_s=max(sampling.settle_window_s * factor, SIM_MIN_SETTLE_WINDOW_S),
                   average_time_s=max(sampling.average_time_s * factor, SIM_MIN_AVERAGE_TIME_S))


def wants_dashboard(args: argparse.Namespace) -> bool:
    """True when an option asks for the Rerun dashboard (--rerun, --spawn, --connect, --serve, --save)."""
    return bool(getattr(args, "rerun", False) or getattr(args, "spawn", False) or getattr(args, "connect", None)
                or getattr(args, "serve", False) or getattr(args, "save", None) is not None)


def _err(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------------------------ command


def run(args: argparse.Namespace) -> int:
    """Run ``ftacq calibrate``; return the exit status (raises FtacqError subclasses for the CLI to report).

    The CLI handles SIGTERM as Ctrl-C (:mod:`ftacq.app.signals`), so the simulated cell and the drivers are
    always closed.
    """
    from ftacq.app.commands.robot import start_robot
    from drivers.sensor import open_sensor
    from ftacq.app.config import config_from_dict, load_config
    from procedures.calibration_procedure import (
        CalibrationProcedure,
        Move,
        ProcedureOptions,
        calibration_steps,
        check_steps,
        count_measurements,
    )
    from procedures.plan import Plan, format_plan, make_plan
    from procedures.progress import ProgressListener
    from procedures.run_folder import RunFolder, RunFolderWriter

    from ftacq.validation import check_number, check_output_file, check_output_folder

    if not (args.config or args.sim or args.resume):
        raise InputError("give --config CELL.toml, --sim, or --resume RUN_DIR")
    from ftacq.app.signals import warn_if_sigint_ignored

    warn_if_sigint_ignored("ftacq calibrate", moves_the_arm=not args.dry_run)
    time_scale = DEFAULT_SIM_TIME_SCALE if args.time_scale is None else args.time_scale
    check_number(time_scale, "--time-scale", low=0.0)
    if getattr(args, "save", None) is not None:
        check_output_file(args.save, "--save")

    folder: RunFolder | None = None
    sim_info: dict = {}
    if args.resume:
        folder = RunFolder.open(args.resume)
        if folder.status == "done":
            raise InputError(f"{args.resume}: this run is already done (calibration.json is there); nothing to resume")
        if folder.status == "running" and folder.process_alive():
            raise InputError(f"{args.resume}: this run is still {folder.status_note}; stop it before resuming")
        if folder.status == "interrupted":
            _err(f"note: {args.resume}: {folder.status_note}; resuming it")
        from ftacq.app.commands.quick_stage import refuse_resume

        refuse_resume(folder)
        config = config_from_dict(folder.config, str(folder.path / "run.json"))
        plan = Plan.from_json(folder.plan_json)
        sim_info = dict(folder.document.get("sim") or {})
        if args.config:
            _err(f"note: --resume uses the configuration stored in {folder.path}/run.json; {args.config} is ignored")
        if sim_info and not args.sim:  # run.json knows: resumed on the simulated cell, at its time scale
            _err(f"note: {args.resume} was made with --sim (run.json): resuming it on the simulated cell")
            args.sim = True
            if args.time_scale is None:
                time_scale = float(sim_info.get("time_scale", time_scale))
    elif args.sim:
        config = load_config(args.config) if args.config else _sim_config(args)
        plan = None
    else:
        config = load_config(args.config)
        plan = None
    sensor_check_options(args, None)  # a bad --reference-mass is refused before anything moves
    if args.sim:
        sim_info = {"sensor": sim_info.get("sensor", args.sensor), "time_scale": time_scale,
                    "bad_sensor": bool(sim_info.get("bad_sensor", getattr(args, "sim_bad_sensor", False))),
                    "model": sim_info.get("model", config.robot.model),
                    "mount": sim_info.get("mount", config.robot.mount)}
    out_parent = args.out or Path(config.output.folder)
    if folder is None:  # a new run folder will be made there: check it before the robot is connected
        check_output_folder(out_parent, "--out" if args.out else f"{config.source}: output.folder")
    if getattr(args, "quick", False):
        if args.resume or args.dynamic:
            raise InputError("--quick runs alone: not with --resume or --dynamic (it identifies the inertia too)")
        from ftacq.app.commands.quick_stage import run_quick

        return run_quick(args, config, sim_info, out_parent)

    with contextlib.ExitStack() as stack:
        cell = None
        if args.sim:
            from ftacq.app.simcell import enter_calibration_cell

            cell, config = enter_calibration_cell(stack, config, sim_info, time_scale)
        settings = config.plan_settings() if plan is None else plan.settings
        robot = start_robot(config.robot.host, settings, stack)
        start_q = robot.joint_positions()

        measured = folder.measured() if folder else {}
        if plan is None:
            plan = make_plan(settings, start_q)
        print(format_plan(plan), flush=True)
        if cell is not None and time_scale != 1.0:
            print(f"  simulation: time scale {time_scale:g} ("
                  + ("moves complete at once" if time_scale == 0 else f"{time_scale:g}× faster than real time")
                  + "; settle and averaging times shrink alike): the estimate above is for a real robot",
                  flush=True)
        drift_check = config.sampling.drift_check
        remaining = count_measurements(plan, measured, drift_check)
        if folder is not None:
            print(f"  resuming {folder.path}: {len(measured)} poses already measured, {remaining} to measure",
                  flush=True)
        optional_problems: list[str] = []
        problems = check_steps(calibration_steps(plan, measured, drift_check), settings, start_q, optional_problems)
        if problems:
            from ftacq.errors import PlanError

            raise PlanError("the plan's moves from the robot's current configuration are not clear:\n  "
                            + "\n  ".join(problems))
        print(f"  path check: {sum(isinstance(s, Move) for s in calibration_steps(plan, measured, drift_check))} moves "
              "checked for collisions and joint limits from the current configuration: clear"
              + (" but the drift-check revisit, which will be skipped (the verdict will say WARN): "
                 + "; ".join(optional_problems) if optional_problems else ""), flush=True)
        if args.dry_run:
            print("dry run: the robot did not move", flush=True)
            return 0
        confirm_motion(args)

        # the viewer before the sensor: its time axis starts with the run, not seconds into the sensor's stream
        dashboard, viewer = dashboard_listener(args, stack, settings.model) if wants_dashboard(args) \
            else (None, None)
        sensor = open_sensor(config.sensor.url)
        stack.callback(sensor.close)
        if viewer is not None:
            viewer.dashboard.start_clock()  # the time axis starts with the sensor's stream
        sensor.start()

        if folder is None:
            extra = {"sim": sim_info} if args.sim else {}
            folder = RunFolder.create(out_parent, config.to_dict(), plan.to_json(), extra=extra)
        _err(f"run folder: {folder.path}")
        sampling = sim_sampling(config.sampling, time_scale) if args.sim else config.sampling
        options = ProcedureOptions.from_config(config.replace_section("sampling", **_as_dict(sampling)))
        options = dataclasses.replace(options, drift=args.drift, **sensor_check_options(args, options))
        total = count_measurements(plan, (), drift_check)
        estimate_s = plan.estimated_duration_s * remaining / max(total, 1)
        progress = ProgressListener(total, estimate_s / (max(time_scale, 1.0) if args.sim else 1),
                                    done=total - remaining)
        stack.callback(progress.close)
        listeners: list[Listener] = [RunFolderWriter(folder), progress]
        if cell is not None and args.sim_wrong_tool:
            listeners.insert(0, cell.wrong_tool_listener(plan))
        if dashboard is not None:
            listeners.append(dashboard)
        procedure = CalibrationProcedure(plan, robot, sensor, options, listeners, measured)
        result = procedure.run()
        progress.close()
        status = _finish(args, folder, plan, config, result, cell, options, sensor.info)
        if args.dynamic and status == 0:
            from ftacq.app.commands.dynamic_stage import run_dynamic_stage

            status = run_dynamic_stage(args, stack, config, settings, robot, sensor, folder, cell, confirm_motion,
                                       listeners=[] if dashboard is None else [dashboard])
        return status


def _as_dict(sampling) -> dict:
    from dataclasses import asdict

    return asdict(sampling)


def dashboard_listener(args: argparse.Namespace, stack: contextlib.ExitStack, model_name: str):
    """Return the dashboard as a listener in its own thread (drawing never slows the procedure; the raw stream's
    batches are dropped for the viewer rather than queued without bound), closed with the stack, and the
    :class:`DashboardListener` it wraps (call its ``dashboard.start_clock()`` as the sensor starts)."""
    from ftacq.app.dashboard import Dashboard, DashboardListener, close_recording, open_recording
    from ftacq.kinematics import ur_model
    from procedures.delivery import BackgroundListener

    recording = open_recording(args)
    stack.callback(close_recording, recording)
    try:
        model = ur_model(model_name)
    except Exception:  # noqa: BLE001 - without a model the dashboard draws the flange frames only
        model = None
    listener = DashboardListener(Dashboard(recording), model=model)
    background = BackgroundListener([listener], name="ftacq-dashboard")
    stack.callback(listener.flush)
    stack.callback(background.close)  # runs first: deliver what is queued, then flush the arm
    return background, listener


def _finish(args, folder, plan, config, result, cell, options, sensor_info=None) -> int:
    """Write calibration.json and the report, print the summary and the verdict last; raise AbortedError for a
    stopped/failed run. Returns 1 when the verdict is FAIL (the calibration is kept but must not be used)."""
    import numpy as np

    from ftacq.calfile import save_calibration
    from ftacq.posesets import PLANNED_SETS, is_identified_on
    from ftacq.provenance import input_record, with_provenance
    from ftacq.verdict import FAIL, format_verdict
    from procedures.acceptance import run_verdict
    from procedures.run_report import format_truth_comparison, validation_dict, write_report
    from procedures.run_folder import CALIBRATION_JSON

    truth = cell.truth.calibration() if cell is not None else None
    verdict = None
    try:
        verdict = run_verdict(result, plan, options)
        folder.update(verdict=verdict.to_dict())
    except Exception:
        if result.status == "done":
            raise
        log.warning("could not judge the %s run", result.status, exc_info=True)
    if result.identification is not None:
        calibration = result.identification.calibration
        drift_check = None
        if result.drift is not None:
            drift_check = {"label": result.drift.label, "drift": np.asarray(result.drift.drift).tolist(),
                           "elapsed_s": result.drift.elapsed_s}
        sets = [m.set_name for m in result.measured.values()]
        calibration = with_provenance(
            calibration, sensor_info, getattr(config.tool, "name", None), run_folder=str(folder.path),
            validation=None if result.validation is None else validation_dict(result.validation),
            input=input_record(folder.poses_csv, sets, [s for s in PLANNED_SETS if is_identified_on(s)],
                               has_std=True, has_count=True),
            drift_check=drift_check, verdict=None if verdict is None else verdict.to_dict())
        from dataclasses import replace

        from ftacq.app.commands.dynamic_stage import sensor_offset_from

        offset, offset_source = sensor_offset_from(config, cell)
        if not offset_source.startswith("zero"):  # CELL.toml tool.sensor_offset_m (the exports need it too)
            calibration = replace(calibration, sensor_offset=offset)
        save_calibration(folder.path / CALIBRATION_JSON, calibration)
    try:
        report = write_report(folder.path, result, plan, config.to_dict(), truth=truth,
                              title="ftacq calibration (simulated cell)" if cell is not None else "ftacq calibration",
                              verdict=verdict)
    except Exception:
        if result.status == "done":
            raise
        log.warning("could not write the report of the %s run", result.status, exc_info=True)
    from ftacq.app.hints import ftacq_command

    resume = ftacq_command("calibrate", *(["--sim"] if cell is not None else []), "--resume", folder.path)
    if result.status != "done":
        kept = len(folder.measured())  # what is on disk (a pose may be written just as the interrupt came)
        text = (f"calibration {result.status}: {result.message}\n"
                f"the robot was stopped; {kept} measured poses are kept in {folder.path / 'poses.csv'}\n"
                f"resume with: {resume}")
        if result.interrupted:
            raise InterruptedByUser("interrupted: " + text) from result.error
        raise AbortedError(text) from result.error
    print("")
    if result.identification is not None:
        cal = result.identification.calibration
        alpha, beta = cal.base_tilt_deg
        print(f"identified ({result.identification.method_used}): tool mass {cal.mass_kg:.4f} kg, base tilt "
              f"({alpha:+.3f}°, {beta:+.3f}°), outliers: {', '.join(result.identification.outliers) or 'none'}")
        orientation_deg = cal.metadata.get("noise", {}).get("orientation_error_deg", 0.0)
        if orientation_deg > 0.0:
            print(f"robot orientation error found in the residuals: {orientation_deg:.4f}° (1σ per axis; weighted in)")
    if truth is not None and result.identification is not None:
        print("")
        print(format_truth_comparison(result.identification.calibration, truth))
    if result.validation is not None:
        v = result.validation
        print("")
        print(f"validation on {len(v.labels)} held-out poses (compensated wrench, ideally 0):")
        print("  max |error|: F " + " ".join(f"{x:.4f}" for x in v.max_abs[:3]) + " N, T "
              + " ".join(f"{x:.5f}" for x in v.max_abs[3:]) + " N·m")
        print("  RMS error:   F " + " ".join(f"{x:.4f}" for x in v.rms[:3]) + " N, T "
              + " ".join(f"{x:.5f}" for x in v.rms[3:]) + " N·m")
    if result.drift is not None:
        d = result.drift
        print(f"drift check ({d.label} revisited after {d.elapsed_s:.0f} s): |ΔF| {np.linalg.norm(d.drift[:3]):.4f} N,"
              f" |ΔT| {np.linalg.norm(d.drift[3:]):.5f} N·m" + (" — WARNING" if d.warning else ""))
    for warning in result.warnings:
        print(f"warning: {warning}")
    print("")
    print(f"calibration: {folder.path / CALIBRATION_JSON}")
    print(f"report:      {report}")
    print(f"poses:       {folder.path / 'poses.csv'}")
    if verdict is None:
        return 0
    print("")
    print(format_verdict(verdict))
    return 1 if verdict.status == FAIL else 0
