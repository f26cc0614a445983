"""One way to run a checked chain of moveJs while recording the sensor and every robot state: the excitation stage
(:mod:`procedures.excitation`, no holds) and the quick calibration (:mod:`procedures.quick`, still holds between the
moves) both run here.

:class:`MotionRecorder` reads the sensor in its own thread (every batch kept) while :func:`run_waypoints` issues
the moves from the caller's thread (each blocking until arrived) and, after a move, holds still for a number of
robot states at the controller's RTDE rate. The record (:meth:`MotionRecorder.record`) puts sensor samples on the
host clock through the device's own sample times (the Net F/T's sample counter: a skipped sample is a gap, not a
shift) and robot states through the controller's timestamps, each through the minimum-delay line of the whole
recording (:func:`ftacq.timebase.device_to_host_clock`); q̈ is the physical arm's (``target_qdd`` of the measured
servo lag earlier, :func:`ftacq.dynamics.acceleration.physical_acceleration`). Ctrl-C or a fault stops the robot and
keeps what was recorded: the partial run is attached to the raised exception as ``error.motion_run``.

A run publishes :mod:`procedures.events` to its listeners as the full run does, so the dashboard and the progress
bar follow every motion alike: :class:`~procedures.events.PlanReady` (the waypoints), a
:class:`~procedures.events.StateChanged` per move ("moving") and hold ("holding"), then "done", "stopped"
(Ctrl-C) or "failed"; and a :class:`~procedures.events.WrenchSamples` per sensor read (at most one per
``READ_PERIOD_S``), with the newest robot state.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from drivers.ur_connection import E_SERIES_RATE_HZ
from ftacq.dynamics.acceleration import physical_acceleration
from ftacq.dynamics.identify import MotionRecord
from ftacq.kinematics import flange_pose
from ftacq.kinematics.trapezoid import move_duration_s
from ftacq.timebase import device_to_host_clock
from procedures import events

if TYPE_CHECKING:
    from drivers.sensor import ForceTorqueSensor, WrenchBatch
    from ftacq.kinematics import URModel

SENSOR_READ_TIMEOUT_S = 0.5
MAX_SILENT_READS = 6
"""Consecutive sensor reads without a sample (3 s) that end the recording as a fault."""
READ_PERIOD_S = 0.01
"""The recorder reads the sensor at most this often, seconds. Every sample is kept whatever the pace (the drivers
buffer them); its events need no more than 100 a second (the dashboard, the progress). Reading on every burst
instead (~500 reads/s from a 7 kHz Net F/T) cost ~15 % of a core in per-read decoding, state lookups and flange
poses."""
SETTLE_STATES = 5
"""Robot states waited for at rest after the last move (the record ends at rest)."""


@dataclass
class MotionRecorder:
    """Reads the sensor in a thread ("ftacq-motion-sensor") until stopped, keeping every batch; :meth:`record`
    assembles them with the robot states the stream received since :meth:`start`. Each batch is published to
    ``listeners`` as a :class:`~procedures.events.WrenchSamples` with the newest robot state (its flange pose by
    ``model``'s forward kinematics, when a model is given)."""

    sensor: ForceTorqueSensor
    stream: object
    batches: list[WrenchBatch] = field(default_factory=list)
    error: BaseException | None = None
    first_robot: int = 0
    listeners: Sequence[events.Listener] = ()
    model: URModel | None = None

    def __post_init__(self) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ftacq-motion-sensor", daemon=True)

    def _run(self) -> None:
        from ftacq.errors import DeviceTimeoutError

        silent = 0
        try:
            while not self._stop.is_set():
                read_at_s = time.monotonic()
                try:
                    batch = self.sensor.read(timeout_s=SENSOR_READ_TIMEOUT_S)
                except DeviceTimeoutError:
                    silent += 1  # a late stream (the driver reconnects): the identification sees a gap
                    if silent >= MAX_SILENT_READS:
                        raise
                    continue
                silent = 0
                self._keep(batch)
                self._stop.wait(read_at_s + READ_PERIOD_S - time.monotonic())
            with contextlib.suppress(DeviceTimeoutError):  # stopped: what the driver holds still belongs here
                self._keep(self.sensor.read(timeout_s=0.0))
        except BaseException as error:  # noqa: BLE001 - reported by the caller after the robot stopped
            self.error = error

    def _keep(self, batch: WrenchBatch) -> None:
        if len(batch):
            self.batches.append(batch)
            if self.listeners:
                events.publish(self.listeners, self._samples(batch))

    def _samples(self, batch: WrenchBatch) -> events.WrenchSamples:
        """The batch as an event, with the newest robot state (none before the first)."""
        newest = self.stream.window(last=1)  # type: ignore[attr-defined]
        if not len(newest):
            return events.WrenchSamples(batch)
        q = np.array(newest.q[-1])
        return events.WrenchSamples(batch, flange_pose=None if self.model is None else flange_pose(self.model, q),
                                    joint_positions_rad=q)

    def start(self) -> None:
        """Drop what the sensor buffered before, note the first robot state, start reading."""
        self.sensor.read(timeout_s=SENSOR_READ_TIMEOUT_S)
        self.first_robot = self.stream.count  # type: ignore[attr-defined]
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)

    def record(self) -> MotionRecord:
        """The record so far (host clock)."""
        return assemble_record(self.batches, self.stream, self.first_robot)


