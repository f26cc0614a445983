"""The excitation stage: a short motion that makes the tool's inertia visible, planned and checked like the poses,
recorded with the robot's state, then identified (:mod:`ftacq.dynamics.identify`).

Plan: a chain of moveJs from the start configuration to random joint targets around it and back — small
amplitudes on the base, shoulder and elbow (the tool stays near where the poses were), large ones on the three
wrist joints (they turn the tool about every axis: that is what identifies the inertia) — each at the CELL.toml
joint speed and acceleration. Every segment is checked as the calibration's moves are
(:func:`procedures.plan.check_path`: joint limits and collisions along the whole path, tool cylinder and table
included); a target whose segment is not clear is drawn again. The plan states its duration; the robot moves only
after the operator confirmed it (as for the poses).

Recording: the sensor is read in its own thread, the robot's every RTDE state by :class:`drivers.ur_stream.URStateStream`,
while this thread issues the moves (each blocking until arrived). Ctrl-C stops the robot and keeps what was
recorded. Sensor samples are put on the host clock through the device's own sample times (the Net F/T's sample
counter: a skipped sample is a gap, not a shift of the samples after it) and the minimum-delay line of the whole
recording (:func:`ftacq.timebase.device_to_host_clock`), robot samples likewise through the controller's
timestamps and their arrival stamps; the residual lag is measured by the identification.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ftacq.dynamics.acceleration import physical_acceleration
from ftacq.dynamics.identify import MotionRecord
from ftacq.timebase import device_to_host_clock
from ftacq.errors import PlanError
from ftacq.kinematics.trapezoid import trapezoid_duration_s

if TYPE_CHECKING:
    from drivers.sensor import ForceTorqueSensor, WrenchBatch

log = logging.getLogger(__name__)

AMPLITUDE_RAD = (0.25, 0.2, 0.25, 1.0, 1.0, 1.5)
"""Largest excursion of each joint from the start configuration (base … wrist 3), rad."""
DEFAULT_MOVES = 10
"""Segments before the return to the start (≈ 2 s each at 1 rad/s, 2 rad/s²)."""
MAX_DRAWS = 200
"""Random targets tried per segment before the plan gives up."""
SENSOR_READ_TIMEOUT_S = 0.5
MAX_SILENT_READS = 6
"""Consecutive sensor reads without a sample (3 s) that end the recording as a fault."""


@dataclass(frozen=True)
class ExcitationPlan:
    """A checked excitation: moveJ joint targets (K, 6) rad from ``start_q_rad`` (the last one is the start again),
    at ``speed_rad_s`` and ``acceleration_rad_s2``; ``estimated_duration_s`` on a real robot."""

    start_q_rad: np.ndarray
    targets_rad: np.ndarray
    speed_rad_s: float
    acceleration_rad_s2: float
    estimated_duration_s: float
    seed: int = 0

    def to_json(self) -> dict:
        return {"start_q_rad": self.start_q_rad.tolist(), "targets_rad": self.targets_rad.tolist(),
                "speed_rad_s": self.speed_rad_s, "acceleration_rad_s2": self.acceleration_rad_s2,
                "estimated_duration_s": self.estimated_duration_s, "seed": self.seed}


def plan_excitation(settings, start_q_rad: np.ndarray, moves: int = DEFAULT_MOVES, seed: int = 0,
                    amplitude_rad: tuple[float, ...] = AMPLITUDE_RAD) -> ExcitationPlan:
    """Plan and check an excitation from ``start_q_rad`` with the plan settings' joint speed and acceleration.

    Raises PlanError when no clear segment is found (a cramped cell: reduce the amplitudes or move the start)."""
    from procedures.plan import check_path

    rng = np.random.default_rng(seed)
    start = np.asarray(start_q_rad, dtype=float).reshape(6)
    amplitude = np.asarray(amplitude_rad, dtype=float)
    speed, acceleration = float(settings.joint_speed_rad_s), float(settings.joint_acceleration_rad_s2)
    targets, q, problems = [], start, []
    for index in range(moves + 1):
        for _ in range(MAX_DRAWS):
            if index == moves:
                candidate = start
            else:  # a random excursion of every joint, each with a random sign
                candidate = start + amplitude * rng.uniform(0.4, 1.0, 6) * rng.choice((-1.0, 1.0), 6)
            problems = check_path(settings, q, candidate)
            if not problems or index == moves:
                break
        if problems:
            raise PlanError(f"excitation segment {index + 1}: no clear path found ({problems[0]}); move the robot to "
                            "a freer start configuration or reduce the excitation")
        targets.append(candidate)
        q = candidate
    targets_array = np.array(targets)
    path = np.vstack([start, targets_array])
    duration = sum(trapezoid_duration_s(float(np.max(np.abs(b - a))), speed, acceleration)
                   for a, b in zip(path[:-1], path[1:]))
    return ExcitationPlan(start, targets_array, speed, acceleration, float(duration), seed)


def format_excitation(plan: ExcitationPlan) -> str:
    """A few lines for the operator: what will move, how fast, how long."""
    span = np.ptp(np.vstack([plan.start_q_rad, plan.targets_rad]), axis=0)
    return (f"Excitation plan: {len(plan.targets_rad)} moveJ segments around the current configuration, "
            f"joint speed {plan.speed_rad_s:g} rad/s, acceleration {plan.acceleration_rad_s2:g} rad/s²\n"
            f"  joint ranges (rad): " + " ".join(f"{v:.2f}" for v in span) + "\n"
            f"  every segment checked for joint limits and collisions along its path: clear\n"
            f"  estimated duration: {plan.estimated_duration_s:.1f} s (ends where it started)")


@dataclass
class _SensorRecorder:
    """Reads the sensor in a thread until stopped, keeping every batch."""

    sensor: ForceTorqueSensor
    batches: list[WrenchBatch] = field(default_factory=list)
    error: BaseException | None = None

    def __post_init__(self) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ftacq-excitation-sensor", daemon=True)

    def _run(self) -> None:
        from ftacq.errors import DeviceTimeoutError

        silent = 0
        try:
            while not self._stop.is_set():
                try:
                    batch = self.sensor.read(timeout_s=SENSOR_READ_TIMEOUT_S)
                except DeviceTimeoutError:
                    silent += 1  # a late stream (the driver reconnects): the identification sees a gap
                    if silent >= MAX_SILENT_READS:
                        raise
                    continue
                silent = 0
                if len(batch):
                    self.batches.append(batch)
        except BaseException as error:  # noqa: BLE001 - reported by the caller after the robot stopped
            self.error = error

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)


def record_excitation(plan: ExcitationPlan, robot, sensor, stream, move_timeout_s: float = 60.0,
                      on_move=None) -> MotionRecord:
    """Run the plan (moveJ after moveJ) while recording sensor and robot; return the record (host clock).

    ``stream`` is a started :class:`drivers.ur_stream.URStateStream`. ``on_move(i, n)`` is called before each
    segment (progress). Ctrl-C or a fault stops the robot; the recording made so far is attached to the raised
    exception as ``error.motion_record``."""
    from procedures.plan import check_path  # noqa: F401 - the plan was checked; moves below follow it exactly

    sensor.read(timeout_s=SENSOR_READ_TIMEOUT_S)  # drop what was buffered before the stage
    first_robot = stream.count
    recorder = _SensorRecorder(sensor)
    recorder.start()
    try:
        for index, target in enumerate(plan.targets_rad):
            if on_move is not None:
                on_move(index, len(plan.targets_rad))
            if recorder.error is not None:
                raise recorder.error
            robot.move_joints(target, plan.speed_rad_s, plan.acceleration_rad_s2, timeout_s=move_timeout_s)
        stream.wait_for_samples(stream.count + 5, timeout_s=1.0)  # a few samples at rest after the last move
    except BaseException as error:
        try:
            robot.stop()
        finally:
            recorder.stop()
            error.motion_record = _assemble(recorder.batches, stream, first_robot)  # type: ignore[attr-defined]
        raise
    recorder.stop()
    if recorder.error is not None:
        raise recorder.error
    return _assemble(recorder.batches, stream, first_robot)


def _assemble(batches: list, stream, first_robot: int) -> MotionRecord:
    """The record: sensor samples on the host clock from their device times (arrival stamps for a sensor without
    a sample clock), robot states from the controller's timestamps, each stream through the minimum-delay line of
    the whole recording."""
    if batches:
        arrival = np.concatenate([b.time_s for b in batches])
        device = np.concatenate([b.device_time_s for b in batches])
        wrench = np.concatenate([b.wrench for b in batches])
    else:
        arrival, device, wrench = np.empty(0), np.empty(0), np.empty((0, 6))
    window = stream.window(last=max(stream.count - first_robot, 0))
    # both streams through the minimum-delay line of the whole recording (the live line's height is the newest
    # seconds', its slope error would tilt the recording's start against the sensor's)
    robot_times = device_to_host_clock(window.controller_time_s, window.arrival_s) if len(window) else window.time_s
    # q̈ of the physical arm, as q and q̇ (actual_*): target_qdd of the servo lag earlier, measured here
    qdd, servo_lag_s = physical_acceleration(robot_times, window.qd, window.target_qd, window.qdd)
    times = device_to_host_clock(device, arrival)
    return MotionRecord(times, wrench, robot_times, window.q, window.qd, qdd,
                        metadata={"robot_samples": len(window), "sensor_samples": int(arrival.size),
                                  "servo_lag_s": servo_lag_s,
                                  "sensor_clock": "device" if np.isfinite(device).any() else "arrival"})
