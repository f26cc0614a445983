"""The live monitor: sensor batches → gravity compensation with the latest robot orientation → dashboard.

Three threads, each with one job::

    caller's thread ("acquisition")   sensor.read() → Calibration.compensate(…, flange_R_base) → hand-off
    "ftacq-dashboard"                 bounded queue → Dashboard (coalesced batches, robot, health)
    "ftacq-record"                    unbounded queue → CSV file (optional; never drops)

Acquisition never waits for the viewer: batches go to the dashboard through a bounded queue that drops (and
counts) when full, so a slow or vanished viewer costs frames on screen, never samples. The optional CSV
recorder gets every batch. The robot's state is read by its own reader at its own rate
(:class:`drivers.ur.URStateReader`); the monitor only asks it for the latest joint angles and flange pose.
Ctrl-C (KeyboardInterrupt in the acquisition thread) ends the run cleanly: threads joined, file finished.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivers.robot import RobotStateSource
from drivers.sensor import ForceTorqueSensor, WrenchBatch
from ftacq.errors import DeviceTimeoutError, FtacqError
from ftacq.so3 import rotation_from_rotvec

log = logging.getLogger(__name__)

BATCH_PERIOD_S = 0.01
"""The acquisition loop reads the sensor at most this often (the driver buffers samples in between)."""
READ_TIMEOUT_S = 1.0
"""Longest wait for the sensor's next samples before counting a timeout and trying again."""
DASHBOARD_QUEUE_BATCHES = 500
"""Batches the dashboard may lag behind (≈ 5 s at BATCH_PERIOD_S) before batches are dropped for the viewer."""
DASHBOARD_PERIOD_S = 0.05
"""The dashboard thread sends at most this often, coalescing the batches queued meanwhile (fewer, larger sends)."""
ROBOT_LOG_RATE_HZ = 30.0
HEALTH_LOG_RATE_HZ = 2.0
THREAD_JOIN_TIMEOUT_S = 10.0
"""How long close() waits for the dashboard and recorder threads to finish their queues."""


@dataclass
class MonitorSummary:
    """What a monitor run did.

    Attributes:
        samples: wrench samples the driver delivered (all of them went to the dashboard queue or were counted
            in ``viewer_dropped_samples``, and all went to the record file if any).
        batches: sensor reads that returned samples.
        compensated_samples: samples compensated (0 without a calibration or a robot).
        lost: samples the sensor stream lost (driver health, since the driver started).
        rate_hz: the sensor's sample rate as the driver measured it at the end of the run.
        timeouts: reads that timed out.
        viewer_dropped_batches, viewer_dropped_samples: dropped for the viewer only (queue full or viewer failed).
        duration_s: wall time of the run. interrupted: stopped by Ctrl-C. record_path: the CSV written, if any.
        dashboard_error: the dashboard thread's exception text, if it failed (acquisition went on).
    """

    samples: int = 0
    batches: int = 0
    compensated_samples: int = 0
    lost: int = 0
    rate_hz: float = 0.0
    timeouts: int = 0
    viewer_dropped_batches: int = 0
    viewer_dropped_samples: int = 0
    duration_s: float = 0.0
    interrupted: bool = False
    record_path: Path | None = None
    dashboard_error: str | None = None


@dataclass(frozen=True)
class _Item:
    """One batch as the acquisition thread hands it on."""

    batch: WrenchBatch
    compensated: np.ndarray | None  # (N, 6) or None
    flange_pose: np.ndarray | None  # (6,) pose used for compensation
    joint_positions_rad: np.ndarray | None  # (6,)


_STOP = object()


