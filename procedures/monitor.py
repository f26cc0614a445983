"""The live monitor: sensor batches → compensation with the robot's state at their time → events for the listeners.

Three threads, each with one job::

    caller's thread ("acquisition")   sensor.read() → compensator → health checks → publish events
    "ftacq-listeners"                 a BackgroundListener: bounded queue → the listeners (dashboard, readout, …)
    "ftacq-record"                    unbounded queue → CSV file (optional; never drops)

The monitor publishes :mod:`procedures.events` as the calibration procedure does (it never calls a viewer):
every read as :class:`~procedures.events.WrenchSamples`, the arm as :class:`~procedures.events.RobotState`
(``robot_rate_hz``), the stream's health as :class:`~procedures.events.SensorStatus` (``status_rate_hz``) and
lines for the operator as :class:`~procedures.events.Notice`. The application chooses the listeners.

Acquisition never waits for a listener: events go through a :class:`procedures.delivery.BackgroundListener`,
whose bounded queue drops (and counts) samples when a viewer is slow: frames on screen are lost, never samples.
The optional CSV recorder gets every batch, with each sample's time on the host clock from the sensor's own clock
(:class:`ftacq.timebase.SampleClock`, shared with a dynamic compensator) and the mapping's uncertainty. The
robot's state is read by its own reader at its own rate (:class:`drivers.ur.URStateReader`); the monitor only asks
it for the latest joint angles and flange pose.
Ctrl-C ends the run cleanly: threads joined, file finished. Run from the main thread, :meth:`LiveMonitor.run` turns
the first SIGINT into its stop event, so the loop ends between two reads and every batch the driver handed over is
both published and recorded (a KeyboardInterrupt can strike between any two bytecodes: between publishing a batch
and recording it, the viewer and the record would disagree); a second Ctrl-C interrupts at once. A
KeyboardInterrupt raised in the acquisition thread otherwise (another thread, a custom SIGINT handler) still ends
the run cleanly.

Two seams, for what is added to the monitor without touching its loop:

- a :class:`Compensator` turns raw samples into the contact wrench given the robot's state
  (:class:`procedures.static_compensation.StaticCompensator` and
  :class:`procedures.dynamic_compensation.DynamicCompensator`: with the robot's state at the samples' time, from
  the RTDE state stream; :class:`GravityCompensator`: with the newest pose, for an arm that stays still). A
  compensator may also say the pose at each sample's time (``sample_flange_pose()``: the record's pose columns);
  a batch it leaves uncompensated (None, with a robot) is published flagged ``uncompensated``;
- :class:`HealthCheck` objects see every read (compensated) in the acquisition thread and return notices
  (warnings are also kept in :attr:`MonitorSummary.warnings`).

(Over 500 lines: the loop, its record writer and its Ctrl-C handling share the run's state and are read together.)
"""

from __future__ import annotations

import contextlib
import logging
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Iterator, Protocol, Sequence

import numpy as np

from drivers.robot import RobotStateSource
from drivers.sensor import ForceTorqueSensor, WrenchBatch
from ftacq.channels import CONTACT_COLUMNS
from ftacq.posefile import POSE_COLUMNS
from ftacq.timebase import SampleClock
from ftacq.errors import DeviceTimeoutError, FtacqError
from ftacq.so3 import rotation_from_rotvec
from procedures import events
from procedures.delivery import DEFAULT_MAX_QUEUED, DEFAULT_PERIOD_S, Fanout

if TYPE_CHECKING:
    from ftacq.calibration import Calibration

log = logging.getLogger(__name__)

