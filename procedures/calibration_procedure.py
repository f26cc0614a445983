"""The calibration procedure: move through the checked plan, settle, average, record; then identify and validate.

Two parts, as bluesky separates a plan from its engine:

- :func:`calibration_steps` is a generator of steps (:class:`Move`, :class:`Measure`, :class:`Identify`,
  :class:`Validate`) over a :class:`procedures.plan.Plan`, skipping poses already measured (resume). Walked
  without hardware by :func:`check_steps`, it re-checks every joint move of the run for collisions and limits
  before the robot moves (``--dry-run`` prints that walk).
- :class:`CalibrationProcedure` executes the steps with a robot and a sensor, PyMeasure-style:
  ``startup`` (the robot is ready), ``execute`` (the steps), ``shutdown`` in ``finally`` (the robot is stopped
  on any exit but success). Its states and allowed transitions are the table :data:`TRANSITIONS`.

Stop versus abort (bluesky's ``run_engine``): :meth:`CalibrationProcedure.request_stop` (or Ctrl-C / SIGTERM,
seen as KeyboardInterrupt) ends the run at once or at the next checkpoint with status "stopped"; a fault
(protective stop, sensor silent, a pose that does not settle, a refused path, a crash) ends it with "failed".
Both stop the robot and keep every pose measured so far; there is no "halt" that skips cleanup.

Optional steps: the drift-check revisit of the first pose only reports the bias drift; every pose the
calibration needs has been measured before it. A fault in it (its move refused, a protective stop, a pose that
does not settle, a silent sensor) stops the robot, is kept in :attr:`ProcedureResult.drift_skipped` and the
warnings, and the run goes on to identify and validate what it measured (status "done"; the verdict says WARN,
:func:`procedures.acceptance.run_verdict`). A stop request or Ctrl-C during it still stops the run.

The procedure never writes files or draws: it emits :mod:`procedures.events` to its listeners (the run-folder
writer, the progress bar, the Rerun dashboard), including every batch it reads from the sensor
(:class:`procedures.tap.SensorTap`).

A little over 500 lines: the step list, the executor that runs it and its result share one run state (what
was measured, skipped, stopped); the checks of a step list (``check_steps``) could move apart if it grows.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field
from typing import Iterable, Iterator, Sequence

import numpy as np

from drivers.robot import Robot
from drivers.sensor import ForceTorqueSensor
from ftacq.errors import AbortedError, FtacqError, MotionLimitError, PlanError, RobotError
from ftacq.posesets import DRIFT_SET, IDENTIFICATION_SETS, VALIDATION_SET
from ftacq.settings import from_setting, values_from
from procedures import events
from procedures.measured import MeasuredPose, drift_label, pose_record
from procedures.settle import SettleSettings, StopRequested, average_at_pose, wait_until_settled
from procedures.tap import SensorTap

log = logging.getLogger(__name__)

TARGET_TOLERANCE_RAD = 0.01
"""After a move, every joint must be within this of its target (else the robot did not do what was planned)."""

TERMINAL_STATES = ("done", "stopped", "failed")
TRANSITIONS: dict[str, tuple[str, ...]] = {
    "idle": ("planning",),
    "planning": ("moving", "identifying"),
    "moving": ("settling", "identifying"),
    "settling": ("averaging", "identifying"),
    "averaging": ("moving", "identifying"),
    "identifying": ("validating", "done"),
    "validating": ("done",),
    "done": (),
    "stopped": (),
    "failed": (),
}
"""Allowed transitions; "stopped" and "failed" may also be entered from any non-terminal state. Moving or settling
goes straight to identifying only when the optional drift-check revisit failed."""


# ------------------------------------------------------------------------------------------------ steps


@dataclass(frozen=True)
class Move:
    """moveJ to the plan's joint target of pose ``index`` (``purpose`` "pose" or "drift")."""

    index: int
    label: str
    joint_target_rad: np.ndarray
    purpose: str = "pose"


