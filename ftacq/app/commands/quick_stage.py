"""``ftacq calibrate --quick``: design, check and confirm one continuous trajectory; run and record it; identify every
parameter from the motion (ftacq/dynamics/joint.py); judge it on still validation poses it never fitted; replay raw
vs compensated in the Rerun dashboard; save or discard (docs/quick.md).

Run folder: run.json (the plan and status), motion.csv (the recording, both streams), report.md, and
calibration.json once saved (the same file as the full run's, with inertia). A stopped run (Ctrl-C, a
protective stop) keeps motion.csv and says how to restart: a continuous motion is not resumed halfway, it is
run again (about a minute).

The analysis (:func:`analyse_quick`: each hold from its settling, the fit with the drift when the data ask, the
verdict with what it allows for) is here beside the command that runs it, and the benchmark calls it too: just
over 500 lines; it would move to ``procedures/`` as a module of its own if another command needed it.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ftacq.errors import AbortedError, FtacqError, InputError, InterruptedByUser
from procedures.run_report import write_quick_report  # the report with the full run's sections and plots

log = logging.getLogger(__name__)

MOTION_CSV = "motion.csv"
QUICK_MODE = "quick"
"""run.json ``mode`` of a quick run (``--resume`` refuses it with the restart command)."""


def _err(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def hold_windows(recording, purpose: str, plan) -> list[tuple[int, int]]:
    """Robot-sample windows [start, end) of the holds with this purpose that were reached."""
    return [(int(a), int(b)) for (a, b), p in zip(recording.hold_rows, plan.purposes) if p == purpose and b > a]


REST_SPEED_RAD_S = 0.005
"""A robot state is at rest when no joint moves faster than this, rad/s (a hold's window is counted in states as they
arrive: one that arrived in a burst may begin with the end of the move before it)."""
DRIFT_CURVATURE_TIME_S = 600.0
"""The shortest time constant of a sensor's warm-up drift the validation allows for, s: a straight line fitted to an
exponential drift over a span T is off at its end by about rate · T² / (12 τ), which the verdict adds to the error
it expects (what the linear drift model leaves out)."""
RING_MIN_FREQUENCY_HZ = 5.0
"""The lowest ring-down frequency of a tool the validation allows for, Hz: a ring of amplitude A left after the
settle check adds at most about A / (2π f) N·s to a hold's sum, so A / (2π f T) to its mean over T s."""


@dataclass(frozen=True)
class Rest:
    """One reached hold: its waypoint ``index``, its purpose, robot rows [start, end) (``start`` its first state at
    rest, :data:`REST_SPEED_RAD_S`), and when its wrench had settled (robot clock, s; :func:`ftacq.rest_windows.settled_starts`)."""

    index: int
    purpose: str
    start: int
    end: int
    settled_s: float


@dataclass(frozen=True)
class QuickAnalysis:
    """What :func:`analyse_quick` found: the joint fit, the drift, the holds' settling, the verdict, the rows fitted."""

    result: Any
    drift: Any
    rests: list[Rest]
    ring_allowance: np.ndarray
    verdict: Any
    rows: np.ndarray

    def settle_summary(self) -> dict:
        """The holds' settling for the calibration's metadata: each hold's delay from rest to settled (s), and the
        ring amplitude the check could miss (6,) [N, N·m]."""
        return {"settle_delay_s": [round(float(r.settled_s), 4) for r in self.rests],
                "ring_allowance": self.ring_allowance.tolist()}