BATCH_PERIOD_S = 0.01
"""The acquisition loop reads the sensor at most this often (the driver buffers samples in between)."""
READ_TIMEOUT_S = 1.0
"""Longest wait for the sensor's next samples before counting a timeout and trying again."""
ROBOT_RATE_HZ = 30.0
"""RobotState events per second (the arm in 3-D)."""
STATUS_RATE_HZ = 2.0
"""SensorStatus events per second (health plots, the live readout)."""
THREAD_JOIN_TIMEOUT_S = 10.0
"""How long the end of a run waits for the listeners to finish their queue."""
SWITCH_INTERVAL_S = 0.001
"""The interpreter's thread switch interval while streaming, s (given back at the end): the RTDE state reader and
the sensor's receive thread get the interpreter within this when their data arrive. At Python's default 5 ms the
RTDE reader was 5.6 ms late at the median and 11.8 ms at p90 beside the monitor's loop, 1.1 ms at the median with
1 ms (measured in issue 27), so the newest robot state lagged the sensor samples it should cover."""


def flange_R_base_from_pose(flange_pose: np.ndarray) -> np.ndarray:
    """Return flange_R_base (3, 3) = base_R_flangeᵀ from a UR pose [x, y, z, rx, ry, rz] (rotation vector)."""
    return rotation_from_rotvec(np.asarray(flange_pose, dtype=float)[3:6]).T


# ------------------------------------------------------------------------------------------------ seams


class Compensator(Protocol):
    """Turns raw sensor-frame samples into the contact wrench (N, 6) [N, N·m], sensor frame."""

    def compensate(self, batch: WrenchBatch, robot: events.RobotState | None) -> np.ndarray | None:
        """Return the contact wrench of ``batch`` given the robot's latest state, or None when it cannot
        (e.g. no robot state)."""


@dataclass(frozen=True)
class GravityCompensator:
    """Static gravity compensation with a :class:`ftacq.calibration.Calibration` and the latest flange orientation
    (:meth:`ftacq.calibration.Calibration.compensate`: raw − bias − tool weight in the sensor frame). Right only for
    an arm that stays still (tests, benchmarks of the stream): ``ftacq monitor`` uses
    :class:`procedures.static_compensation.StaticCompensator`, the orientation at each sample's time."""

    calibration: Calibration

    def compensate(self, batch: WrenchBatch, robot: events.RobotState | None) -> np.ndarray | None:
        if robot is None:
            return None
        return self.calibration.compensate(batch.wrench, flange_R_base_from_pose(robot.flange_pose))


class HealthCheck(Protocol):
    """Looks at every read in the acquisition thread (keep it to a few numpy operations per batch)."""

    def check(self, samples: events.WrenchSamples) -> Sequence[events.StreamEvent]:
        """Return events to publish (usually none): notices (WARN and ERROR ones are kept in the run's summary)
        or the check's own stream events."""


# ------------------------------------------------------------------------------------------------ summary


@dataclass
class MonitorSummary:
    """What a monitor run did.

    Attributes:
        samples: wrench samples the driver delivered (every one was published, or counted in
            ``dropped_samples``, and went to the record file if any).
        batches: sensor reads that returned samples.
        compensated_samples: samples compensated (0 without a compensator or a robot).
        first_sample_s, last_sample_s: receive times of the first and last sample (host monotonic clock, s).
        lost: samples the sensor stream lost (driver health, since the driver started); of which socket_drops
            (datagrams the kernel dropped at the receive socket: this host was late) and ring_overflows (the reader
            fell behind the driver's ring). The rest never reached this host's socket (the sender or the link).
        driver_rate_hz: the sample rate the driver measured at the end of the run.
        timeouts: reads that timed out.
        dropped_batches, dropped_samples: not delivered to the listeners (queue full, or every listener failed);
            never dropped from the record.
        duration_s: wall time of the run. interrupted: stopped by Ctrl-C. record_path: the CSV written, if any.
        listener_error: the first listener failure ("Type: message"), if any (acquisition went on).
        warnings: the WARN/ERROR notices of the health checks and of the robot state stream.
        clock_rate_error, clock_uncertainty_s: the sensor clock's mapping at the end of the run (s/s, s; 0 and inf
            without a device clock): :class:`ftacq.timebase.DeviceClock`.
    """

    samples: int = 0
    batches: int = 0
    compensated_samples: int = 0
    first_sample_s: float | None = None
    last_sample_s: float | None = None
    lost: int = 0
    socket_drops: int = 0
    ring_overflows: int = 0
    driver_rate_hz: float = 0.0
    timeouts: int = 0
    dropped_batches: int = 0
    dropped_samples: int = 0
    duration_s: float = 0.0
    interrupted: bool = False
    record_path: Path | None = None
    listener_error: str | None = None
    warnings: list[str] = field(default_factory=list)
    clock_rate_error: float = 0.0
    clock_uncertainty_s: float = float("inf")

    @property
    def span_s(self) -> float:
        """Seconds from the first to the last sample received (host monotonic clock); 0 with fewer than 2."""
        if self.first_sample_s is None or self.last_sample_s is None:
            return 0.0
        return max(0.0, self.last_sample_s - self.first_sample_s)

    @property
    def rate_hz(self) -> float:
        """samples / :attr:`span_s`: the rate the samples arrived at over the run, Hz (0 if unknown)."""
        return self.samples / self.span_s if self.span_s > 0 else 0.0