@dataclass(frozen=True)
class Measure:
    """Settle, average and record pose ``index`` under ``label`` in set ``set_name``."""

    index: int
    label: str
    set_name: str


@dataclass(frozen=True)
class Identify:
    """Identify the calibration from the A and E poses."""


@dataclass(frozen=True)
class Validate:
    """Compensate the V poses with the identified calibration and report the errors."""


Step = Move | Measure | Identify | Validate


def calibration_steps(plan, measured: Iterable[str] = (), drift_check: bool = True) -> Iterator[Step]:
    """Yield the steps of a run over ``plan`` (execution order), skipping the labels in ``measured``.

    The drift check revisits the first pose of the plan after the last one (label ``<first>-revisit``, set D),
    through the plan's checked ``revisit_target_rad`` (the same flange pose, perhaps another 2π-equivalent joint
    target) when it has one.
    """
    done = set(measured)
    for i, label in enumerate(plan.labels):
        if label in done:
            continue
        yield Move(i, label, np.asarray(plan.joint_targets_rad[i]))
        yield Measure(i, label, plan.set_names[i])
    if drift_check and len(plan) and drift_label(plan.labels[0]) not in done:
        revisit = getattr(plan, "revisit_target_rad", None)
        target = plan.joint_targets_rad[0] if revisit is None else revisit
        yield Move(0, plan.labels[0], np.asarray(target, dtype=float), purpose="drift")
        yield Measure(0, drift_label(plan.labels[0]), DRIFT_SET)
    yield Identify()
    yield Validate()


def check_steps(steps: Iterable[Step], settings, start_q_rad: np.ndarray,
                optional: list[str] | None = None) -> list[str]:
    """Walk the steps without hardware: check every joint move for collisions and joint limits along its path
    (:func:`procedures.plan.check_path`) and the speed and acceleration against the model. Return the problems.

    ``optional``: when given, the problems of optional moves (:func:`is_optional`: the drift-check revisit) go
    into this list instead: the run may start, and skips that step when it gets there (its move is re-checked
    and refused then).
    """
    from procedures.plan import check_path

    problems: list[str] = []
    q = np.asarray(start_q_rad, dtype=float)
    for step in steps:
        if isinstance(step, Move):
            found = [f"move to {step.label}: {problem}" for problem in check_path(settings, q, step.joint_target_rad)]
            (optional if optional is not None and is_optional(step) else problems).extend(found)
            q = step.joint_target_rad
    return problems


def count_measurements(plan, measured: Iterable[str] = (), drift_check: bool = True) -> int:
    """Return how many poses a run still has to measure."""
    return sum(1 for s in calibration_steps(plan, measured, drift_check) if isinstance(s, Measure))


# ------------------------------------------------------------------------------------------------ executor


@dataclass(frozen=True)
class ProcedureOptions:
    """Execution settings (SI units). ``mount`` names the nominal mount for the tilt report."""

    settle: SettleSettings = field(default_factory=SettleSettings)
    move_timeout_s: float = from_setting("robot.move_timeout_s")
    drift_check: bool = from_setting("sampling.drift_check")
    drift_warn_force_n: float = from_setting("sampling.drift_warn_force_n")
    drift_warn_torque_nm: float = from_setting("sampling.drift_warn_torque_nm")
    mismatch_tolerance_force_n: float = from_setting("sampling.mismatch_tolerance_force_n")
    mismatch_tolerance_torque_nm: float = from_setting("sampling.mismatch_tolerance_torque_nm")
    sensor_check: bool = from_setting("sensor.check")
    sensor_accuracy_percent: float = from_setting("sensor.accuracy_percent")
    reference_mass_kg: float | None = from_setting("tool.reference_mass_kg")
    reference_sigma_kg: float = 0.0
    """1σ of ``reference_mass_kg`` (``--reference-mass KG±SIGMA``)."""
    mount: str | None = None
    drift: str = "auto"
    """Bias drift model of the identification (ftacq.identification.DRIFT_MODELS)."""
    target_tolerance_rad: float = TARGET_TOLERANCE_RAD

    @classmethod
    def from_config(cls, config) -> "ProcedureOptions":
        """Build from :class:`ftacq.app.config.CellConfig`."""
        return cls(settle=SettleSettings.from_config(config), mount=config.robot.mount, **values_from(config, cls))