def hold_rests(recording, plan) -> tuple[list[Rest], np.ndarray]:
    """Every reached hold from its first robot state at rest, and when its wrench settled there (judged from the
    samples: the tool rings after each stop); ``settled_s`` is the delay after the rest began, s; and the largest
    ring amplitude (6,) the settle check can miss."""
    from ftacq.rest_windows import settled_starts

    record = recording.record
    found = []
    for k, ((a, b), purpose) in enumerate(zip(recording.hold_rows, plan.purposes)):
        if b - a < 2:
            continue
        still = np.flatnonzero(np.max(np.abs(record.qd[a:b]), axis=1) <= REST_SPEED_RAD_S)
        if still.size < 2:
            continue
        found.append((k, purpose, a + int(still[0]), a + int(still[-1]) + 1))
    windows = [(float(record.robot_time_s[a]), float(record.robot_time_s[b - 1])) for _, _, a, b in found]
    settled, allowance = settled_starts(record.sensor_time_s, record.wrench, windows)
    rests = [Rest(k, p, a, b, float(t - w[0])) for (k, p, a, b), w, t in zip(found, windows, settled)]
    return rests, allowance


def validation_poses(recording, plan, lag_s: float, rests: list[Rest] | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(q (M, 6), mean wrench (M, 6), its standard error (M, 6), labels, mean sensor time (M,) s, duration (M,) s) of
    each still
    validation hold: the sensor samples within the hold's robot-time window (shifted by the lag) from when its
    wrench settled (:func:`hold_rests`) to its end."""
    from procedures.quick import VALIDATE

    record = recording.record
    if rests is None:
        rests = hold_rests(recording, plan)[0]
    qs, means, errors, labels, times, durations = [], [], [], [], [], []
    for rest in rests:
        if rest.purpose != VALIDATE or rest.end - rest.start < 20:
            continue
        a, b = rest.start, rest.end
        t0 = record.robot_time_s[a] + rest.settled_s + lag_s
        t1 = record.robot_time_s[b - 1] + lag_s
        inside = (record.sensor_time_s >= t0) & (record.sensor_time_s < t1)
        if inside.sum() < 10:
            continue
        samples = record.wrench[inside]
        qs.append(record.q[a:b].mean(axis=0))
        means.append(samples.mean(axis=0))
        errors.append(samples.std(axis=0, ddof=1) / np.sqrt(len(samples)))
        labels.append(plan.labels[rest.index])
        times.append(float(record.sensor_time_s[inside].mean()))
        durations.append(float(np.ptp(record.sensor_time_s[inside])))
    return (np.array(qs).reshape(-1, 6), np.array(means).reshape(-1, 6), np.array(errors).reshape(-1, 6),
            np.array(labels), np.array(times), np.array(durations))


def fitted_rows(recording, plan, rests: list[Rest]) -> np.ndarray:
    """(M,) the robot rows the fit uses: all but the validation holds and, in each fitted hold, the rows between the
    stop and the wrench's settling (the ring-down, which the model does not describe)."""
    from procedures.quick import VALIDATE

    record = recording.record
    rows = np.ones(len(record.robot_time_s), dtype=bool)
    for a, b in hold_windows(recording, VALIDATE, plan):
        rows[a:b] = False
    for rest in rests:
        if rest.purpose != VALIDATE:
            settled = record.robot_time_s[rest.start] + rest.settled_s
            rows[rest.start:rest.end] &= record.robot_time_s[rest.start:rest.end] >= settled
    return rows


def analyse_quick(recording, plan, robot_model, sensor_offset_m: np.ndarray, nominal_down: np.ndarray,
                  completed: bool, drift: str = "auto", metadata: dict | None = None) -> QuickAnalysis:
    """Settle, fit (with the drift when the data ask for it, ftacq/dynamics/drift_terms.py) and judge a recording."""
    from ftacq.dynamics.drift_terms import identify_with_drift

    rests, allowance = hold_rests(recording, plan)
    rows = fitted_rows(recording, plan, rests)
    result, drift_fit = identify_with_drift(recording.record, robot_model, sensor_offset_m, nominal_down, rows=rows,
                                            drift=drift, reference_s=float(recording.record.robot_time_s[-1]),
                                            metadata=metadata)
    verdict = quick_verdict(result, recording, plan, robot_model, completed, drift_fit, rests, allowance)
    return QuickAnalysis(result, drift_fit, rests, allowance, verdict, rows)


def quick_verdict(result, recording, plan, robot_model, completed: bool, drift_fit=None,
                  rests: list[Rest] | None = None, ring_allowance: np.ndarray | None = None):
    """The verdict: the validation holds compensated with the result (static model: the arm is still; the bias at
    each hold's own time when a drift was fitted), against the error expected from the standard error of each mean,
    the parameters' covariance propagated (the drift's rates included: the holds come after the fitted motion),
    and what the model leaves out: a ring-down too small to be seen (``ring_allowance``, :func:`hold_rests`) and the
    curvature of a warm-up drift (:data:`DRIFT_CURVATURE_TIME_S`) (:func:`ftacq.verdict.validation_finding`); plus
    whether the whole trajectory ran."""
    from ftacq.dynamics.drift_terms import DRIFT_COLUMNS, SECONDS_PER_HOUR
    from ftacq.kinematics import forward_kinematics
    from ftacq.verdict import FAIL, PASS, Finding, judge, validation_finding

    if rests is None:
        rests, ring_allowance = hold_rests(recording, plan)
    q, mean, standard_error, labels, times, durations = validation_poses(recording, plan, result.lag_s, rests)
    findings = []
    if len(q):
        rotations = np.array([forward_kinematics(robot_model, qi)[:3, :3].T for qi in q])  # flange_R_base
        calibration = result.calibration
        modelled = drift_fit is not None and drift_fit.modelled
        base = result.optimum.size - (DRIFT_COLUMNS if modelled else 0)
        s_h = (times - (drift_fit.reference_s if drift_fit is not None else 0.0)) / SECONDS_PER_HOUR
        errors = mean - calibration.predict(rotations)
        jac = np.zeros((len(q), 6, result.optimum.size))
        for i in range(base):
            step = 1e-6 * max(abs(result.optimum[i]), 1e-3)
            plus, minus = result.optimum.copy(), result.optimum.copy()
            plus[i] += step
            minus[i] -= step
            jac[:, :, i] = (result.parameters(plus).predict(rotations) - result.parameters(minus).predict(rotations)) \
                / (2 * step)
        extra = np.zeros((len(q), 6))
        if modelled:
            errors = errors - s_h[:, None] * drift_fit.rate
            jac[:, :, base:] = s_h[:, None, None] * np.eye(6)
        if drift_fit is not None:
            # a warm-up's curvature the line leaves out, at the end of the span (rate in /h, span in h)
            extra += (np.abs(drift_fit.rate) * drift_fit.span_h ** 2 * SECONDS_PER_HOUR
                      / (12 * DRIFT_CURVATURE_TIME_S)) ** 2
            if not modelled:  # a drift below significance, not modelled: the holds come after the fitted motion
                middle = -0.5 * drift_fit.span_h
                extra += ((s_h - middle)[:, None] ** 2) * (drift_fit.rate ** 2 + drift_fit.rate_sigma ** 2)
        if ring_allowance is not None:  # what is left of a ring-down too small to be seen, averaged over the hold
            extra += (np.asarray(ring_allowance)[None, :] / (2 * np.pi * RING_MIN_FREQUENCY_HZ)
                      / np.maximum(durations, 1e-3)[:, None]) ** 2
        covariance = np.einsum("mai,ij,mbj->mab", jac, result.covariance, jac)
        covariance += np.einsum("ma,ab->mab", standard_error ** 2 + extra, np.eye(6))
        findings.append(validation_finding(errors, covariance, list(labels)))
    else:
        findings.append(validation_finding(np.zeros((0, 6)), np.zeros((0, 6, 6)), []))
    findings.append(Finding("poses", PASS if completed else FAIL,
                            "the whole trajectory ran" if completed else "the trajectory did not finish",
                            f"condition number {result.condition_number:.3g}, {result.rows} rows fitted, lag "
                            f"{1e3 * result.lag_s:.2f} ms"))
    if drift_fit is not None:
        findings.append(drift_finding(drift_fit))
    return judge(findings)


def drift_finding(drift_fit):
    """The drift inside the motion, as a finding ("trend", as the full run's): modelled or not, and why. It never
    fails the run: the fit models what it sees, and the validation judges the result with it; a sensor still
    drifting is what ``ftacq tare`` is for (docs/drift-and-tare.md)."""
    from ftacq.verdict import PASS, Finding

    rate = drift_fit.rate
    size = (f"{np.linalg.norm(rate[:3]):.3g} N/h and {np.linalg.norm(rate[3:]):.3g} N·m/h "
            f"(± {np.linalg.norm(drift_fit.rate_sigma[:3]):.2g}, {np.linalg.norm(drift_fit.rate_sigma[3:]):.2g})")
    if drift_fit.modelled:
        summary = (f"the sensor's zero drifted {size} during the motion; the fit modelled it and keeps the biases "
                   "of the end of the run (tare before use if it keeps drifting)")
    else:
        summary = f"no drift the motion can see ({size})"
    details = f"linear bias drift: {drift_fit.chosen}"
    return Finding("trend", PASS, summary, details, {"chi2": drift_fit.chi2, "p_value": drift_fit.p_value,
                                                      "rate": rate.tolist(),
                                                      "rate_sigma": drift_fit.rate_sigma.tolist()})


def _g(values) -> str:
    """1σ values, two significant digits each."""
    return "[" + ", ".join(f"{v:.2g}" for v in np.ravel(values)) + "]"


def replay(args: argparse.Namespace, recording, calibration, model_name: str) -> None:
    """Raw vs compensated (dynamic model) over the whole run, and the arm, in the Rerun dashboard."""
    from ftacq.app.dashboard import Dashboard, close_recording, open_recording
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
    rec = open_recording(args)
    try:
        dashboard = Dashboard(rec)
        dashboard.log_wrench_batch(times, raw, compensated)
        arm_rows = slice(None, None, 10)
        poses = np.array([flange_pose(robot, q) for q in record.q[arm_rows]])
        dashboard.log_arm(record.robot_time_s[arm_rows], poses, record.q[arm_rows])
        dashboard.flush_columns()
    finally:
        close_recording(rec)


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
    from procedures.quick import FIT, VALIDATE, check_quick, design_quick, format_quick, record_quick
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
        sensor = open_sensor(config.sensor.url)
        stack.callback(sensor.close)
        sensor.start()
        extra = {"mode": QUICK_MODE, **({"sim": sim_info} if args.sim else {})}
        folder = RunFolder.create(out_parent, config.to_dict(), plan.to_json(), extra=extra)
        _err(f"run folder: {folder.path}")
        folder.set_status("running", "quick calibration: recording the motion")
        stack.push(lambda kind, error, trace: _end_unfinished(folder, error, restart))
        stream = URStateStream(config.robot.host)
        stack.callback(stream.close)
        stream.start()

        def on_hold(k: int, purpose: str, begins: bool) -> None:
            if cell is not None and args.sim_wrong_tool and purpose == VALIDATE:
                extra_kg = sys.modules[type(cell).__module__].WRONG_TOOL_EXTRA_MASS_KG  # the simulated cell's own knob
                cell.swap_tool(cell.truth.mass_kg + extra_kg) if begins else cell.swap_tool()

        motion_path = folder.path / MOTION_CSV
        moving = time.monotonic()
        try:
            recording = record_quick(plan, robot, sensor, stream, config.robot.move_timeout_s,
                                     on_waypoint=lambda k, n: _err(f"quick trajectory: waypoint {k + 1}/{n}"),
                                     on_hold=on_hold)
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
        if getattr(args, "rerun", False) or getattr(args, "save", None) is not None or getattr(args, "spawn", False) \
                or getattr(args, "connect", None) or getattr(args, "serve", False):
            replay(args, recording, calibration, settings.model)
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


__all__ = ["run_quick", "quick_verdict", "analyse_quick", "hold_rests", "fitted_rows", "QuickAnalysis", "Rest", "refuse_resume", "validation_poses"]
