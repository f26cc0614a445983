"""The Python API: open a cell, read compensated batches, tare, close. ``ftacq monitor`` is a client of it.

    import ftacq
    with ftacq.open_cell("CELL.toml", calibration="calibration.json") as cell:   # or ftacq.open_cell(sim=True)
        for batch in cell.batches(seconds=5):
            print(batch.time_s[-1], batch.compensated[-1])
        cell.tare()

:func:`open_cell` opens the devices (the sensor, the robot's state reader and its RTDE state stream), builds the live
compensation the calibration allows (dynamic with the tool's inertia, else static with the pose at each sample's
time, the drift tracker with either: :mod:`procedures.bias_health`) and a :class:`procedures.monitor.LiveMonitor`
over them, with :class:`procedures.live_tare.LiveTare` among its checks. The sensor streams from the start; the
driver buffers what nobody has read yet. A :class:`Cell` reads only when asked, one read at a time whoever asks:
:meth:`Cell.batches` (the caller's thread reads), :meth:`Cell.tare`, :meth:`Cell.run` (``ftacq monitor``: to the
listeners until a duration, a stop or Ctrl-C). Every read takes the monitor's one path: compensated, published to
the listeners, written to the record, checked. Leaving the ``with`` block (normally, by an exception or Ctrl-C)
finishes the record, joins the monitor's threads and closes the devices (and the simulated cell).

A listener (a live viewer, a publisher) is a callable taking each :mod:`procedures.events` event, called from the
monitor's "ftacq-listeners" thread; it must not block (a slow one costs dropped viewer frames, never samples).
``cell.add_listener(listener, close=...)`` (or ``open_cell(listeners=...)``); ``close`` runs once after its last
event. docs/python-api.md. (Over 500 lines: the opening of a cell and the reading it allows are one contract.)
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Sequence

import numpy as np

from ftacq.drift import MAX_PRIOR_AGE_S
from ftacq.drift_health import BiasHealth
from ftacq.provenance import age_s, biases_measured_utc, require_same_sensor
from procedures.bias_health import DriftCheck, DriftCompensator

if TYPE_CHECKING:
    from ftacq.calibration import Calibration
    from procedures import events
    from procedures.monitor import MonitorSummary
    from procedures.tare import TareResult

NOMINAL_SENSOR_RATE_HZ = 7000.0
"""The rate a record's size per hour is reckoned at when the sensor does not say its own, Hz."""
FIRST_STATE_TIMEOUT_S = 1.0
"""Longest wait for the RTDE state stream's first package before the sensor starts, s (samples before it are left
uncompensated: no pose of their time)."""


@dataclass(frozen=True)
class SimOptions:
    """The simulated cell of ``open_cell(sim=...)`` (``sim=True``: these defaults: the arm still, no drift).

    Attributes: jog (the simulated technician jogs the arm 8 s, holds it 8 s and pushes on the tool meanwhile),
    drift_n_per_h (the sensor's force biases drift, N/h; torque 1/50 of it in N·m/h), warmup_n_per_h (a warm-up
    from power-on starting at this rate, N/h), swap_tool_after_s (another tool on the sensor after this, s),
    rate_hz (the Net F/T's sample rate), model (the simulated arm: UR5e; a CB3 model streams at 125 Hz).
    """

    jog: bool = False
    drift_n_per_h: float = 0.0
    warmup_n_per_h: float = 0.0
    swap_tool_after_s: float | None = None
    rate_hz: float | None = None
    model: str | None = None


@dataclass(frozen=True)
class Batch:
    """One sensor read: N samples in time order, numpy arrays with the sample along the first axis.

    Attributes:
        time_s: (N,) each sample's time on the host's monotonic clock (``time.monotonic``), s, from the sensor's
            own clock (docs/dynamics.md, "How the clocks are aligned"; the receive time for a sensor without one).
        receive_time_s: (N,) when the host received each sample, s (same clock).
        raw: (N, 6) the sensor's wrench [Fx, Fy, Fz N, Tx, Ty, Tz N·m], sensor frame.
        compensated: (N, 6) the contact wrench (raw minus the calibration's model: biases, tool weight and, with
            the tool's inertia, its inertial wrench), sensor frame; NaN rows where not compensated
            (``uncompensated``, or no calibration).
        flange_pose: (N, 6) base_T_flange [x, y, z m, rx, ry, rz rad] (rotation vector, base frame) at each
            sample's time when known, else the newest one read with the batch; NaN without a robot.
        saturated: (N,) bool, a channel at its range's end. sequence: (N,) int64, the device's sample counter.
        compensation: "dynamic" (gravity and inertia), "static" (gravity at each sample's pose) or "none".
        uncompensated: the calibration could not be applied (no robot state near these samples).
        drift_corrected: the drift tracker's offset was subtracted (``auto_tare`` and the offset trusted).
    """

    time_s: np.ndarray
    receive_time_s: np.ndarray
    raw: np.ndarray
    compensated: np.ndarray
    flange_pose: np.ndarray
    saturated: np.ndarray
    sequence: np.ndarray
    compensation: str
    uncompensated: bool
    drift_corrected: bool

    def __len__(self) -> int:
        return len(self.time_s)

    @property
    def model(self) -> np.ndarray:
        """(N, 6) what the compensation subtracted: raw − compensated, N and N·m."""
        return self.raw - self.compensated