# ------------------------------------------------------------------------------------------------ record


RECORD_COLUMNS = (
    "time_s", *POSE_COLUMNS, *CONTACT_COLUMNS,
    "sequence", "status", "sample_saturated", "sample_time_s", "device_time_s", "clock_uncertainty_s",
)
"""Columns of the ``--record`` CSV, one row per sample: host receive time (s, monotonic clock); the flange pose
at the sample's time when the compensator knows it (``sample_flange_pose``: the pose the static compensation used),
else the one read with the batch (m, rad; base frame, rotation vector; empty without a robot); the raw sensor-frame wrench
(N, N·m); the compensated contact wrench (empty without a calibration, and for a batch left uncompensated: no
robot state near its samples); the device's sequence number, status word and saturation flag; the sample's time
on the host clock from the device's own clock (s, monotonic clock: :class:`ftacq.timebase.SampleClock`; the
receive time for a sensor without a sample clock), its time on the device's clock (s; empty without one) and the
mapping's uncertainty when the batch was read (s; empty without a device clock). The pose and wrench columns are named as in a pose record (:mod:`ftacq.posefile`), so
``ftacq compensate`` reads a monitor record as it is."""

_STOP = object()


def _stop_on_sigint(stop: threading.Event, interrupted: threading.Event, warn: bool = True) -> bool:
    """Make the first SIGINT set ``interrupted`` and ``stop`` (and put Python's default handler back, so that a
    second one raises KeyboardInterrupt at once). Only from the main thread and while SIGINT has Python's default
    handler (an ignored SIGINT stays ignored, a custom handler is kept); return whether it was installed."""
    if threading.current_thread() is not threading.main_thread():
        return False
    current = signal.getsignal(signal.SIGINT)
    if current is signal.SIG_IGN and warn:  # inherited: a shell without job control starts `cmd &` (and nohup) so
        log.warning("Ctrl-C (SIGINT) is ignored in this process (started in the background?): stop it with "
                    "SIGTERM (kill PID)")
    if current is not signal.default_int_handler:
        return False

    def handler(signum: int, frame: object) -> None:
        interrupted.set()
        stop.set()
        signal.signal(signal.SIGINT, signal.default_int_handler)

    signal.signal(signal.SIGINT, handler)
    return True


@contextlib.contextmanager
def ctrl_c_after() -> Iterator[None]:
    """Run one read with the first Ctrl-C held until its end (main thread, Python's SIGINT handler; a no-op
    elsewhere): the read is published and recorded alike, then KeyboardInterrupt is raised. A second Ctrl-C
    raises at once. For a caller that reads one batch at a time (:class:`ftacq.app.session.Cell`)."""
    interrupted = threading.Event()
    caught = _stop_on_sigint(threading.Event(), interrupted, warn=False)
    try:
        yield
    finally:
        if caught and signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
            signal.signal(signal.SIGINT, signal.default_int_handler)
    if interrupted.is_set():
        raise KeyboardInterrupt