@dataclass
class ProcedureResult:
    """How a run ended.

    Attributes:
        status: "done", "stopped" (Ctrl-C / SIGTERM / requested) or "failed" (fault or crash).
        message: one line saying what happened (and where).
        measured: every measured pose by label (including those of earlier, resumed runs).
        identification: the :class:`ftacq.identification.IdentificationResult`, when identification ran.
        validation, drift: the :class:`events.Validated` / :class:`events.DriftChecked` emitted, if any.
        error: the exception that ended a stopped or failed run. warnings: drift and identification warnings.
        interrupted: True when the run ended by Ctrl-C or SIGTERM.
        drift_skipped: what failed in the optional drift-check revisit and why ("" when it did not fail); the
            run identified without it.
    """

    status: str
    message: str
    measured: dict[str, MeasuredPose]
    identification: object | None = None
    validation: events.Validated | None = None
    drift: events.DriftChecked | None = None
    error: BaseException | None = None
    warnings: list[str] = field(default_factory=list)
    interrupted: bool = False
    drift_skipped: str = ""


def is_optional(step: Step) -> bool:
    """Return True for a step of the drift-check revisit: the run identifies without it if it fails."""
    return (isinstance(step, Move) and step.purpose == "drift") or (isinstance(step, Measure)
                                                                    and step.set_name == DRIFT_SET)