@dataclass(frozen=True)
class LiveBias:
    """The biases now: the calibration's (as the last tare left them) plus the drift tracked since.

    Attributes: bias (6,) and sigma (6,) its 1σ, N and N·m (sensor frame); drift (6,) the tracked change since
    the calibration or the last tare; applied (the stream subtracts ``drift``: ``auto_tare`` and trusted);
    rest_windows (rest windows the tracker used); time_s (host monotonic clock, s).
    """

    time_s: float
    bias: np.ndarray
    sigma: np.ndarray
    drift: np.ndarray
    applied: bool
    rest_windows: int


class Cell:
    """An open cell streaming compensated wrenches; made by :func:`open_cell` (module docstring).

    Attributes: calibration (in force: its biases as the last :meth:`tare` left them; None: raw only), model (the
    arm's :class:`ftacq.kinematics.URModel`), robot_host, sensor_url, source (the CELL.toml path or "simulated
    cell"), sim_cell (the simulated cell, or None), compensator (the live one: dynamic or static; None without a
    calibration), drift (the :class:`procedures.bias_health.DriftCompensator`), notes (lines for the operator from
    the start: which compensation, the calibration's sensor match, when its biases were measured, the record's size
    per hour), sensor_rate_hz (the sensor's sample rate, Hz).
    """

    def __init__(self) -> None:
        self._calibration: Calibration | None = None
        self.model: Any = None
        self.robot_host = ""
        self.sensor_url = ""
        self.source = ""
        self.sim_cell: Any = None
        self.compensator: Any = None
        self.drift: Any = None
        self.notes: list[str] = []
        self.drift_text: str | None = None
        self.sensor_known = False  # the calibration is the simulated sensor's own: no sensor match to check
        self.sensor_rate_hz = NOMINAL_SENSOR_RATE_HZ
        self.average_s = 0.5
        self.monitor: Any = None
        self._tare: Any = None
        self._stack = contextlib.ExitStack()
        self._closers: list[Callable[[], None]] = []
        self._listeners: list[events.Listener] = []
        self._step_lock = threading.Lock()
        self._stop = threading.Event()
        self._backlog: deque[Batch] = deque()
        self._iterators = 0
        self._closed = False
        self._summary: MonitorSummary | None = None

    @property
    def calibration(self) -> Calibration | None:
        """The calibration in force (its biases as the last tare left them), or None (raw only)."""
        return self.drift.calibration if self.drift is not None else self._calibration

    # ------------------------------------------------------------------------------------------ reading

    def batches(self, seconds: float | None = None) -> Iterator[Batch]:
        """Yield every read as a :class:`Batch` (about every 10 ms) for ``seconds`` (None: until the cell is closed
        or the loop left). Reads made meanwhile by :meth:`tare` are yielded too; one iterator at a time."""
        deadline_s = None if seconds is None else time.monotonic() + float(seconds)
        self._iterators += 1
        try:
            while True:
                if self._backlog:
                    yield self._backlog.popleft()
                    continue
                if self._closed or (deadline_s is not None and time.monotonic() >= deadline_s):
                    return
                with self._step_lock:
                    if not self._backlog:
                        self._step(deadline_s)
        finally:
            self._iterators -= 1
            if not self._iterators:
                self._backlog.clear()

    def tare(self, seconds: float | None = None, timeout_s: float | None = None) -> TareResult:
        """Re-estimate the biases at the current pose from the next ``seconds`` (default CELL.toml's
        ``sampling.average_time_s``) of samples taken with the arm still and the tool untouched, keeping the rest of
        the calibration (as ``ftacq tare`` at the current pose; :mod:`procedures.live_tare`); the reads after it are
        compensated with the new biases and :attr:`calibration` carries them (``bias_history`` records the tare;
        ``ftacq.save_calibration`` writes it). Returns the :class:`procedures.tare.TareResult` (``.estimate.change``:
        the biases' change, N and N·m). Any thread: the one already reading serves it, else this one reads.
        Raises :class:`procedures.live_tare.TareError` (the arm not still within ``timeout_s``, default
        :data:`procedures.live_tare.TARE_TIMEOUT_S`), InputError (no calibration)."""
        from ftacq.errors import InputError
        from procedures.live_tare import TARE_TIMEOUT_S

        if self._tare is None:
            raise InputError("tare: this cell streams raw wrenches only (no calibration given)")
        if self._closed:
            raise InputError("tare: the cell is closed")
        request = self._tare.request(self.average_s if seconds is None else float(seconds),
                                     TARE_TIMEOUT_S if timeout_s is None else float(timeout_s))
        try:
            while not request.done.is_set():
                self._tare.expire()
                if self._closed:
                    self._tare.cancel("the cell was closed")
                elif self._step_lock.acquire(blocking=False):
                    try:
                        if not request.done.is_set():
                            self._step(None)
                    finally:
                        self._step_lock.release()
                else:  # another thread is reading: its reads serve the request
                    request.done.wait(0.05)
        except BaseException:
            self._tare.cancel("interrupted")
            raise
        return request.wait(0)

    @property
    def bias(self) -> LiveBias | None:
        """The current bias estimate (:class:`LiveBias`), or None without a calibration."""
        if self.drift is None:
            return None
        with self.drift.lock:  # (not the reading lock: ``run`` holds that for the whole stream)
            health = self.drift.health
            tracker = health.tracker
            time_s = self.monitor.summary.last_sample_s if self.monitor.started else None
            time_s = time_s if time_s is not None else (tracker.time_s or time.monotonic())
            calibration = tracker.calibration
            file_bias = np.concatenate([calibration.force_bias, calibration.torque_bias])
            drift = tracker.offset(time_s)
            return LiveBias(float(time_s), file_bias + drift, tracker.sigma(time_s), drift, bool(health.applied),
                            int(tracker.accepted))

    def run(self, seconds: float | None = None, stop: threading.Event | None = None) -> MonitorSummary:
        """Stream to the listeners (nothing to the caller) until ``seconds`` have passed, ``stop`` is set or
        Ctrl-C (from the main thread the first one ends the loop between two reads), then close the cell; return
        the run's :class:`procedures.monitor.MonitorSummary` (what ``ftacq monitor`` does)."""
        try:
            with self._step_lock:
                self._start_monitor()
                self.monitor.sample_poses = False  # no batch goes to the caller: no pose per sample (a CSV record
                stop = stop or self._stop          # still gets them: LiveMonitor._process)
                self.monitor.stream(seconds, stop)
        finally:
            summary = self.close()
        assert summary is not None  # (started above)
        return summary

    def add_listener(self, listener: events.Listener, close: Callable[[], None] | None = None) -> None:
        """Give every event from now on to ``listener`` (from the "ftacq-listeners" thread; it must not block);
        ``close`` runs once after its last event, when the cell closes. Add before the first read to get all."""
        if self.monitor is None:  # opening: the monitor is made with them
            self._listeners.append(listener)
        else:
            self.monitor.add_listener(listener)
        if close is not None:
            self._closers.append(close)

    # ------------------------------------------------------------------------------------------ closing

    @property
    def summary(self) -> MonitorSummary | None:
        """The monitor's counts (samples, lost, dropped for the listeners, ...); final once closed."""
        return self._summary if self._summary is not None else (
            self.monitor.summary if self.monitor is not None and self.monitor.started else None)

    def close(self) -> MonitorSummary | None:
        """Finish the record, join the monitor's threads, close the listeners given a ``close``, stop the devices
        (and the simulated cell); return the summary (None when nothing was read). Safe twice."""
        if self._closed:
            return self._summary
        self._closed = True
        self._stop.set()
        try:
            with self._step_lock:
                if self._tare is not None:
                    self._tare.cancel("the cell was closed")
                if self.monitor is not None and self.monitor.started:
                    self._summary = self.monitor.finish()
        finally:
            try:
                for close in reversed(self._closers):
                    close()
            finally:
                self._stack.close()
        return self._summary

    def __enter__(self) -> Cell:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------ one read

    def _start_monitor(self) -> None:
        if self._closed:
            raise RuntimeError("the cell is closed")
        self.monitor.start()

    def _step(self, deadline_s: float | None) -> None:
        """One read through the monitor (caller holds ``_step_lock``); queue it for an open iterator. From the
        main thread a Ctrl-C during the read lets it finish (published and recorded alike), then raises."""
        from procedures.monitor import ctrl_c_after

        self._start_monitor()
        dynamic_before = getattr(self.compensator, "dynamic_batches", 0)
        # the pose at each sample's time for a Batch only when an iterator takes it (forward kinematics per read)
        self.monitor.sample_poses = self._iterators > 0
        with ctrl_c_after():
            samples = self.monitor.step(deadline_s, self._stop)
            if samples is not None and self._iterators:
                self._backlog.append(self._batch(samples, dynamic_before))

    def _batch(self, samples: events.WrenchSamples, dynamic_before: int) -> Batch:
        raw = samples.batch
        n = len(raw)
        compensated = samples.compensated if samples.compensated is not None else np.full((n, 6), np.nan)
        pose = samples.sample_flange_pose
        if pose is None:
            pose = (np.full((n, 6), np.nan) if samples.flange_pose is None
                    else np.broadcast_to(np.asarray(samples.flange_pose, dtype=float), (n, 6)).copy())
        if samples.compensated is None:
            kind = "none"
        elif getattr(self.compensator, "dynamic_batches", 0) > dynamic_before:
            kind = "dynamic"
        else:
            kind = "static"
        time_s = samples.sample_time_s if samples.sample_time_s is not None else raw.time_s
        return Batch(time_s=np.asarray(time_s, dtype=float), receive_time_s=np.asarray(raw.time_s, dtype=float),
                     raw=np.asarray(raw.wrench, dtype=float), compensated=np.asarray(compensated, dtype=float),
                     flange_pose=np.asarray(pose, dtype=float), saturated=np.asarray(raw.saturated, dtype=bool),
                     sequence=np.asarray(raw.sequence, dtype=np.int64), compensation=kind,
                     uncompensated=bool(samples.uncompensated),
                     drift_corrected=bool(self.drift is not None and samples.compensated is not None
                                          and self.drift.health.applied))