class _DashboardWorker:
    """Owns the "ftacq-dashboard" thread: drains the bounded queue into the dashboard."""

    def __init__(self, dashboard, sensor: ForceTorqueSensor, model, queue_batches: int,
                 robot_log_rate_hz: float, health_log_rate_hz: float, period_s: float = DASHBOARD_PERIOD_S,
                 robot: RobotStateSource | None = None) -> None:
        self.dashboard = dashboard
        self.sensor = sensor
        self.robot = robot
        self._robot_connected = True
        self.model = model
        self.queue: queue.Queue = queue.Queue(maxsize=queue_batches)
        self.dropped_batches = 0
        self.dropped_samples = 0
        self.error: BaseException | None = None
        self._robot_period_s = 1.0 / robot_log_rate_hz
        self._health_period_s = 1.0 / health_log_rate_hz
        self._period_s = period_s
        # Daemon: a sink stuck in a dead network connection must not keep the process alive after Ctrl-C;
        # close() still joins it (with a deadline) and re-raises its error.
        self._thread = threading.Thread(target=self._run, name="ftacq-dashboard", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def offer(self, item: _Item) -> None:
        """Hand a batch to the viewer without waiting; count it as dropped if the queue is full or the viewer failed."""
        if self.error is None:
            try:
                self.queue.put_nowait(item)
                return
            except queue.Full:
                pass
        self.dropped_batches += 1
        self.dropped_samples += len(item.batch)

    def close(self, timeout_s: float = THREAD_JOIN_TIMEOUT_S) -> None:
        """Let the thread log what is queued, then stop it (waiting at most ``timeout_s`` seconds)."""
        deadline = time.monotonic() + timeout_s
        if self._thread.is_alive():
            try:
                self.queue.put(_STOP, timeout=max(0.0, deadline - time.monotonic()))
            except queue.Full:
                log.warning("dashboard thread is not draining its queue; leaving it")
            self._thread.join(max(0.0, deadline - time.monotonic()))
            if self._thread.is_alive():
                log.warning("dashboard thread did not finish within %.1f s", timeout_s)

    def _run(self) -> None:
        last_robot_s = last_health_s = -np.inf
        stopping = False
        while not stopping:
            items = [self.queue.get()]
            send_at_s = time.monotonic() + self._period_s
            while items[-1] is not _STOP:  # coalesce the batches of one period into one send
                try:
                    items.append(self.queue.get(timeout=max(0.0, send_at_s - time.monotonic())))
                except queue.Empty:
                    break
            if any(item is _STOP for item in items):
                stopping = True
                items = [item for item in items if item is not _STOP]
            if not items or self.error is not None:
                self._count_dropped(items)
                continue
            try:
                last_robot_s, last_health_s = self._log(items, last_robot_s, last_health_s)
            except BaseException as error:  # noqa: BLE001 - kept and re-raised by the monitor, acquisition goes on
                self.error = error
                log.warning("dashboard failed; acquisition continues without it: %s", error)
                self._count_dropped(items)

    def _count_dropped(self, items: list) -> None:
        self.dropped_batches += len(items)
        self.dropped_samples += sum(len(item.batch) for item in items)

    def _check_robot(self, now_s: float) -> None:
        """Say on the dashboard when the robot's state stream is lost or back (compensation needs it)."""
        connected = bool(getattr(self.robot, "connected", True)) if self.robot is not None else True
        if connected != self._robot_connected:
            self._robot_connected = connected
            if connected:
                self.dashboard.log_text("robot state stream is back", time_s=now_s)
            else:
                log.warning("robot state stream lost: compensation uses the last orientation received")
                self.dashboard.log_text("robot state stream lost: compensation uses the last orientation received",
                                        level="WARN", time_s=now_s)

    def _log(self, items: list[_Item], last_robot_s: float, last_health_s: float) -> tuple[float, float]:
        time_s = np.concatenate([item.batch.time_s for item in items])
        raw = np.concatenate([item.batch.wrench for item in items])
        with_compensation = [item for item in items if item.compensated is not None]
        if len(with_compensation) == len(items):
            self.dashboard.log_wrench_batch(time_s, raw, np.concatenate([item.compensated for item in items]))
        else:  # a calibration without robot state for some batches: log the raw stream, compensated where known
            self.dashboard.log_wrench_batch(time_s, raw, None)
            for item in with_compensation:
                self.dashboard.log_wrench_batch(item.batch.time_s, item.batch.wrench, item.compensated)
        latest = items[-1]
        now_s = float(latest.batch.time_s[-1])
        if (self.model is not None and latest.joint_positions_rad is not None and latest.flange_pose is not None
                and now_s - last_robot_s >= self._robot_period_s):
            self.dashboard.log_robot(now_s, latest.joint_positions_rad, latest.flange_pose, self.model)
            last_robot_s = now_s
        if now_s - last_health_s >= self._health_period_s:
            self.dashboard.log_health(now_s, self.sensor.health(), viewer_dropped=self.dropped_samples)
            self._check_robot(now_s)
            last_health_s = now_s
        return last_robot_s, last_health_s


RECORD_COLUMNS = (
    "time_s", "x", "y", "z", "rx", "ry", "rz", "fx", "fy", "fz", "tx", "ty", "tz",
    "contact_fx", "contact_fy", "contact_fz", "contact_tx", "contact_ty", "contact_tz",
    "sequence", "status", "sample_saturated",
)
"""Columns of the ``--record`` CSV, one row per sample: host receive time (s, monotonic clock); the flange pose
used for compensation (m, rad; base frame, rotation vector; empty without a robot); the raw sensor-frame wrench
(N, N·m); the compensated contact wrench (empty without a calibration); the device's sequence number, status
word and saturation flag. The pose and wrench columns are named as in a pose record (:mod:`ftacq.posefile`), so
``ftacq compensate`` reads a monitor record as it is."""


class _Recorder:
    """Owns the "ftacq-record" thread: writes every batch to a CSV (atomically renamed into place at the end)."""

    def __init__(self, path: Path, header_lines: list[str]) -> None:
        self.path = Path(path)
        self.rows = 0
        self.error: BaseException | None = None
        self._header = header_lines
        self._queue: queue.SimpleQueue = queue.SimpleQueue()  # unbounded: the record never drops
        self._thread = threading.Thread(target=self._run, name="ftacq-record")

    def start(self) -> None:
        self._thread.start()

    def put(self, item: _Item) -> None:
        self._queue.put(item)

    def close(self) -> None:
        """Write what is queued, finish the file and join the thread; re-raise its error."""
        self._queue.put(_STOP)
        self._thread.join()
        if self.error is not None:
            raise self.error

    def _run(self) -> None:
        from ftacq.fileio import atomic_write

        try:
            with atomic_write(self.path) as handle:
                for line in self._header:
                    handle.write(f"# {line}\n")
                handle.write(",".join(RECORD_COLUMNS) + "\n")
                while (item := self._queue.get()) is not _STOP:
                    handle.write(self._format(item))
                    self.rows += len(item.batch)
        except BaseException as error:  # noqa: BLE001 - re-raised by close()
            self.error = error

    @staticmethod
    def _format(item: _Item) -> str:
        batch = item.batch
        n = len(batch)
        pose = np.full((n, 6), np.nan) if item.flange_pose is None else np.broadcast_to(item.flange_pose, (n, 6))
        contact = np.full((n, 6), np.nan) if item.compensated is None else item.compensated
        numbers = np.column_stack([batch.time_s, pose, batch.wrench, contact, batch.sequence, batch.status,
                                   batch.saturated.astype(np.int64)])
        cells = np.char.mod(["%.9f"] + ["%.9g"] * 6 + ["%.9g"] * 12 + ["%d"] * 3, numbers)
        cells[cells == "nan"] = ""  # not known: no robot, or no calibration
        return "\n".join(",".join(row) for row in cells) + "\n"


def flange_R_base_from_pose(flange_pose: np.ndarray) -> np.ndarray:
    """Return flange_R_base (3, 3) = base_R_flangeᵀ from a UR pose [x, y, z, rx, ry, rz] (rotation vector)."""
    return rotation_from_rotvec(np.asarray(flange_pose, dtype=float)[3:6]).T


@dataclass
class LiveMonitor:
    """Streams a started sensor through compensation to a dashboard and an optional CSV.

    Args:
        sensor: a started :class:`drivers.sensor.ForceTorqueSensor`.
        calibration: a :class:`ftacq.calibration.Calibration`, or None (raw only).
        robot: the robot's latest state (:class:`RobotStateSource`), or None (no compensation, no 3-D arm).
        dashboard: a :class:`ftacq.app.dashboard.Dashboard`, or None.
        model: the :class:`ftacq.kinematics.URModel` drawn in 3-D.
        record_path: write every sample to this CSV (see :data:`RECORD_COLUMNS`), or None.
        strict: re-raise a dashboard failure at the end of :meth:`run` (tests); live, it is only reported.
    """

    sensor: ForceTorqueSensor
    calibration: object | None = None
    robot: RobotStateSource | None = None
    dashboard: object | None = None
    model: object | None = None
    record_path: Path | None = None
    strict: bool = False
    batch_period_s: float = BATCH_PERIOD_S
    read_timeout_s: float = READ_TIMEOUT_S
    queue_batches: int = DASHBOARD_QUEUE_BATCHES
    dashboard_period_s: float = DASHBOARD_PERIOD_S
    robot_log_rate_hz: float = ROBOT_LOG_RATE_HZ
    health_log_rate_hz: float = HEALTH_LOG_RATE_HZ
    record_header: list[str] = field(default_factory=list)

    def run(self, duration_s: float | None = None, stop: threading.Event | None = None) -> MonitorSummary:
        """Stream until ``duration_s`` seconds have passed, ``stop`` is set, or Ctrl-C; return the summary.

        Sensor errors propagate after the threads are closed (the CSV keeps what was recorded).
        """
        stop = stop or threading.Event()
        summary = MonitorSummary(record_path=self.record_path)
        worker = None
        if self.dashboard is not None:
            worker = _DashboardWorker(self.dashboard, self.sensor, self.model, self.queue_batches,
                                      self.robot_log_rate_hz, self.health_log_rate_hz, self.dashboard_period_s,
                                      robot=self.robot)
            worker.start()
        recorder = _Recorder(self.record_path, self.record_header) if self.record_path is not None else None
        if recorder is not None:
            recorder.start()
        start_s = time.monotonic()
        deadline_s = None if duration_s is None else start_s + duration_s
        try:
            next_read_s = start_s
            while not stop.is_set():
                now_s = time.monotonic()
                if deadline_s is not None and now_s >= deadline_s:
                    break
                if next_read_s > now_s:  # pace reads: the driver buffers, fewer and larger batches cost less
                    stop.wait(next_read_s - now_s)
                next_read_s = max(next_read_s + self.batch_period_s, time.monotonic())
                timeout_s = self.read_timeout_s
                if deadline_s is not None:
                    timeout_s = max(0.0, min(timeout_s, deadline_s - time.monotonic()))
                try:
                    batch = self.sensor.read(timeout_s=timeout_s)
                except DeviceTimeoutError:
                    summary.timeouts += 1
                    continue
                if len(batch) == 0:
                    continue
                item = self._process(batch)
                summary.samples += len(batch)
                summary.batches += 1
                if item.compensated is not None:
                    summary.compensated_samples += len(batch)
                if worker is not None:
                    worker.offer(item)
                if recorder is not None:
                    recorder.put(item)
        except KeyboardInterrupt:
            summary.interrupted = True
        finally:
            summary.duration_s = time.monotonic() - start_s
            if worker is not None:
                worker.close()
                summary.viewer_dropped_batches = worker.dropped_batches
                summary.viewer_dropped_samples = worker.dropped_samples
                if worker.error is not None:
                    summary.dashboard_error = f"{type(worker.error).__name__}: {worker.error}"
            if recorder is not None:
                recorder.close()
            try:
                health = self.sensor.health()
                summary.lost, summary.rate_hz = int(health.lost), float(health.rate_hz)
            except FtacqError:
                log.warning("could not read the sensor's health at the end of the run", exc_info=True)
        if worker is not None and worker.error is not None and self.strict:
            raise worker.error
        return summary

    def _process(self, batch: WrenchBatch) -> _Item:
        pose = q = compensated = None
        if self.robot is not None:
            pose = np.asarray(self.robot.flange_pose(), dtype=float)
            q = np.asarray(self.robot.joint_positions(), dtype=float)
            if self.calibration is not None:
                compensated = self.calibration.compensate(batch.wrench, flange_R_base_from_pose(pose))
        return _Item(batch=batch, compensated=compensated, flange_pose=pose, joint_positions_rad=q)
