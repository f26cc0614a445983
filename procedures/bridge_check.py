"""``ftacq bridge --check``: with the arm still, feed known wrenches into the controller's external F/T input and
compare what the controller then reports (``actual_TCP_force``) with the convention (docs/bridge.md).

UR does not document what ``actual_TCP_force`` reads while the external input is on; this is how a sign, frame
or payload error is caught on the real cell before anything relies on the input. Steps, each held
:data:`HOLD_S` and read over its second half:

1. zero: what the controller subtracts by itself (payload handling): the force must equal
   :func:`ftacq.bridge_convention.controller_tcp_force` of a zero wrench (``raw``: minus the tool's weight;
   ``compensated``: nothing);
2. +Fx, +Fy, +Fz (:data:`TEST_FORCE_N`) and +Tx, +Ty, +Tz (:data:`TEST_TORQUE_NM`), fed in the convention's frame:
   the change from step 1 must be the step rotated into base axes (forces compared for force steps, torques
   for torque steps: independent of the TCP). A reading opposite to the prediction is a flipped sign; one of the
   right size in another direction is a frame error (angle given).

Each step is read from the cycles sent :data:`SETTLE_CYCLES` cycles after its wrench reached the controller. The arm must be still
(a moving arm aborts the check) and no force-mode program may run:
the values fed are not measurements.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ftacq.bridge_convention import FeedPlan, controller_tcp_force
from ftacq.channels import AXES
from ftacq.errors import FtacqError
from ftacq.kinematics import URModel, forward_kinematics

HOLD_S = 0.3
TEST_FORCE_N = 10.0
TEST_TORQUE_NM = 1.0
FORCE_TOLERANCE_N = 0.5
TORQUE_TOLERANCE_NM = 0.05
RELATIVE_TOLERANCE = 0.05
STILL_JOINT_SPEED_RAD_S = 1e-3
MIN_CYCLES_PER_STEP = 5
"""Each step's reading averages at least this many controller cycles (waiting longer if the controller is slow)."""
STABLE_SPREAD = 1e-3
"""The last cycles of a step count once actual_TCP_force varies by at most this (N or N·m) across them: the fed
value and the still arm make it constant."""
SETTLE_CYCLES = 3
"""A cycle counts for a step from this many controller cycles after the step's wrench can have arrived."""
CYCLE_TIMEOUT_S = 1.0
"""The check is not time-critical: it waits this long for a controller cycle (the controller's own watchdog still
pauses the program if the feed stops for 0.1 s)."""


class CheckAborted(FtacqError):
    """The check could not run to the end (the arm moved, the controller stopped answering)."""


@dataclass(frozen=True)
class StepResult:
    """One fed step: what was fed, what was expected and measured (base axes, the compared 3-vector), verdict."""

    name: str
    fed: np.ndarray
    expected: np.ndarray
    measured: np.ndarray
    verdict: str  # "ok", "sign flipped", "frame rotated by X°", "mismatch"

    @property
    def ok(self) -> bool:
        return self.verdict == "ok"


@dataclass
class CheckReport:
    """All steps and a plain-words summary."""

    steps: list[StepResult] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return bool(self.steps) and all(step.ok for step in self.steps)

    def lines(self) -> list[str]:
        out = []
        for step in self.steps:
            out.append(f"{step.name:>5}: fed {np.round(step.fed, 3).tolist()}  expected "
                       f"{np.round(step.expected, 3).tolist()}  controller {np.round(step.measured, 3).tolist()}  "
                       f"-> {step.verdict}")
        bad = [s for s in self.steps if not s.ok]
        if not bad:
            out.append("PASS: frame, signs and payload handling match the convention")
        else:
            problems = "; ".join(f"{s.name}: {s.verdict}" for s in bad)
            out.append(f"FAIL: {problems}. Do not rely on the external input until this is understood "
                       "(docs/bridge.md, 'ftacq bridge --check')")
        return out


def judge(expected: np.ndarray, measured: np.ndarray, absolute_tolerance: float) -> str:
    """Compare two 3-vectors: "ok", "sign flipped", "frame rotated by X°" or "mismatch (…)"."""
    error = float(np.linalg.norm(measured - expected))
    size = float(np.linalg.norm(expected))
    tolerance = absolute_tolerance + RELATIVE_TOLERANCE * size
    if error <= tolerance:
        return "ok"
    if size > absolute_tolerance and float(np.linalg.norm(measured + expected)) <= tolerance:
        return "sign flipped"
    if size > absolute_tolerance and abs(float(np.linalg.norm(measured)) - size) <= tolerance:
        cos = float(np.dot(measured, expected) / (np.linalg.norm(measured) * size))
        return f"frame rotated by {np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))):.0f}°"
    return f"mismatch (off by {error:.3g})"