def open_cell(config: str | Path | None = None, *, calibration: str | Path | Calibration | None = None,
              sim: bool | SimOptions = False, record: str | Path | None = None,
              record_rate_hz: float | None = 0.0,
              listeners: Sequence[events.Listener] = (), auto_tare: bool = False, force: bool = False,
              who: str = "ftacq.open_cell", prepare: Callable[[Cell], Callable[[], None] | None] | None = None
              ) -> Cell:
    """Open a cell and start its sensor streaming; use it in a ``with`` block (it closes everything on leaving).

    Args:
        config: the CELL.toml path (robot.host, robot.model, sensor.url, sampling.average_time_s), or None with
            ``sim``.
        calibration: a calibration file (``ftacq calibrate``/``identify``/``tare``) or a
            :class:`ftacq.Calibration`; None: raw only (with ``sim``: the simulated cell's true calibration).
        sim: True or :class:`SimOptions`: the simulated cell (UR5e controller and Net F/T at 7 kHz on loopback;
            from a source checkout).
        record: also write the samples to this CSV (the columns of ``ftacq monitor --record``, docs/formats.md).
        record_rate_hz: samples per second written to ``record``: 0 every sample (default), None as many as fit
            1 GB per hour (``ftacq monitor``'s default; ``cell.notes`` says the size per hour).
        listeners: event listeners (see :meth:`Cell.add_listener`).
        auto_tare: subtract the drift tracker's offset while it is trusted (``--auto-tare``, docs/drift-and-tare.md).
        force: accept a calibration made with another sensor (refused otherwise: InputError).
        who: the name in messages ("ftacq monitor" for the command).
        prepare: called with the cell once its model, calibration and source are known, before any device is
            opened (``ftacq monitor`` opens its viewer: spawning one takes seconds); what it returns, if anything,
            is called just before the sensor starts (the viewer's time axis starts with the sensor's stream).

    Raises InputError (a bad file or value: one line), DeviceError/DeviceTimeoutError (a device that does not
    answer); nothing stays open then.
    """
    cell = Cell()
    try:
        _open(cell, config, calibration, sim, record, record_rate_hz, listeners, auto_tare, force, who, prepare)
    except BaseException:
        cell.close()
        raise
    return cell


