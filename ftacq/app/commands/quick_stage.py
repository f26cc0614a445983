"""``ftacq calibrate --quick``: design, check and confirm one continuous trajectory; run and record it; identify every
parameter from the motion (ftacq/dynamics/joint.py); judge it on still validation poses it never fitted; replay raw
vs compensated in the Rerun dashboard; save or discard (docs/quick.md).

Run folder: run.json (the plan and status), motion.csv (the recording, both streams), report.md, and
calibration.json once saved (the same file as the full run's, with inertia). A stopped run (Ctrl-C, a
protective stop) keeps motion.csv and says how to restart: a continuous motion is not resumed halfway, it is
run again (about a minute).

The analysis (each hold from its settling, the fit with the drift when the data ask, the verdict with what it allows
for) is :mod:`procedures.quick_analysis`.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import time
from pathlib import Path

import numpy as np

from ftacq.errors import AbortedError, FtacqError, InputError, InterruptedByUser
from procedures.quick import VALIDATE
from procedures.quick_analysis import analyse_quick, hold_windows
from procedures.run_report import write_quick_report  # the report with the full run's sections and plots

log = logging.getLogger(__name__)

MOTION_CSV = "motion.csv"
QUICK_MODE = "quick"
"""run.json ``mode`` of a quick run (``--resume`` refuses it with the restart command)."""


def _err(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _g(values) -> str:
    """1σ values, two significant digits each."""
    return "[" + ", ".join(f"{v:.2g}" for v in np.ravel(values)) + "]"


def replay(dashboard, recording, calibration, model_name: str) -> None:
    """Raw vs compensated (dynamic model) over the whole run, and the arm, on the run's ``dashboard`` (the motion's
    plan and states came live; the wrenches are drawn once, on the record's clock)."""
    from ftacq.dynamics import compensate_moving
    from ftacq.kinematics import flange_pose, ur_model

    record = recording.record
    robot = ur_model(model_name)
    every = max(len(record.sensor_time_s) // max(int(np.ptp(record.sensor_time_s) * 1000), 1), 1)  # ≤ ~1 kHz
    raw = record.wrench[::every]
    times = record.sensor_time_s[::every]
    lag = float(calibration.metadata.get("quick", {}).get("lag_ms", 0.0)) * 1e-3
    compensated = compensate_moving(calibration, raw, record.q, record.qd, record.qdd, robot=robot,
                                    sensor_time_s=times - lag, robot_time_s=record.robot_time_s)
    dashboard.log_wrench_batch(times, raw, compensated)
    arm_rows = slice(None, None, 10)
    poses = np.array([flange_pose(robot, q) for q in record.q[arm_rows]])
    dashboard.log_arm(record.robot_time_s[arm_rows], poses, record.q[arm_rows])
    dashboard.flush_columns()


def _live_listeners(args: argparse.Namespace, stack: contextlib.ExitStack, plan, cell, model_name: str):
    """The quick motion's listeners (progress; the dashboard's steps, without the raw stream that :func:`replay`
    draws; the simulated wrong tool during the validation holds) and the dashboard (None when not asked for)."""
    from ftacq.app.commands.calibrate import dashboard_listener, wants_dashboard
    from procedures import events
    from procedures.progress import ProgressListener

    progress = ProgressListener(len(plan.waypoints_rad), plan.estimated_duration_s, motion="quick trajectory")
    stack.callback(progress.close)
    listeners: list[events.Listener] = [progress]
    viewer = None
    if wants_dashboard(args):
        background, viewer = dashboard_listener(args, stack, model_name)

        def steps(event: events.Event) -> None:
            if not isinstance(event, events.WrenchSamples):
                background(event)

        listeners.append(steps)
    if cell is not None and args.sim_wrong_tool:
        extra_kg = sys.modules[type(cell).__module__].WRONG_TOOL_EXTRA_MASS_KG  # the simulated cell's own knob

        def wrong_tool(event: events.Event) -> None:  # a part in the gripper during the validation holds only
            if isinstance(event, events.StateChanged):
                held_out = event.state == "holding" and event.index is not None and plan.purposes[event.index] == VALIDATE
                cell.swap_tool(cell.truth.mass_kg + extra_kg) if held_out else cell.swap_tool()

        wrong_tool.critical = True  # type: ignore[attr-defined]
        listeners.insert(0, wrong_tool)
    return listeners, viewer


def _end_unfinished(folder, error: BaseException | None, restart: str) -> bool:
    """The run folder's exit handler (an ExitStack exit callback): a run left "running" by an exception the stages
    did not handle ends "stopped" (Ctrl-C) or "failed" with the error, as the full run does; an unexpected crash is
    logged with its traceback and reported as one line with the restart command. Returns False (the exception, if
    any, goes on)."""
    if error is None or folder.document.get("status") != "running":
        return False
    interrupted = isinstance(error, KeyboardInterrupt)
    if not interrupted and not isinstance(error, FtacqError):
        log.error("quick calibration crashed", exc_info=error)
    what = error if isinstance(error, FtacqError) else f"{type(error).__name__}: {error}"
    text = f"quick calibration {'interrupted' if interrupted else 'failed'} ({what}); nothing was saved; restart with: {restart}"
    folder.set_status("stopped" if interrupted else "failed", text)
    if isinstance(error, Exception) and not isinstance(error, FtacqError):
        raise AbortedError(text) from error
    return False


def _save_or_discard(args: argparse.Namespace, verdict) -> bool:
    """--yes: save a PASS only. Otherwise ask (no terminal: discard)."""
    from ftacq.verdict import PASS

    if args.yes:
        return verdict.status == PASS
    if not sys.stdin or not sys.stdin.isatty():
        return False
    answer = input(f"verdict {verdict.status}: save this calibration? [y/N] ").strip().lower()
    return answer in ("y", "yes")


def run_quick(args: argparse.Namespace, config, sim_info: dict, out_parent: Path) -> int:
    """Run the quick calibration; return the exit status (0 saved, 1 not saved / FAIL)."""
    from ftacq.app.commands.robot import start_robot
    from drivers.sensor import open_sensor
    from drivers.ur_stream import URStateStream
    from ftacq.app.commands.dynamic_stage import sensor_offset_from
    from ftacq.app.confirm import confirm_motion
    from ftacq.app.hints import ftacq_command
    from ftacq.calfile import save_calibration
    from ftacq.dynamics.motionfile import write_motion_csv
    from ftacq.mounts import mount_of
    from ftacq.verdict import format_verdict
    from procedures.plan import make_plan
    from procedures.quick import FIT, check_quick, design_quick, format_quick, record_quick
    from procedures.run_folder import RunFolder

    restart = ftacq_command("calibrate", *(["--sim"] if args.sim else ["--config", args.config or "CELL.toml"]),
                            "--quick")
    with contextlib.ExitStack() as stack:
        cell = None
        if args.sim:
            from ftacq.app.simcell import enter_calibration_cell

            cell, config = enter_calibration_cell(stack, config, sim_info, time_scale=1.0)
        settings = config.plan_settings()
        robot = start_robot(config.robot.host, settings, stack)
        reported = getattr(getattr(robot, "info", None), "model", None)
        if reported is not None and reported.name != settings.ur.name:
            raise InputError(f"the controller at {config.robot.host} says it is a {reported.name}, "
                             f"{config.source} says robot.model = {settings.model}: the quick calibration's motion "
                             f"model needs the right one (set robot.model)")
        wall: dict[str, float] = {}
        started = time.monotonic()
        start_q = robot.joint_positions()
        plan = design_quick(settings, start_q, make_plan(settings, start_q))
        print(format_quick(plan), flush=True)
        problems = check_quick(settings, robot.joint_positions(), plan.waypoints_rad)
        if problems:
            from ftacq.errors import PlanError

            raise PlanError("the quick trajectory is not clear from the robot's configuration:\n  "
                            + "\n  ".join(problems))
        wall["plan"] = time.monotonic() - started
        if args.dry_run:
            print("dry run: the robot did not move", flush=True)
            return 0
        confirm_motion(args)
        confirmed = time.monotonic()
        listeners, viewer = _live_listeners(args, stack, plan, cell, settings.model)
        sensor = open_sensor(config.sensor.url)
        stack.callback(sensor.close)
        if viewer is not None:
            viewer.dashboard.start_clock()  # the time axis starts with the sensor's stream
        sensor.start()
        extra = {"mode": QUICK_MODE, **({"sim": sim_info} if args.sim else {})}
        folder = RunFolder.create(out_parent, config.to_dict(), plan.to_json(), extra=extra)
        _err(f"run folder: {folder.path}")
        folder.set_status("running", "quick calibration: recording the motion")
        stack.push(lambda kind, error, trace: _end_unfinished(folder, error, restart))
        stream = URStateStream(config.robot.host)
        stack.callback(stream.close)
        stream.start()

        motion_path = folder.path / MOTION_CSV
        moving = time.monotonic()
        try:
            recording = record_quick(plan, robot, sensor, stream, config.robot.move_timeout_s, listeners=listeners)
        except (KeyboardInterrupt, FtacqError) as error:
            partial = getattr(error, "quick_recording", None)
            if partial is not None and len(partial.record.robot_time_s):
                write_motion_csv(motion_path, partial.record, settings.model)
            interrupted = isinstance(error, KeyboardInterrupt)
            text = (f"quick calibration {'interrupted' if interrupted else 'failed'}: the robot was stopped; nothing "
                    f"was saved; the motion so far is in {motion_path}. A continuous motion is not resumed: restart "
                    f"with: {restart}")
            folder.set_status("stopped" if interrupted else "failed", text)
            if interrupted:
                raise InterruptedByUser(text) from error
            raise AbortedError(f"{error}\n{text}") from error
        wall["motion"] = time.monotonic() - moving
        write_motion_csv(motion_path, recording.record, settings.model)
        identifying = time.monotonic()
        offset, offset_source = sensor_offset_from(config, cell)
        analysis = analyse_quick(recording, plan, settings.ur, offset, np.array(mount_of(settings.mount).down_base),
                                 completed=recording.completed == len(plan.waypoints_rad),
                                 drift=getattr(args, "drift", "auto"), metadata={"run_folder": str(folder.path)})
        result, verdict = analysis.result, analysis.verdict
        wall["identify"] = time.monotonic() - identifying
        wall["total_without_confirmation"] = time.monotonic() - confirmed + wall["plan"]
        calibration = result.calibration
        from dataclasses import replace

        metadata = dict(calibration.metadata)
        metadata["quick"] = {**metadata.get("quick", {}), "plan": plan.to_json(), "motion_file": MOTION_CSV,
                             "sensor_offset_source": offset_source, "wall_time_s": wall,
                             "fit_holds": len(hold_windows(recording, FIT, plan)), **analysis.settle_summary()}
        metadata["drift_model"] = analysis.drift.to_metadata(
            (config.sampling.drift_warn_force_n, config.sampling.drift_warn_torque_nm),
            clock_offset_s=time.time() - time.monotonic())  # the recording's host clock is time.monotonic()
        metadata["verdict"] = verdict.to_dict()
        calibration = replace(calibration, metadata=metadata)
        truth = None if cell is None else replace(cell.truth.calibration(), inertia=cell.truth.inertia)
        print("", flush=True)
        print(f"motion recorded in {wall['motion']:.1f} s ({len(recording.record.sensor_time_s)} sensor samples, "
              f"{len(recording.record.robot_time_s)} robot states) -> {motion_path}", flush=True)
        print(f"identified from the motion in {wall['identify']:.1f} s: mass {calibration.mass_kg:.4f} kg "
              f"(1σ {result.sigma['mass_kg']:.2g}), lag {1e3 * result.lag_s:.2f} ms, condition number "
              f"{result.condition_number:.3g}", flush=True)
        if truth is not None:
            from procedures.run_report import format_truth_comparison

            print(format_truth_comparison(calibration, truth), flush=True)
            print(f"inertia about the centre of mass (kg·m²): identified {_g(calibration.inertia)}\n"
                  f"                                        true       {_g(truth.inertia)}\n"
                  f"                                        1σ         {_g(result.sigma['inertia_kg_m2'])}",
                  flush=True)
        print(format_verdict(verdict), flush=True)
        if viewer is not None:
            replay(viewer.dashboard, recording, calibration, settings.model)
        saved = _save_or_discard(args, verdict)
        report = write_quick_report(folder.path, result, verdict, plan, wall, truth, motion=recording.record,
                                    robot=settings.ur, saved=saved, analysis=analysis)
        if saved:
            save_calibration(folder.path / "calibration.json", calibration)
            folder.set_status("done", f"quick calibration saved (verdict {verdict.status})",
                              verdict=verdict.to_dict())
            print(f"calibration: {folder.path / 'calibration.json'}")
            print(f"report:      {report}")
            return 0
        folder.set_status("failed", f"quick calibration not saved (verdict {verdict.status})",
                          verdict=verdict.to_dict())
        print(f"not saved (verdict {verdict.status}{'' if args.yes else ', discarded'}); report: {report}; "
              f"restart with: {restart}, or run the full calibration")
        return 1


def refuse_resume(folder) -> None:
    """A quick run folder is not resumed: raise InputError with the restart command."""
    if folder.document.get("mode") == QUICK_MODE:
        from ftacq.app.hints import ftacq_command

        raise InputError(f"{folder.path}: a quick calibration is not resumed (its motion is one piece); restart it "
                         f"with: " + ftacq_command("calibrate", *(["--sim"] if folder.document.get("sim") else []),
                                                   "--quick"))


__all__ = ["run_quick", "refuse_resume"]