def run_check(controller_input, switch, plan: FeedPlan, model: URModel, gravity_base_m_s2,
              hold_s: float = HOLD_S) -> CheckReport:
    """Enable the input with ``plan``, feed the steps, disable; return the report (raises CheckAborted).

    A thread feeds every controller cycle from before the enable call to after the disable call (the controller
    pauses the program 0.1 s after the input stops), while this thread steps through the wrenches."""
    steps = [("zero", np.zeros(6))]
    for axis in range(6):
        wrench = np.zeros(6)
        wrench[axis] = TEST_FORCE_N if axis < 3 else TEST_TORQUE_NM
        steps.append((f"+{AXES[axis]}", wrench))
    readings: list[np.ndarray] = []
    with _Feeder(controller_input) as feeder:
        feeder.wait_readings(0, 1)
        q0 = feeder.q
        if switch is not None:
            switch.set_payload(plan.payload_kg, plan.payload_cog_m)
            switch.enable_external_ft_input(True, plan.function, plan.sensor_mass_kg, plan.sensor_measuring_offset_m,
                                            plan.sensor_cog_m)
        try:
            for step, (_name, wrench) in enumerate(steps, start=1):
                feeder.set(step, wrench)
                time.sleep(hold_s)  # pacing only: what is read are the cycles after the value settled
                readings.append(feeder.wait_readings(step, MIN_CYCLES_PER_STEP))
                if float(np.max(np.abs(feeder.q - q0))) > 1e-3 or feeder.max_speed > STILL_JOINT_SPEED_RAD_S:
                    raise CheckAborted("the arm moved during ftacq bridge --check; the check needs the arm still")
        finally:
            if switch is not None:
                try:
                    switch.enable_external_ft_input(False, plan.function)
                except FtacqError as error:
                    raise CheckAborted(f"could not disable the external input after the check ({error}); if the "
                                       "program was paused, the controller saw no input for 0.1 s") from error
    report = CheckReport()
    base_R_flange = forward_kinematics(model, q0)[:3, :3]
    zero_expected = controller_tcp_force(np.zeros(6), plan, base_R_flange, plan.sensor_measuring_offset_m,
                                         gravity_base_m_s2)
    report.steps.append(StepResult("zero", np.zeros(6), zero_expected[:3], readings[0][:3],
                                   judge(zero_expected[:3], readings[0][:3], FORCE_TOLERANCE_N)))
    for (name, wrench), reading in zip(steps[1:], readings[1:]):
        part = slice(0, 3) if np.any(wrench[:3]) else slice(3, 6)
        tolerance = FORCE_TOLERANCE_N if part.start == 0 else TORQUE_TOLERANCE_NM
        expected = base_R_flange @ wrench[part]
        measured = (reading - readings[0])[part]
        report.steps.append(StepResult(name, wrench, expected, measured, judge(expected, measured, tolerance)))
    return report


class _Feeder:
    """Feeds the current test wrench every controller cycle on thread "ftacq-bridge-check" and keeps what the
    controller reports: per step, the actual_TCP_force of the cycles the controller sent after it surely held the
    step's wrench, q and the largest joint speed.

    "Surely held": the package's controller time is at least :data:`SETTLE_CYCLES` cycles past the latest controller
    time at which the step's first write can have arrived: its host send time minus the smallest host-minus-
    controller time difference seen (packages queued in the socket while this thread was late are older)."""

    def __init__(self, controller_input) -> None:
        self.input = controller_input
        self.current = np.zeros(6)
        self.step = 0
        self._first_write_s: float | None = None
        self._offset_s = np.inf
        self._lock = threading.Lock()
        self.settled: dict[int, list[np.ndarray]] = {}
        self.q = np.full(6, np.nan)
        self.max_speed = 0.0
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ftacq-bridge-check", daemon=True)

    def __enter__(self) -> "_Feeder":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def set(self, step: int, wrench: np.ndarray) -> None:
        with self._lock:
            self.step, self.current, self._first_write_s = step, np.array(wrench, dtype=float), None

    def wait_readings(self, step: int, n: int, timeout_s: float = 5.0) -> np.ndarray:
        """The mean actual_TCP_force over at least ``n`` settled cycles of ``step``."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self.error is not None:
                raise CheckAborted(f"the controller stopped answering during the check ({self.error})")
            with self._lock:
                forces = list(self.settled.get(step, ()))
            if len(forces) >= n:
                window = np.array(forces[-n:])
                if float(np.ptp(window, axis=0).max()) <= STABLE_SPREAD:  # the report no longer changes
                    return window.mean(axis=0)
            if time.monotonic() > deadline:
                raise CheckAborted(f"the controller's actual_TCP_force did not settle over {n} cycles within "
                                   f"{timeout_s:g} s of a check step (is the arm still, is force mode off?)")
            time.sleep(0.005)

    def _run(self) -> None:
        catching_up = True  # packages queued since the client connected: skipped, as the bridge does
        try:
            while not self._stop.is_set():
                cycle = self.input.next_cycle(timeout_s=CYCLE_TIMEOUT_S)
                self._offset_s = min(self._offset_s, cycle.received_s - cycle.timestamp_s)
                if catching_up and self.input.queued():
                    continue
                catching_up = False
                with self._lock:
                    first = self._first_write_s
                    if first is not None and cycle.timestamp_s >= first - self._offset_s + SETTLE_CYCLES * self.input.cycle_s:
                        self.settled.setdefault(self.step, []).append(cycle.tcp_force)
                    self.input.write(self.current)
                    if first is None:
                        self._first_write_s = time.monotonic()
                self.q = cycle.q
                self.max_speed = max(self.max_speed, float(np.max(np.abs(cycle.qd))))
        except BaseException as error:  # noqa: BLE001 - reported to the stepping thread
            self.error = error