def _open(cell: Cell, config, calibration, sim, record, record_rate_hz, listeners, auto_tare: bool, force: bool,
          who: str, prepare) -> None:
    from drivers.sensor import open_sensor
    from drivers.ur import URStateReader
    from ftacq import __version__
    from ftacq.timebase import SampleClock
    from ftacq.errors import InputError
    from ftacq.kinematics import ur_model
    from ftacq.validation import check_output_file
    from procedures.live_tare import LiveTare  # (with the drift tracker's modules: imported before the sensor starts)
    from procedures.monitor import LiveMonitor

    stack = cell._stack
    if (config is None) == (not sim):
        raise InputError(f"{who}: give a CELL.toml path or sim=True (one of them)")
    if record is not None:
        record = check_output_file(record, "record")
    calibration_text = "none"
    if isinstance(calibration, (str, Path)):
        from ftacq.calfile import load_calibration

        calibration_text = str(calibration)
        calibration = load_calibration(calibration)
    elif calibration is not None:
        calibration_text = "given in Python"
    options = SimOptions() if sim is True else sim
    if options:
        from ftacq.app.sim_technician import DEFAULT_SIM_MODEL, SIM_SENSOR_RATE_HZ, SIM_WARMUP_TAU_S
        from ftacq.app.simcell import simulated_cell, simulated_truth

        drift_n_per_s = options.drift_n_per_h / 3600.0
        warmup_n = options.warmup_n_per_h / 3600.0 * SIM_WARMUP_TAU_S
        truth = simulated_truth(drift_n_per_s=(drift_n_per_s, -drift_n_per_s, drift_n_per_s),
                                drift_nm_per_s=(drift_n_per_s / 50, -drift_n_per_s / 50, drift_n_per_s / 50),
                                thermal_step_n=(warmup_n, -warmup_n, warmup_n),
                                thermal_step_nm=(warmup_n / 30, -warmup_n / 30, warmup_n / 30),
                                thermal_step_at_s=0.0, thermal_time_constant_s=SIM_WARMUP_TAU_S)
        sim_cell = cell.sim_cell = stack.enter_context(
            simulated_cell(truth=truth, sensor="netft", rate_hz=options.rate_hz or SIM_SENSOR_RATE_HZ,
                           model=options.model or DEFAULT_SIM_MODEL))
        cell.robot_host, cell.sensor_url = sim_cell.robot_host, sim_cell.sensor_url
        model_name = getattr(sim_cell, "model_name", DEFAULT_SIM_MODEL)
        if calibration is None:  # the simulated tool's true one, inertia included: compensated while jogging
            from ftacq.app.simcell import true_calibration

            calibration = true_calibration(sim_cell.truth)
            calibration_text = "simulated cell ground truth"
            cell.sensor_known = True  # the simulated sensor's own calibration: no sensor record to check
        cell.source = "simulated cell"
    else:
        from ftacq.app.config import load_config

        cell_config = load_config(config)
        cell.robot_host, model_name, cell.sensor_url = (cell_config.robot.host, cell_config.robot.model,
                                                        cell_config.sensor.url)
        cell.average_s = float(cell_config.sampling.average_time_s)
        cell.source = str(config)
    cell._calibration = calibration
    model = cell.model = ur_model(model_name)
    before_start = prepare(cell) if prepare is not None else None

    sensor = open_sensor(cell.sensor_url)
    stack.callback(sensor.close)
    cell.sensor_rate_hz = float(sensor.info.rate_hz or NOMINAL_SENSOR_RATE_HZ)
    robot = URStateReader(cell.robot_host, model=model)
    stack.callback(robot.close)
    robot.start()
    if options and (options.jog or options.swap_tool_after_s is not None):
        from ftacq.app.sim_technician import SimulatedTechnician

        stack.callback(SimulatedTechnician(cell.sim_cell, jog=options.jog,
                                           swap_after_s=options.swap_tool_after_s).start().close)
    sample_clock = SampleClock()  # one sensor clock for the record and the compensation
    if calibration is not None:  # its state stream before the sensor's: the first samples have states around them
        cell.compensator = _live_compensator(cell, calibration, model, sample_clock)
    if before_start is not None:
        before_start()
    sensor.start()
    checks: list = []
    if calibration is not None:
        cell.drift, drift_check = _drift_health(cell, calibration, sensor.info, auto_tare, force, who)
        cell.drift.moving = cell.compensator
        cell._tare = LiveTare(cell.drift)
        checks = [drift_check, cell._tare]
    record_every = 1
    if record is not None:
        from ftacq.app.file_budget import record_budget

        record_every, size = record_budget(cell.sensor_rate_hz, record_rate_hz)
        cell.notes.append(f"{'--record' if who.startswith('ftacq ') else 'record'} {record}: {size}")
    header = [f"ftacq {__version__} monitor recording", f"source: {cell.source}", f"sensor: {cell.sensor_url}",
              f"robot: {cell.robot_host} ({model.name})", f"calibration: {calibration_text}",
              "units: s, N, N·m, m, rad; wrenches in the sensor frame, pose = base_T_flange",
              "force_unit: N", "torque_unit: N-m",  # read by ftacq compensate (docs/formats.md)
              *([f"rows: every {record_every}th sample (--record-rate)"] if record_every > 1 else []),
              "times: time_s = receive time; sample_time_s = the sensor's own clock (device_time_s) on the host "
              "monotonic clock through the minimum-delay line, clock_uncertainty_s its uncertainty "
              "(docs/dynamics.md, How the clocks are aligned)"]
    cell.monitor = LiveMonitor(sensor, robot=robot, compensator=cell.drift, checks=checks,
                               listeners=[*listeners, *cell._listeners],
                               record_path=None if record is None else Path(record), record_header=header,
                               record_every=record_every, sample_clock=sample_clock, sample_poses=True)