def assemble_record(batches: Sequence, stream, first_robot: int) -> MotionRecord:
    """The record of sensor ``batches`` and the robot states ``stream`` received from its ``first_robot``-th on:
    sensor samples on the host clock from their device times (arrival stamps for a sensor without a sample clock),
    robot states from the controller's timestamps, each stream through the minimum-delay line of the whole
    recording (the live line's height is the newest seconds', its slope error would tilt the recording's start)."""
    if batches:
        arrival = np.concatenate([b.time_s for b in batches])
        device = np.concatenate([b.device_time_s for b in batches])
        wrench = np.concatenate([b.wrench for b in batches])
    else:
        arrival, device, wrench = np.empty(0), np.empty(0), np.empty((0, 6))
    window = stream.window(last=max(stream.count - first_robot, 0))
    robot_times = device_to_host_clock(window.controller_time_s, window.arrival_s) if len(window) else window.time_s
    # q̈ of the physical arm, as q and q̇ (actual_*): target_qdd of the servo lag earlier, measured here
    qdd, servo_lag_s = physical_acceleration(robot_times, window.qd, window.target_qd, window.qdd)
    times = device_to_host_clock(device, arrival)
    return MotionRecord(times, wrench, robot_times, window.q, window.qd, qdd,
                        metadata={"robot_samples": len(window), "sensor_samples": int(arrival.size),
                                  "servo_lag_s": servo_lag_s,
                                  "sensor_clock": "device" if np.isfinite(device).any() else "arrival"})


@dataclass
class MotionRun:
    """What :func:`run_waypoints` recorded: the record, each waypoint's hold as (first, end) robot-state indices
    into the record's robot rows ((−1, −1) without a hold), and how many waypoints were reached."""

    record: MotionRecord
    holds: np.ndarray
    completed: int


def run_waypoints(robot, sensor, stream, waypoints_rad: np.ndarray, speed_rad_s: float, acceleration_rad_s2: float,
                  hold_s: Sequence[float] | np.ndarray | None = None, move_timeout_s: float = 60.0, *,
                  labels: Sequence[str] | None = None, set_names: Sequence[str] | None = None,
                  listeners: Sequence[events.Listener] = ()) -> MotionRun:
    """Move through ``waypoints_rad`` (W, 6; checked before) by moveJ while recording, holding still ``hold_s[k]``
    seconds (a count of robot states at the stream's RTDE rate) after waypoint k; return the :class:`MotionRun`.

    ``labels`` and ``set_names`` (:data:`ftacq.posesets.POSE_SETS`) name the waypoints in the events published to
    ``listeners`` (module docstring; default "W01"…, set "M"); flange poses come from the robot driver's model.
    ``stream`` is a started :class:`drivers.ur_stream.URStateStream`. Ctrl-C or a fault stops the robot; the run so
    far is attached to the raised exception as ``error.motion_run``."""
    from ftacq.posesets import MOTION_SET

    waypoints = np.asarray(waypoints_rad, dtype=float).reshape(-1, 6)
    count = len(waypoints)
    holds_s = np.zeros(count) if hold_s is None else np.asarray(hold_s, dtype=float)
    names = tuple(labels) if labels is not None else tuple(f"W{k + 1:02d}" for k in range(count))
    rate_hz = float(getattr(stream, "frequency_hz", 0.0) or E_SERIES_RATE_HZ)  # the stream's RTDE rate (CB3: 125 Hz)
    holds = np.full((count, 2), -1, dtype=int)
    model = getattr(robot, "model", None)
    listeners = list(listeners)
    completed = 0

    def state(name: str, k: int | None = None, message: str = "") -> None:
        events.publish(listeners, events.StateChanged(name, k, message, label="" if k is None else names[k],
                                                      measured=completed, total=count))

    if listeners:
        start_q = np.asarray(robot.joint_positions(), dtype=float)
        path = np.vstack([start_q, waypoints])
        events.publish(listeners, events.PlanReady(
            poses=np.array([flange_pose(model, q) if model is not None else np.full(6, np.nan) for q in waypoints]),
            joint_targets_rad=waypoints, labels=names,
            set_names=tuple(set_names) if set_names is not None else (MOTION_SET,) * count,
            estimated_duration_s=float(holds_s.sum()) + sum(
                move_duration_s(a, b, speed_rad_s, acceleration_rad_s2) for a, b in zip(path[:-1], path[1:])),
            joint_travel_rad=float(np.abs(np.diff(path, axis=0)).sum())))
    recorder = MotionRecorder(sensor, stream, listeners=listeners, model=model)
    recorder.start()
    try:
        for k, (target, hold) in enumerate(zip(waypoints, holds_s)):
            state("moving", k)
            if recorder.error is not None:
                raise recorder.error
            robot.move_joints(target, speed_rad_s, acceleration_rad_s2, timeout_s=move_timeout_s)
            if hold > 0:
                state("holding", k)
                begin = stream.count
                stream.wait_for_samples(begin + int(round(hold * rate_hz)), timeout_s=hold + 1.0)
                holds[k] = (begin - recorder.first_robot, stream.count - recorder.first_robot)
            completed = k + 1
        stream.wait_for_samples(stream.count + SETTLE_STATES, timeout_s=1.0)  # a few states at rest at the end
    except BaseException as error:
        try:
            robot.stop()
        finally:
            recorder.stop()
            error.motion_run = MotionRun(recorder.record(), holds, completed)  # type: ignore[attr-defined]
        interrupted = isinstance(error, KeyboardInterrupt)
        with contextlib.suppress(Exception):  # a critical listener's error must not hide the one that stopped the run
            state("stopped" if interrupted else "failed", None,
                  "interrupted" if interrupted else f"{type(error).__name__}: {error}")
        raise
    recorder.stop()
    if recorder.error is not None:
        state("failed", None, f"sensor: {recorder.error}")
        raise recorder.error
    state("done", None, f"{count} waypoints reached")
    return MotionRun(recorder.record(), holds, completed)


__all__ = ["MotionRecorder", "MotionRun", "run_waypoints", "assemble_record", "SENSOR_READ_TIMEOUT_S"]