class _Recorder:
    """Owns the "ftacq-record" thread: writes every batch to a CSV (atomically renamed into place at the end)."""

    def __init__(self, path: Path, header_lines: list[str], every: int = 1) -> None:
        from ftacq.decimation import Decimator

        self.path = Path(path)
        self._decimator = Decimator(every)
        self.rows = 0
        self.error: BaseException | None = None
        self._header = header_lines
        self._queue: queue.SimpleQueue = queue.SimpleQueue()  # unbounded: the record never drops
        self._thread = threading.Thread(target=self._run, name="ftacq-record")

    def start(self) -> None:
        self._thread.start()

    def put(self, samples: events.WrenchSamples, sample_time_s: np.ndarray, uncertainty_s: float) -> None:
        self._queue.put((samples, sample_time_s, uncertainty_s, self._decimator.keep(len(samples.batch))))

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
                    handle.write(self._format(*item))
                    self.rows += len(item[3])
        except BaseException as error:  # noqa: BLE001 - re-raised by close()
            self.error = error

    @staticmethod
    def _format(samples: events.WrenchSamples, sample_time_s: np.ndarray, uncertainty_s: float,
                rows: np.ndarray) -> str:
        """The batch's CSV rows: one ``%`` format per row (:data:`_ROW_FORMAT`), unknown values as empty cells.

        Per row, not per cell: ``np.char.mod`` over the (N, 25) cells cost 0.11 s of CPU per second of 7 kHz data
        (issue 27; the recorder thread then trails acquisition on a loaded machine and the queue, unbounded, holds
        the difference until Ctrl-C), this 0.03 s, with the same text. ``rows``: the samples kept."""
        batch = samples.batch
        n = len(batch)
        if not len(rows):
            return ""
        pose = samples.sample_flange_pose  # the pose of each sample's time, when the compensator knows it
        if pose is None:
            pose = np.full((n, 6), np.nan) if samples.flange_pose is None else np.broadcast_to(samples.flange_pose, (n, 6))
        contact = np.full((n, 6), np.nan) if samples.compensated is None else samples.compensated
        uncertainty = uncertainty_s if np.isfinite(uncertainty_s) else np.nan
        reals = np.column_stack([batch.time_s, pose, batch.wrench, contact, sample_time_s, batch.device_time_s,
                                 np.full(n, uncertainty)])[rows].tolist()
        integers = np.column_stack([batch.sequence, batch.status, batch.saturated.astype(np.int64)])[rows].tolist()
        text = "\n".join([_ROW_FORMAT % (*r[:19], *i, *r[19:]) for r, i in zip(reals, integers)]) + "\n"
        return text.replace("nan", "")  # not known (no robot, no calibration): only NaN prints as "nan"


_ROW_FORMAT = ",".join(["%.9f"] + ["%.9g"] * 18 + ["%d"] * 3 + ["%.9f", "%.9f", "%.3g"])
"""One record row in :data:`RECORD_COLUMNS` order: receive time, pose, raw and contact wrench (19 reals), sequence,
status, saturation (3 integers), sample time, device time, the clock's uncertainty."""


# ------------------------------------------------------------------------------------------------ the monitor