def _live_compensator(cell: Cell, calibration, model, sample_clock) -> Any:
    """The live compensator on its own RTDE state stream (every state, on the host clock through the controller's
    own clock): the dynamic one when the calibration has inertia, else the static one; both compensate each sample
    with the robot's state at its time (the sensor's clock: ``sample_clock``, shared with the record) and leave a
    batch uncompensated when no state is near it. Says which in ``cell.notes``."""
    from drivers.ur_stream import URStateStream

    stream = URStateStream(cell.robot_host)
    cell._stack.callback(stream.close)
    stream.start()
    stream.wait_for_samples(1, FIRST_STATE_TIMEOUT_S)  # a controller still silent then: its samples come later
    if not calibration.has_dynamics:
        from procedures.static_compensation import StaticCompensator

        cell.notes.append("static compensation (the pose at each sample's time): this calibration has no inertia, "
                          "so the wrench is exact only while the arm is still (run ftacq calibrate --dynamic to "
                          "identify the tool's inertia)")
        return StaticCompensator(calibration, model, stream, clock=sample_clock)
    from procedures.dynamic_compensation import STATE_WAIT_S, DynamicCompensator

    compensator = DynamicCompensator(calibration, model, stream, clock=sample_clock, state_wait_s=STATE_WAIT_S)
    cell.notes.append(f"dynamic compensation (tool inertia from the calibration; sensor lag "
                      f"{1e3 * compensator.lag_s:.2f} ms): acceleration from target_qdd "
                      f"{1e3 * compensator.servo_lag_s:.2f} ms earlier (the arm's lag behind its target) while the arm "
                      "follows the controller's trajectory, else a filtered derivative of actual_qd")
    return compensator