class CalibrationProcedure:
    """Run a checked plan on a robot and a sensor (both started by the caller); emit events to listeners.

    Args:
        plan: the checked :class:`procedures.plan.Plan` (the same one the user confirmed).
        robot, sensor: drivers behind :class:`drivers.robot.Robot` and :class:`drivers.sensor.ForceTorqueSensor`.
        options: :class:`ProcedureOptions`.
        listeners: callables taking one event; a listener with ``critical = True`` stops the run if it raises.
        measured: poses measured by an earlier run of this plan (resume); they are not measured again.
    """

    def __init__(self, plan, robot: Robot, sensor: ForceTorqueSensor, options: ProcedureOptions | None = None,
                 listeners: Sequence[events.Listener] = (), measured: dict[str, MeasuredPose] | None = None) -> None:
        self.plan = plan
        self.robot = robot
        self.sensor = sensor
        self.options = options or ProcedureOptions()
        self.listeners: list[events.Listener] = list(listeners)
        self.measured: dict[str, MeasuredPose] = dict(measured or {})
        self.state = "idle"
        self._stop = threading.Event()
        self._abort_reason: str | None = None
        self._index: int | None = None
        self._label = ""
        self._result_parts: dict = {"warnings": []}

    # ------------------------------------------------------------------ control

    def request_stop(self) -> None:
        """Ask for a planned stop: the run ends at the next checkpoint (between reads), robot stopped, data kept,
        status "stopped". Safe from any thread (a UI button, a listener)."""
        self._stop.set()

    def request_abort(self, reason: str) -> None:
        """Abort for a fault seen outside the procedure (e.g. a watchdog): like :meth:`request_stop`, but the run
        ends with status "failed" and ``reason`` in its message."""
        self._abort_reason = reason
        self._stop.set()

    def _should_stop(self) -> bool:
        return self._stop.is_set()

    # ------------------------------------------------------------------ events and states

    def _emit(self, event: events.Event) -> None:
        events.publish(self.listeners, event)

    def _counts(self) -> tuple[int, int]:
        """Return (poses measured so far, resumed ones included; poses the whole run measures)."""
        total = count_measurements(self.plan, (), self.options.drift_check)
        return min(len(self.measured), total), total

    def _enter(self, state: str, index: int | None = None, message: str = "") -> None:
        allowed = TRANSITIONS[self.state]
        if state not in allowed and not (state in ("stopped", "failed") and self.state not in TERMINAL_STATES):
            raise RuntimeError(f"procedure: transition {self.state} → {state} is not allowed")
        self.state = state
        measured, total = self._counts()
        self._emit(events.StateChanged(state, index, message, label=self._label if index is not None else "",
                                       measured=measured, total=total))

    # ------------------------------------------------------------------ run

    def run(self) -> ProcedureResult:
        """Execute the plan; always returns a result (the robot is stopped on any exit but success)."""
        status, message, interrupted = "failed", "", False
        error: BaseException | None = None
        try:
            with SensorTap(self.sensor, self._emit):  # every sample read reaches the listeners (raw stream)
                self.startup()
                self.execute()
            status, message = "done", "calibration finished"
        except StopRequested as exc:
            if self._abort_reason is not None:
                status, message, error = "failed", f"aborted {self._where()}: {self._abort_reason}", exc
            else:
                status, message, error = "stopped", f"stopped on request {self._where()}", exc
        except KeyboardInterrupt as exc:
            status, message, error, interrupted = "stopped", f"interrupted {self._where()}", exc, True
        except FtacqError as exc:
            status, message, error = "failed", f"{type(exc).__name__} {self._where()}: {exc}", exc
        except Exception as exc:  # a crash: still stop the robot and keep the data
            log.exception("calibration procedure crashed")
            status, message, error = "failed", f"crash {self._where()}: {exc!r}", exc
        finally:
            self.shutdown(status, message)
        return ProcedureResult(status=status, message=message, measured=dict(self.measured), error=error,
                               interrupted=interrupted, identification=self._result_parts.get("identification"),
                               validation=self._result_parts.get("validation"),
                               drift=self._result_parts.get("drift"), warnings=self._result_parts["warnings"],
                               drift_skipped=self._result_parts.get("drift_skipped", ""))

    def _where(self) -> str:
        """Where the run is, counted as the progress display counts: pose k/N is the k-th measurement of the N
        the whole run makes (the plan and the drift-check revisit, resumed poses included)."""
        if self._index is None:
            return f"in state {self.state}"
        measured, total = self._counts()
        return f"at pose {min(measured + 1, total)}/{total} ({self._label}) while {self.state}"

    def startup(self) -> None:
        """Check the robot can move; announce the plan."""
        self._enter("planning", message=f"{len(self.plan)} poses, {len(self.measured)} already measured")
        self._emit(events.PlanReady(
            poses=np.asarray(self.plan.poses), joint_targets_rad=np.asarray(self.plan.joint_targets_rad),
            labels=tuple(self.plan.labels), set_names=tuple(self.plan.set_names),
            estimated_duration_s=float(self.plan.estimated_duration_s),
            joint_travel_rad=float(self.plan.joint_travel_rad)))
        status = self.robot.status()
        if status.emergency_stop:
            from ftacq.errors import EmergencyStopError

            raise EmergencyStopError("the robot is emergency-stopped; release the e-stop, then resume")
        if status.protective_stop:
            from ftacq.errors import ProtectiveStopError

            raise ProtectiveStopError("the robot is in a protective stop; unlock it on the pendant, then resume")
        if not status.connected:
            from ftacq.errors import DeviceConnectionError

            raise DeviceConnectionError("the robot's data stream is not connected")

    def execute(self) -> None:
        """Walk the steps (see :func:`calibration_steps`); a fault in an optional step skips the rest of it."""
        skipping = False
        for step in calibration_steps(self.plan, self.measured, self.options.drift_check):
            if self._should_stop():
                raise StopRequested("stop requested")
            if is_optional(step):
                if not skipping:
                    skipping = not self._optional(step)
                continue
            if isinstance(step, Move):
                self._move(step)
            elif isinstance(step, Measure):
                self._measure(step)
            elif isinstance(step, Identify):
                self._index = None
                self._identify()
            elif isinstance(step, Validate):
                self._validate()
        self._enter("done", message="calibration finished")

    def _optional(self, step: Step) -> bool:
        """Run an optional step; on a fault stop the robot, record what failed and return False."""
        try:
            if isinstance(step, Move):
                self._move(step)
            else:
                assert isinstance(step, Measure)
                self._measure(step)
            return True
        except (StopRequested, AbortedError):
            raise
        except FtacqError as exc:
            if self._should_stop():
                raise
            what = self._label or getattr(step, "label", "")
            reason = f"{type(exc).__name__} at {what} while {self.state}: {exc}"
            log.warning("the drift check failed, the run identifies without it: %s", reason)
            try:
                self.robot.stop()
            except Exception:
                log.warning("robot.stop() failed after the drift check's fault", exc_info=True)
            self._result_parts["drift_skipped"] = reason
            self._result_parts["warnings"].append(
                f"the drift check was not made ({reason}); the calibration uses the poses measured before it")
            return False

    def shutdown(self, status: str, message: str) -> None:
        """Stop the robot unless the run succeeded, and announce the final state (always called)."""
        if status != "done":
            for _attempt in range(2):  # a second Ctrl-C must not skip the stop
                try:
                    self.robot.stop()
                    break
                except KeyboardInterrupt:
                    continue
                except Exception:
                    log.warning("robot.stop() failed during shutdown", exc_info=True)
                    break
            if self.state not in TERMINAL_STATES:
                try:
                    self._enter(status, self._index, message)
                except Exception:
                    log.warning("could not record the final state %s", status, exc_info=True)

    # ------------------------------------------------------------------ steps

    def _move(self, step: Move) -> None:
        from procedures.plan import check_path

        settings = self.plan.settings
        self._index = step.index
        self._label = drift_label(step.label) if step.purpose == "drift" else step.label
        self._enter("moving", step.index, "drift check: back to the first pose" if step.purpose == "drift" else "")
        q_now = np.asarray(self.robot.joint_positions(), dtype=float)
        problems = check_path(settings, q_now, step.joint_target_rad)
        if problems:
            raise PlanError(f"move to {step.label} refused before moving: {'; '.join(problems)}")
        speed, acceleration = settings.joint_speed_rad_s, settings.joint_acceleration_rad_s2
        model = settings.ur
        if speed > min(model.max_joint_speed_rad_s):
            raise MotionLimitError(f"joint speed {speed} rad/s is above the {model.name} rating")
        self.robot.move_joints(step.joint_target_rad, speed, acceleration, timeout_s=self.options.move_timeout_s)
        reached = np.asarray(self.robot.joint_positions(), dtype=float)
        error = float(np.max(np.abs(reached - step.joint_target_rad)))
        if error > self.options.target_tolerance_rad:
            raise RobotError(f"the robot stopped {error:.4f} rad from the target of {step.label} "
                             f"(tolerance {self.options.target_tolerance_rad} rad)")

    def _measure(self, step: Measure) -> None:
        self._index, self._label = step.index, step.label
        self._enter("settling", step.index)
        wait_until_settled(self.robot, self.sensor, self.options.settle, self._should_stop)
        self._enter("averaging", step.index)
        average, t_start, t_end = average_at_pose(self.sensor, self.options.settle, self._should_stop)
        pose = np.asarray(self.robot.flange_pose(), dtype=float)
        q = np.asarray(self.robot.joint_positions(), dtype=float)
        event = events.PoseMeasured(
            index=step.index, label=step.label, set_name=step.set_name, pose=pose, joint_positions_rad=q,
            mean=np.asarray(average.mean, dtype=float), std=np.asarray(average.std, dtype=float),
            count=int(average.count), saturated=int(average.saturated), lost=int(average.lost),
            t_start_s=t_start, t_end_s=t_end)
        self._emit(event)  # the run-folder writer (critical) has appended and fsync'd the row when this returns
        self.measured[step.label] = MeasuredPose(step.label, step.set_name, pose, event.mean, event.std,
                                                 event.count, t_end)
        if step.set_name == DRIFT_SET:
            self._drift_check(step)

    def _drift_check(self, step: Measure) -> None:
        first = self.measured.get(self.plan.labels[step.index])
        revisit = self.measured[step.label]
        if first is None:
            return
        drift = revisit.mean - first.mean
        elapsed = (revisit.t_end_s - first.t_end_s) if (revisit.t_end_s and first.t_end_s) else float("nan")
        force, torque = float(np.linalg.norm(drift[:3])), float(np.linalg.norm(drift[3:]))
        warning = ""
        if force > self.options.drift_warn_force_n or torque > self.options.drift_warn_torque_nm:
            warning = (f"bias drift at {first.label} over {elapsed:.0f} s: {force:.3f} N, {torque:.4f} N·m "
                       f"(thresholds {self.options.drift_warn_force_n} N, {self.options.drift_warn_torque_nm} N·m): "
                       "let the sensor warm up (about 30 min powered) and calibrate again")
            self._result_parts["warnings"].append(warning)
        result = events.DriftChecked(first.label, drift, elapsed, warning)
        self._result_parts["drift"] = result
        self._emit(result)

    def identification_record(self):
        """Return the A and E poses measured, in plan order, as a :class:`ftacq.posefile.PoseRecord`."""
        return self._record_of([i for i, s in enumerate(self.plan.set_names) if s in IDENTIFICATION_SETS])

    def _record_of(self, indices: list[int]):
        return pose_record([self.measured[self.plan.labels[i]] for i in indices
                            if self.plan.labels[i] in self.measured])

    def _identify(self) -> None:
        from ftacq.errors import IdentificationError
        from ftacq.identification import identify

        self._enter("identifying")
        record = self.identification_record()
        if record is None:
            raise IdentificationError("no identification pose (A or E) was measured")
        from ftacq.identification.sensor_gain import ReferenceWeight

        options = self.options
        reference = (None if options.reference_mass_kg is None
                     else ReferenceWeight(options.reference_mass_kg, options.reference_sigma_kg))
        result = identify(record, mount=options.mount, drift=options.drift,
                          drift_warn=(options.drift_warn_force_n, options.drift_warn_torque_nm),
                          sensor_check=options.sensor_check, reference=reference,
                          sensor_accuracy_percent=options.sensor_accuracy_percent)
        self._result_parts["identification"] = result
        self._result_parts["warnings"].extend(result.warnings)
        self._emit(events.Identified(calibration=result.calibration, labels=tuple(result.labels),
                                     residuals=np.asarray(result.residuals), outliers=tuple(result.outliers)))

    def _validate(self) -> None:
        result = self._result_parts.get("identification")
        record = self._record_of([i for i, s in enumerate(self.plan.set_names) if s == VALIDATION_SET])
        if result is None or record is None:
            return
        self._enter("validating")
        validation = validate(result.calibration, record)
        self._result_parts["validation"] = validation
        self._emit(validation)


def validate(calibration, record) -> events.Validated:
    """Compensate held-out poses (no contact): the errors (M, 6) should be ≈ 0. Returns per-axis max |e| and RMS.
    With a modelled bias drift each pose is compensated with the bias of its own time."""
    from ftacq.identification.trend import bias_drift_at

    errors = calibration.compensate(record.wrench, record.flange_R_base)
    errors = np.asarray(errors, dtype=float).reshape(-1, 6) - bias_drift_at(calibration, record)
    return events.Validated(labels=tuple(record.labels), errors=errors, max_abs=np.abs(errors).max(axis=0),
                            rms=np.sqrt(np.mean(errors**2, axis=0)))


__all__ = ["CalibrationProcedure", "ProcedureOptions", "ProcedureResult", "Move", "Measure", "Identify", "Validate",
           "calibration_steps", "check_steps", "count_measurements", "is_optional", "validate", "TRANSITIONS"]