@dataclass
class LiveMonitor:
    """Streams a started sensor through a compensator to listeners (events) and an optional CSV.

    Args:
        sensor: a started :class:`drivers.sensor.ForceTorqueSensor`.
        robot: the robot's latest state (:class:`drivers.robot.RobotStateSource`), or None (no compensation that
            needs the arm, no RobotState events).
        compensator: a :class:`Compensator` (e.g. :class:`GravityCompensator`), or None (raw only).
        listeners: called with every event, from the "ftacq-listeners" thread (never from acquisition); those with
            ``direct = True`` from the acquisition thread (they only queue: :class:`procedures.delivery.Fanout`).
        checks: :class:`HealthCheck` objects, called in the acquisition thread with every read.
        record_path: write every sample to this CSV (see :data:`RECORD_COLUMNS`), or None.
        record_every: write only every k-th sample to it (:class:`ftacq.decimation.Decimator`; 1 = every one).
        strict: re-raise a listener's failure at the end of :meth:`run` (tests); live, it is only reported.
        queue_batches, listener_period_s: the BackgroundListener's queue bound and delivery period.
        sample_clock: the samples' :class:`~ftacq.timebase.SampleClock` (their times on the host clock, for
            the record); share it with a dynamic compensator so that each batch is observed once. Default: its own.
        sample_poses: give every published batch the flange pose at each sample's time when the compensator
            knows it (``WrenchSamples.sample_flange_pose``; always with a record).

    One run: :meth:`run`, or :meth:`start`, then :meth:`step` or :meth:`stream` from one thread at a time, then
    :meth:`finish` (what :class:`ftacq.app.session.Cell` does, for ``ftacq monitor`` and the Python API).
    """

    sensor: ForceTorqueSensor
    robot: RobotStateSource | None = None
    compensator: Compensator | None = None
    listeners: Sequence[events.Listener] = ()
    checks: Sequence[HealthCheck] = ()
    record_path: Path | None = None
    strict: bool = False
    batch_period_s: float = BATCH_PERIOD_S
    read_timeout_s: float = READ_TIMEOUT_S
    queue_batches: int = DEFAULT_MAX_QUEUED
    listener_period_s: float = DEFAULT_PERIOD_S
    robot_rate_hz: float = ROBOT_RATE_HZ
    status_rate_hz: float = STATUS_RATE_HZ
    record_header: list[str] = field(default_factory=list)
    record_every: int = 1
    sample_clock: SampleClock = field(default_factory=SampleClock)
    switch_interval_s: float = SWITCH_INTERVAL_S
    sample_poses: bool = False
    _summary: MonitorSummary | None = field(default=None, init=False, repr=False)
    _publisher: Fanout = field(default=None, init=False, repr=False)  # type: ignore[assignment]
    _recorder: _Recorder | None = field(default=None, init=False, repr=False)
    _finished: bool = field(default=False, init=False, repr=False)

    def run(self, duration_s: float | None = None, stop: threading.Event | None = None) -> MonitorSummary:
        """Stream until ``duration_s`` seconds have passed, ``stop`` is set, or Ctrl-C; return the summary.

        :meth:`start`, :meth:`stream`, :meth:`finish`. Sensor errors propagate after the threads are closed (the CSV
        keeps what was recorded). From the main thread, Ctrl-C stops the loop between two reads (see the module
        docstring).
        """
        self.start()
        try:
            self.stream(duration_s, stop)
        finally:
            summary = self.finish()
        if self._publisher.first_error is not None and self.strict:
            raise self._publisher.first_error
        return summary

    def start(self) -> None:
        """Start the listeners' and the record's threads and shorten the switch interval (once: :meth:`finish`
        ends what this started). Reads (:meth:`step`) may follow from any one thread at a time."""
        if self._summary is not None:
            return
        self._summary = MonitorSummary(record_path=self.record_path)
        self._publisher = Fanout(self.listeners, max_queued=self.queue_batches, period_s=self.listener_period_s)
        self._recorder = _Recorder(self.record_path, self.record_header, self.record_every) if self.record_path is not None else None
        if self._recorder is not None:
            self._recorder.start()
        self._last_robot_s = self._last_status_s = -np.inf
        self._robot_connected = True
        self._start_s = self._next_read_s = time.monotonic()
        self._switch_interval_s = sys.getswitchinterval()
        sys.setswitchinterval(min(self._switch_interval_s, self.switch_interval_s))

    @property
    def started(self) -> bool:
        """Whether :meth:`start` has run."""
        return self._summary is not None

    @property
    def summary(self) -> MonitorSummary:
        """The run's counts so far (complete after :meth:`finish`)."""
        if self._summary is None:
            raise RuntimeError("the monitor has not started")
        return self._summary

    def add_listener(self, listener: events.Listener) -> None:
        """Add a listener; once started, it receives the events published from then on."""
        self.listeners = [*self.listeners, listener]
        if self._publisher is not None:
            self._publisher.add(listener)

    def stream(self, duration_s: float | None = None, stop: threading.Event | None = None) -> None:
        """Read (:meth:`step`) until ``duration_s`` seconds have passed, ``stop`` is set, or Ctrl-C (then
        ``summary.interrupted``); from the main thread the first Ctrl-C ends the loop between two reads."""
        summary = self.summary
        stop = stop or threading.Event()
        interrupted = threading.Event()
        deadline_s = None if duration_s is None else time.monotonic() + duration_s
        sigint_caught = _stop_on_sigint(stop, interrupted)
        try:
            while not stop.is_set():
                if deadline_s is not None and time.monotonic() >= deadline_s:
                    break
                self.step(deadline_s, stop)
        except KeyboardInterrupt:
            summary.interrupted = True
        finally:
            if sigint_caught and signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
                signal.signal(signal.SIGINT, signal.default_int_handler)
            summary.interrupted = summary.interrupted or interrupted.is_set()

    def step(self, deadline_s: float | None = None, stop: threading.Event | None = None
             ) -> events.WrenchSamples | None:
        """Read the sensor once (paced: at most every ``batch_period_s``), then compensate, publish, record and
        check what it returned; return those samples, or None when nothing came before the read's timeout (or
        ``deadline_s``, monotonic clock, s). ``stop`` cuts the pacing wait short."""
        summary = self.summary
        now_s = time.monotonic()
        if self._next_read_s > now_s:  # pace reads: the driver buffers, fewer and larger batches cost less
            (stop or threading.Event()).wait(self._next_read_s - now_s)
        self._next_read_s = max(self._next_read_s + self.batch_period_s, time.monotonic())
        timeout_s = self.read_timeout_s
        if deadline_s is not None:
            timeout_s = max(0.0, min(timeout_s, deadline_s - time.monotonic()))
        try:
            batch = self.sensor.read(timeout_s=timeout_s)
        except DeviceTimeoutError:
            summary.timeouts += 1
            return None
        if len(batch) == 0:
            return None
        sample_time_s = self.sample_clock.host_times(batch.time_s, batch.device_time_s)
        samples = self._process(batch, sample_time_s)
        self._count(summary, samples)
        self._publisher(samples)
        if self._recorder is not None:
            self._recorder.put(samples, sample_time_s, self.sample_clock.uncertainty_s)
        self._run_checks(samples, summary)
        self._publish_periodic(samples, summary)
        return samples

    def finish(self) -> MonitorSummary:
        """Publish the last status, deliver what is queued, finish the record and join both threads, give the
        switch interval back; return the summary (safe twice). Re-raises the record's write error."""
        summary = self.summary
        if self._finished:
            return summary
        self._finished = True
        publisher = self._publisher
        sys.setswitchinterval(self._switch_interval_s)
        summary.duration_s = time.monotonic() - self._start_s
        summary.clock_rate_error = self.sample_clock.rate_error
        summary.clock_uncertainty_s = self.sample_clock.uncertainty_s
        try:
            health = self.sensor.health()
            summary.lost, summary.driver_rate_hz = int(health.lost), float(health.rate_hz)
            summary.socket_drops, summary.ring_overflows = int(health.socket_drops), int(health.ring_overflows)
            if summary.last_sample_s is not None:
                publisher(events.SensorStatus(summary.last_sample_s, health, publisher.dropped_samples))
        except FtacqError:
            log.warning("could not read the sensor's health at the end of the run", exc_info=True)
        publisher.close(THREAD_JOIN_TIMEOUT_S)
        summary.dropped_batches, summary.dropped_samples = publisher.dropped_batches, publisher.dropped_samples
        if publisher.first_error is not None:
            summary.listener_error = f"{type(publisher.first_error).__name__}: {publisher.first_error}"
        if self._recorder is not None:
            self._recorder.close()
        return summary

    # -- steps of the acquisition loop ------------------------------------------------------------------------

    def _robot_state(self, time_s: float) -> events.RobotState | None:
        if self.robot is None:
            return None
        state = getattr(self.robot, "joints_and_flange_pose", None)  # one state's both (URStateReader)
        q, pose = state() if state is not None else (self.robot.joint_positions(), self.robot.flange_pose())
        return events.RobotState(time_s=time_s, joint_positions_rad=np.asarray(q, dtype=float),
                                 flange_pose=np.asarray(pose, dtype=float))

    def _process(self, batch: WrenchBatch, sample_time_s: np.ndarray) -> events.WrenchSamples:
        robot = self._robot_state(float(batch.time_s[-1]))
        compensated = None if self.compensator is None else self.compensator.compensate(batch, robot)
        pose_at_samples = getattr(self.compensator, "sample_flange_pose", None)
        return events.WrenchSamples(batch=batch, compensated=compensated,
                                    flange_pose=None if robot is None else robot.flange_pose,
                                    joint_positions_rad=None if robot is None else robot.joint_positions_rad,
                                    sample_flange_pose=pose_at_samples() if pose_at_samples is not None and (
                                        self.record_path is not None or self.sample_poses) else None,
                                    sample_time_s=sample_time_s,
                                    uncompensated=self.compensator is not None and robot is not None
                                    and compensated is None)

    @staticmethod
    def _count(summary: MonitorSummary, samples: events.WrenchSamples) -> None:
        summary.samples += len(samples)
        summary.batches += 1
        if samples.compensated is not None:
            summary.compensated_samples += len(samples)
        if summary.first_sample_s is None:
            summary.first_sample_s = float(samples.batch.time_s[0])
        summary.last_sample_s = float(samples.batch.time_s[-1])

    def _notify(self, notice: events.Notice, summary: MonitorSummary) -> None:
        if notice.level != "INFO":
            summary.warnings.append(notice.text)
        self._publisher(notice)

    def _run_checks(self, samples: events.WrenchSamples, summary: MonitorSummary) -> None:
        for check in self.checks:
            for event in check.check(samples):
                if isinstance(event, events.Notice):
                    self._notify(event, summary)
                else:  # a check's own stream event (e.g. events.BiasDrift)
                    self._publisher(event)

    def _publish_periodic(self, samples: events.WrenchSamples, summary: MonitorSummary) -> None:
        """Publish the arm (``robot_rate_hz``) and the stream's health (``status_rate_hz``) on the sensor clock."""
        now_s = float(samples.batch.time_s[-1])
        joints, pose = samples.joint_positions_rad, samples.flange_pose  # both known, or both None (no robot)
        if joints is not None and pose is not None and now_s - self._last_robot_s >= 1.0 / self.robot_rate_hz:
            self._publisher(events.RobotState(now_s, joints, pose))
            self._last_robot_s = now_s
        if now_s - self._last_status_s >= 1.0 / self.status_rate_hz:
            self._publisher(events.SensorStatus(now_s, self.sensor.health(), self._publisher.dropped_samples,
                                                self.sample_clock.uncertainty_s))
            self._check_robot(now_s, summary)
            self._last_status_s = now_s

    def _check_robot(self, now_s: float, summary: MonitorSummary) -> None:
        """Say when the robot's state stream is lost or back (compensation needs it)."""
        connected = bool(getattr(self.robot, "connected", True)) if self.robot is not None else True
        if connected == self._robot_connected:
            return
        self._robot_connected = connected
        if connected:
            self._notify(events.Notice("robot state stream is back", time_s=now_s), summary)
        else:
            text = "robot state stream lost: reads with no robot state near their samples are left uncompensated"
            log.warning(text)
            self._notify(events.Notice(text, level="WARN", time_s=now_s), summary)


__all__ = ["LiveMonitor", "MonitorSummary", "Compensator", "GravityCompensator", "HealthCheck", "RECORD_COLUMNS",
           "flange_R_base_from_pose", "ctrl_c_after"]