def _drift_health(cell: Cell, calibration, sensor_info, auto_tare: bool, force: bool, who: str) -> tuple[Any, Any]:
    """Check the calibration belongs to the sensor (refused unless ``force``) and build the drift tracker's
    compensator and health check; say when the biases were measured (``cell.drift_text``)."""
    note = "" if cell.sensor_known else require_same_sensor(calibration, sensor_info, force, who)
    if note:
        cell.notes.append(note)
    measured = biases_measured_utc(calibration)
    age = age_s(measured)
    health = BiasHealth(calibration, age_s=MAX_PRIOR_AGE_S if age is None else age, auto_tare=auto_tare)
    compensator = DriftCompensator(health)
    history = calibration.metadata.get("bias_history") or []
    method = history[-1].get("method", "calibration") if history else "calibration"
    cell.drift_text = (f"biases from {method}, measured {measured or 'at an unknown time'}"
                       + (f" ({age / 3600.0:.1f} h ago)" if age is not None
                          else " (the first rest windows set the offset)")
                       + f"; drift tracker on, {'applied (--auto-tare)' if auto_tare else 'reporting only'}")
    cell.notes.append(cell.drift_text)
    return compensator, DriftCheck(compensator)


__all__ = ["open_cell", "Cell", "Batch", "LiveBias", "SimOptions"]
