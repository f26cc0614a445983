"""The controller bridge: the sensor at full rate → compensation → low-pass filter → one wrench per controller cycle
into the UR controller's external F/T input, under a watchdog (docs/bridge.md).

Two threads::

    "ftacq-bridge-feed"   per controller cycle (the controller's output package is the clock):
                          take the sensor's new samples → bias-removed (raw feed) or compensated: the dynamic
                          model (gravity and the tool's inertial wrench) when the calibration has inertia, else
                          the static model (the flange orientation from this cycle's actual_q, Pinocchio's
                          forward kinematics: ftacq.kinematics.FlangeRotation) → Butterworth
                          low-pass (state carried across batches) → the newest filtered value through the feed
                          convention → checks → write external_force_torque
    caller's thread       enables the input (payload, enable call), waits for the end (--seconds, Ctrl-C, a
                          watchdog trip), publishes what is fed to the listeners, disables the input

Timing (docs/bridge.md "Timing"): the value answering one output package must reach the controller before the next
(2 ms at 500 Hz). The feed thread asks for real-time scheduling (SCHED_FIFO, :data:`REALTIME_PRIORITY`, as ur-rtde's
interfaces do with their ``rt_priority``; refused without CAP_SYS_NICE or an rtprio limit, then it runs at normal priority and
:attr:`BridgeSummary.feed_priority` says why); the interpreter's thread switch interval is shortened to
:data:`SWITCH_INTERVAL_S` while feeding, so the feed thread gets the interpreter within that when its package
arrives; and the sensor driver is asked to hold samples at most :data:`SENSOR_HOLD_S`. Both are given back when
the run ends, on every path (the driver's previous hold, as ``prefer_low_latency`` returned it).

Dynamic model: procedures.dynamic_compensation.DynamicCompensator, as in ``ftacq monitor``, with the controller
cycles this bridge receives as its robot state stream (:class:`CycleStates`): the rigid-body model once per cycle
(q̈ = target_qdd while the arm tracks the controller's trajectory, else a derivative of actual_qd), interpolated
onto each sample's own time (its sequence number on the host clock, less the lag ``identify --motion`` measured).
A batch with no cycle states around it is compensated statically.

Decimation: the filter runs on every sensor sample (7 kHz); each controller cycle takes its newest output, so the
cut-off (:data:`CUTOFF_FRACTION` of the controller rate) is the anti-alias filter. The stated delay is the
filter's low-frequency group delay plus the time from the newest sample to the write (measured, per cycle).

Start-up: the controller's packages queue from the moment the input client connects; the feed thread skips those
already superseded by a newer one (``queued``) unanswered, so the first value written answers the controller's
newest cycle, and the caller enables the input only after :data:`START_WRITES` fresh values. Until the enable
call nothing is written while the newest sample is older than ``max_staleness_s`` (a sensor's own start-up backlog
arriving in a burst), and nothing trips; the start must succeed within :data:`START_TIMEOUT_S`. The figures of :class:`BridgeSummary` (late answers, sample ages, counts) cover the
cycles while the input was enabled: from the enable call to the end of the feed, right after the disable call
(all of the feed when a PolyScope program enables the input).

Watchdog (feed thread, every cycle): the newest sample is older than ``max_staleness_s`` (sensor silent or the
bridge starved; a sample's age runs from its sample time, the sensor's own clock on the host's
(:class:`ftacq.timebase.SampleClock`, shared with the dynamic compensation), not from its arrival: a burst of
late samples is old), a sensor error or a saturated sample, a fed wrench changing by more than ``jump_force_n`` /
``jump_torque_nm`` in one cycle, or the controller's cycle missing for ``cycle_timeout_s``. Then nothing more is
written (the last written value was fresh and checked), the caller's thread disables the input and says why; if
the disable cannot arrive within 0.1 s the controller's own watchdog pauses the program. Ctrl-C disables first
(while still feeding fresh values), then stops feeding.

Over 500 lines: the feed loop, its watchdog, the per-cycle log and the run's summary share one loop's state; the
log (:class:`_Log`) and the filter (:class:`WrenchFilter`) are the parts that could be their own modules next.
"""

from __future__ import annotations

import gc
import logging
import math
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from drivers.sensor import ForceTorqueSensor, WrenchBatch
from drivers.ur_connection import CB3_RATE_HZ
from drivers.ur_ft_input import ControllerCycle
from drivers.ur_stream import OFFSET_COLUMN, ROW_COLUMNS, StateWindow
from ftacq.bridge_convention import FeedPlan
from ftacq.calibration import Calibration
from ftacq.timebase import DeviceClock, SampleClock
from ftacq.errors import DeviceError, DeviceTimeoutError, FtacqError
from ftacq.kinematics import FlangeRotation, URModel
from procedures.dynamic_compensation import DynamicCompensator
from procedures.events import Event, FedWrenches, Listener, Notice
from procedures.realtime import REALTIME_PRIORITY, ask_realtime  # (declared there: the CLI's help reads it)

log = logging.getLogger(__name__)

CUTOFF_FRACTION = 0.2
"""Low-pass cut-off as a fraction of the controller rate (100 Hz at 500 Hz, 25 Hz at 125 Hz)."""
FILTER_ORDER = 2
MAX_STALENESS_S = 0.05
"""The newest sensor sample must be at most this old when its value is written (half UR's own 0.1 s watchdog)."""
JUMP_FORCE_N, JUMP_TORQUE_NM = 50.0, 5.0
"""Largest change of the fed force (norm, N) / torque (norm, N·m) from one controller cycle to the next."""
CYCLE_TIMEOUT_S = 0.1
SWITCH_INTERVAL_S = 0.0002
"""The interpreter's thread switch interval while feeding, s (Python's default 5 ms is longer than a cycle)."""
SENSOR_HOLD_S = 0.0003
"""Longest the sensor driver may hold received samples before they are readable while feeding, s (drivers/sensor.py
``prefer_low_latency``; the Net F/T driver's default is 1 ms, to save CPU, and is given back after the run)."""
STATE_CYCLES = 256
"""Controller cycles of joint state kept for the dynamic model (0.5 s at 500 Hz)."""
ROBOT_STATE_RATE_HZ = CB3_RATE_HZ
"""RTDE rate (Hz) for ur-rtde's interfaces while bridging (payload, enable call): the bridge's own input client reads
the controller every cycle, so they need not (each costs ~5 % of a core at 500 Hz); every controller offers it."""
LOG_CHUNK_ROWS = 8192
"""Rows per chunk of the per-cycle log (16 s at 500 Hz, 0.7 MB)."""
LOG_KEEP_S = 600.0
"""The run's summary keeps the per-cycle log of the newest 10 minutes (27 MB at 500 Hz); the counts, the late
answers and the largest sample age cover the whole run."""
PUBLISH_PERIOD_S = 0.1
"""The caller's thread hands the fed values to the listeners this often (batched)."""
START_TIMEOUT_S = 2.0
"""The first sensor samples and controller cycles must arrive within this."""
START_WRITES = 25
"""Fresh values written (50 ms at 500 Hz) before the input is enabled: the start-up's bursts are over."""
LOG_COLUMNS = ("controller_time_s", "cycle_received_s", "written_s", "newest_sample_s", "samples", "fed_fx_n",
               "fed_fy_n", "fed_fz_n", "fed_tx_nm", "fed_ty_nm", "fed_tz_nm", "q1_rad", "q2_rad", "q3_rad", "q4_rad",
               "q5_rad", "q6_rad")
"""One row per controller cycle answered in :attr:`BridgeSummary.log` (monotonic host times; ``written_s`` is when
the value was checked and sent, NaN when nothing was written; ``newest_sample_s`` the newest sample's sample time;
the cycle's actual_q, which the viewer draws the arm from)."""
FED_COLUMNS = slice(5, 11)
"""The fed wrench's columns of :data:`LOG_COLUMNS`."""
Q_COLUMNS = slice(11, 17)
"""The cycle's joint angles' columns of :data:`LOG_COLUMNS`."""


class ControllerInput(Protocol):
    """What the bridge needs of drivers/ur_ft_input.URForceTorqueInput."""

    frequency_hz: float

    def next_cycle(self, timeout_s: float = ...): ...
    def queued(self) -> bool: ...
    def write(self, wrench) -> None: ...


class InputSwitch(Protocol):
    """What the bridge needs of drivers/ur.URRobot: the payload and the enable call."""

    def set_payload(self, mass_kg: float, cog_m) -> object: ...
    def enable_external_ft_input(self, enable: bool, function: str = ..., sensor_mass_kg: float = ...,
                                 sensor_measuring_offset_m=..., sensor_cog_m=...) -> None: ...


@dataclass(frozen=True)
class BridgeSettings:
    """Tunables of one bridge run (SI units)."""

    cutoff_hz: float | None = None
    filter_order: int = FILTER_ORDER
    max_staleness_s: float = MAX_STALENESS_S
    jump_force_n: float = JUMP_FORCE_N
    jump_torque_nm: float = JUMP_TORQUE_NM
    cycle_timeout_s: float = CYCLE_TIMEOUT_S
    realtime_priority: int = REALTIME_PRIORITY
    switch_interval_s: float = SWITCH_INTERVAL_S
    sensor_hold_s: float = SENSOR_HOLD_S
    log_keep_s: float = LOG_KEEP_S


@dataclass
class BridgeSummary:
    """What a bridge run did. ``log`` holds one row per controller cycle answered (:data:`LOG_COLUMNS`); the
    ``enabled_*`` figures, ``late_answers`` and ``max_sample_age_s`` cover the cycles while the input was enabled."""

    cycles: int = 0
    written: int = 0
    samples: int = 0
    duration_s: float = 0.0
    trip: str | None = None
    interrupted: bool = False
    enabled: bool = False
    """The input was enabled by the bridge (False without the enable call, or when it stopped before)."""
    disabled: bool = False
    filter_delay_s: float = 0.0
    cutoff_hz: float = 0.0
    sensor_rate_hz: float = 0.0
    controller_rate_hz: float = 0.0
    compensation: str = ""
    """"dynamic", "static" or "bias only" (raw feed)."""
    feed_priority: str = ""
    """How the feed thread was scheduled, e.g. "SCHED_FIFO 80" or "normal (…why…)"."""
    log: np.ndarray = field(default_factory=lambda: np.empty((0, len(LOG_COLUMNS))))
    """The newest ``log_keep_s`` of the run (all of a shorter run): ``cycles - len(log)`` older rows were dropped."""
    skipped_at_start: int = 0
    """Controller cycles already superseded when the feed began (queued since the client connected), not answered."""
    enabled_from_s: float = float("nan")
    enabled_until_s: float = float("nan")
    """The span the figures cover (host monotonic clock): from the enable call to the end of the feed, right after
    the disable call (the whole feed when a program enables the input); NaN when the input was never enabled."""
    enabled_cycles: int = 0
    enabled_written: int = 0
    """Controller cycles received, and values written, in that span (over the whole run)."""
    late_answers: int = 0
    """Values written later than one controller cycle after their package arrived, while enabled (whole run)."""
    max_sample_age_s: float = float("nan")
    """The oldest newest-sample age at a write while enabled (whole run), s."""

    def written_rows(self, while_enabled: bool = False) -> np.ndarray:
        """The log rows of cycles that were answered with a value (those written while the input was enabled)."""
        written = self.log[:, 2]
        keep = np.isfinite(written)
        if while_enabled:
            keep &= (written >= self.enabled_from_s) & (written <= self.enabled_until_s)
        return self.log[keep]

    def answer_time_s(self, while_enabled: bool = False) -> np.ndarray:
        """Time from a controller cycle's package arriving to the value written in answer, s (a value that must
        reach the controller before its next cycle: longer than one cycle is late)."""
        rows = self.written_rows(while_enabled)
        return rows[:, 2] - rows[:, 1]

    def staleness_s(self, while_enabled: bool = False) -> np.ndarray:
        """Age of the newest sensor sample (from its sample time) when each value was written, s."""
        rows = self.written_rows(while_enabled)
        return rows[:, 2] - rows[:, 3]


class WrenchFilter:
    """Butterworth low-pass over (N, 6) batches, second-order sections designed by scipy (``output="sos"``); the
    state is carried from batch to batch and starts in steady state on the first sample (no start-up transient).

    Each section runs through ``scipy.signal.lfilter`` (the same transposed direct-form recursion ``sosfilt`` runs
    per section): at 14 samples a call, ``sosfilt``'s own argument checks cost several times the filtering
    (benchmarks/README.md, controller bridge)."""

    def __init__(self, cutoff_hz: float, sample_rate_hz: float, order: int = FILTER_ORDER) -> None:
        if not 0 < cutoff_hz < 0.5 * sample_rate_hz:
            raise FtacqError(f"low-pass cut-off {cutoff_hz:g} Hz: must be between 0 and half the sensor rate "
                             f"({0.5 * sample_rate_hz:g} Hz)")
        from scipy import signal  # here, not at the top: scipy.signal (with scipy.stats) takes ~1 s to import

        self.sos = signal.butter(order, cutoff_hz, fs=sample_rate_hz, output="sos")
        self._sections = [(section[:3].copy(), section[3:].copy()) for section in self.sos]
        self._zi_unit = signal.sosfilt_zi(self.sos)[:, :, None]  # (sections, 2, 1): steady state for a unit step
        self.zi: np.ndarray | None = None
        _, delay = signal.group_delay((*signal.sos2tf(self.sos),), w=[1.0], fs=sample_rate_hz)
        self.delay_s = float(delay[0]) / sample_rate_hz
        """Group delay at 1 Hz, s (the delay of slow changes)."""
        self._lfilter = signal.lfilter

    def __call__(self, wrench: np.ndarray) -> np.ndarray:
        if self.zi is None:
            self.zi = self._zi_unit * wrench[0][None, None, :]
        out = wrench
        for k, (b, a) in enumerate(self._sections):
            out, self.zi[k] = self._lfilter(b, a, out, axis=0, zi=self.zi[k])
        return out


def _take(sensor: ForceTorqueSensor) -> WrenchBatch | None:
    """Every sample the driver holds, without waiting (None when there is none)."""
    try:
        return sensor.read(timeout_s=0.0)
    except DeviceTimeoutError:
        return None


class CycleStates:
    """The controller cycles' joint states as a robot state stream (``window``, as drivers.ur_stream.URStateStream)
    for :class:`procedures.dynamic_compensation.DynamicCompensator`: the newest :data:`STATE_CYCLES`, on the host
    clock as the RTDE state stream puts them (:class:`ftacq.timebase.DeviceClock`: the minimum-delay line of
    arrival − timestamp, following the clocks' rate error, one package at a time). Written and read by the feed
    thread. ``frequency_hz``: the controller's rate (0: not known), as the state stream reports it."""

    def __init__(self, capacity: int = STATE_CYCLES, frequency_hz: float = 0.0) -> None:
        self.frequency_hz = float(frequency_hz)
        self._rows = np.zeros((capacity, ROW_COLUMNS))  # laid out as drivers.ur_stream's kept rows
        self._count = 0
        self.clock = DeviceClock()

    def append(self, cycle: ControllerCycle) -> None:
        row = self._rows[self._count % len(self._rows)]
        row[0], row[1] = cycle.received_s, cycle.timestamp_s
        row[2:8], row[8:14], row[14:20], row[20:26] = cycle.q, cycle.qd, cycle.target_qd, cycle.target_qdd
        self.clock.observe_one(cycle.timestamp_s, cycle.received_s)
        row[OFFSET_COLUMN] = self.clock.map_time(cycle.timestamp_s) - cycle.timestamp_s
        self._count += 1

    def window(self, last: int) -> StateWindow:
        capacity = len(self._rows)
        n = min(self._count, capacity, last)
        start = (self._count - n) % capacity
        if start + n <= capacity:
            rows = self._rows[start:start + n].copy()
        else:
            rows = np.concatenate([self._rows[start:], self._rows[:start + n - capacity]])
        return StateWindow.from_rows(rows, self.clock)


class _Log:
    """One row per controller cycle (:data:`LOG_COLUMNS`) in fixed chunks of :data:`LOG_CHUNK_ROWS`, so that the
    feed thread never copies what it logged: a log grown by doubling copied it all at once, in the feed thread:
    30 ms after 2.5 min of feeding, 90 ms after 5, 130 ms after 10, 250 ms after 20 (benchmarks/bridge_log.py),
    every cycle meanwhile missed, and from 10 min on longer than UR's 0.1 s watchdog on the input, which pauses
    the program. Only the newest ``keep_rows`` (at least; whole chunks) are
    kept: when a new chunk starts, the oldest is dropped and its memory reused, so a long run allocates nothing.
    Row ``i`` of the run lives in chunk ``i // chunk_rows``.

    The feed thread calls :meth:`row`; any thread may call :meth:`rows` (it reads one consistent snapshot of the
    kept chunks; a reader more than ``keep_rows`` behind the feed could see a dropped chunk being reused: the
    publisher reads the rows of the last 0.1 s)."""

    def __init__(self, keep_rows: int, chunk_rows: int | None = None, expected_rows: int | None = None) -> None:
        self.chunk_rows = int(chunk_rows or LOG_CHUNK_ROWS)
        self.keep_chunks = max(2, -(-int(keep_rows) // self.chunk_rows) + 1)
        expected_chunks = -(-int(keep_rows if expected_rows is None else expected_rows) // self.chunk_rows) + 1
        self._spares = [self._new_chunk() for _ in range(min(self.keep_chunks, expected_chunks) - 1)]
        """Chunks allocated before feeding (here, in the caller's thread): a fresh 0.7 MB costs the thread that
        first writes it up to 2 ms of page faults on the development machine."""
        self._current = self._new_chunk()
        self._kept: tuple[int, tuple[np.ndarray, ...]] = (0, (self._current,))
        """(index of the oldest kept chunk, the kept chunks): replaced whole, never changed in place."""
        self.count = 0
        """Rows handed out so far (the whole run)."""
        self.complete = 0
        """Rows before this one are filled in (the publisher reads only those)."""

    def _new_chunk(self) -> np.ndarray:
        return np.full((self.chunk_rows, len(LOG_COLUMNS)), np.nan)

    def row(self) -> np.ndarray:
        """The next row, to be filled in by the caller (the feed thread)."""
        offset = self.count % self.chunk_rows
        if offset == 0 and self.count:
            first, chunks = self._kept
            if len(chunks) < self.keep_chunks:
                self._current = self._spares.pop() if self._spares else self._new_chunk()
            else:  # drop the oldest chunk and reuse its memory (a refill: 0.1 ms)
                self._current, first, chunks = chunks[0], first + 1, chunks[1:]
                self._kept = (first, chunks)  # dropped before the refill: a reader's new snapshot no longer has it
                self._current.fill(np.nan)
            self._kept = (first, chunks + (self._current,))
        self.count += 1
        return self._current[offset]

    @property
    def first_kept(self) -> int:
        """Index of the oldest row still kept."""
        return self._kept[0] * self.chunk_rows

    def rows(self, start: int, stop: int) -> np.ndarray:
        """A copy of rows ``start`` to ``stop`` (run indices), less those already dropped."""
        first, chunks = self._kept
        size = self.chunk_rows
        start = max(start, first * size)
        if stop <= start:
            return np.empty((0, len(LOG_COLUMNS)))
        parts = [chunks[k - first][max(start - k * size, 0):min(stop - k * size, size)]
                 for k in range(start // size, (stop - 1) // size + 1)]
        return np.concatenate(parts)


class Bridge:
    """Feed ``sensor`` into the controller's external F/T input (see the module docstring).

    Args:
        sensor: a started sensor. controller_input: a started drivers.ur_ft_input.URForceTorqueInput (owns the
        input; its output stream is the cycle clock and carries actual_q). switch: the enable call and the payload
        (drivers.ur.URRobot opened with ``leave_external_ft_input=True``), or None when a PolyScope program enables
        the input itself. plan: ftacq.bridge_convention.FeedPlan. calibration: for the bias (raw) or the
        compensation (compensated). model: the arm's kinematics (flange orientation from actual_q).
        listeners: :data:`procedures.events.Listener` s: they get :class:`~procedures.events.FedWrenches` about ten
        times a second and a :class:`~procedures.events.Notice` (source "bridge") when the feed starts and stops
        (level ERROR for a watchdog trip). They must not block (wrap a viewer in a BackgroundListener).
        clock_s: the host clock of the cycles' arrival stamps and the sensor's samples (time.monotonic; tests
        that date their stand-ins' cycles and samples themselves pass theirs).
    """

    def __init__(self, sensor: ForceTorqueSensor, controller_input: ControllerInput, switch: InputSwitch | None,
                 plan: FeedPlan, calibration: Calibration, model: URModel, settings: BridgeSettings = BridgeSettings(),
                 listeners: tuple[Listener, ...] = (), sensor_rate_hz: float | None = None,
                 clock_s: Callable[[], float] = time.monotonic) -> None:
        self.sensor, self.input, self.switch = sensor, controller_input, switch
        self.plan, self.calibration, self.model, self.settings = plan, calibration, model, settings
        self.listeners = tuple(listeners)
        self.controller_rate_hz = float(controller_input.frequency_hz)
        self.sensor_rate_hz = float(sensor_rate_hz or sensor.info.rate_hz)
        self.cutoff_hz = settings.cutoff_hz or CUTOFF_FRACTION * self.controller_rate_hz
        self.filter = WrenchFilter(self.cutoff_hz, self.sensor_rate_hz, settings.filter_order)
        self._bias = np.concatenate([calibration.force_bias, calibration.torque_bias])
        self._clock_s = clock_s
        self._sample_clock = SampleClock()
        """The samples' sample times (the sensor's own clock on the host's): what their age runs from."""
        self.states = CycleStates(frequency_hz=self.controller_rate_hz)
        """Every controller cycle's joint state, on the host clock (the dynamic model's robot stream)."""
        self.dynamic: DynamicCompensator | None = None
        if plan.feed == "raw":
            self.compensation = "bias only"
        elif calibration.has_dynamics:
            self.compensation = "dynamic"
            self.dynamic = DynamicCompensator(calibration, model, self.states, clock=self._sample_clock)
        else:
            self.compensation = "static"
        self._flange_rotation = FlangeRotation(model)
        """base_R_flange from a cycle's actual_q (Pinocchio), for the static model."""
        self.feed_priority = "normal"
        self._stop_feeding = threading.Event()
        self._done = threading.Event()
        self._trip: str | None = None
        self._log = _Log(0, expected_rows=0)
        self._samples = 0
        self._written = 0
        self._skipped = 0
        self._enabled_cycles = self._enabled_written = 0
        """Cycles received and values written in ``_window`` (counted by the feed thread)."""
        self._window = (np.inf, np.inf)
        """(from, until) on ``clock_s``: the rows written in it count into the run's figures (until the feed ends,
        the cycle or two after the disable call included)."""
        self._thread: threading.Thread | None = None

    @property
    def written(self) -> int:
        """Values written so far (read from any thread)."""
        return self._written

    # ------------------------------------------------------------------ feed thread
    def _sensor_frame(self, batch: WrenchBatch, cycle: ControllerCycle) -> np.ndarray:
        if self.plan.feed == "raw":
            return batch.wrench - self._bias
        if self.dynamic is not None:
            compensated = self.dynamic.compensate(batch, None)
            if compensated is not None:
                return compensated
        # static; or dynamic with no cycle state within MAX_STATE_GAP_S of the samples: this cycle's orientation. The
        # samples and this cycle are then over 50 ms apart: samples that old trip the age watchdog before one is
        # written; a cycle whose package arrived that late is answered late (counted in late_answers)
        return self.calibration.compensate(batch.wrench, self._flange_rotation(cycle.q).T)

    def _feed(self) -> None:
        settings = self.settings
        self.feed_priority = ask_realtime(settings.realtime_priority)
        held: np.ndarray | None = None
        newest_s = -np.inf
        previous: np.ndarray | None = None
        catching_up = True
        try:
            while not self._stop_feeding.is_set():
                self._log.complete = self._log.count
                try:
                    cycle = self.input.next_cycle(timeout_s=settings.cycle_timeout_s)
                    if catching_up:  # a package queued before feeding began: a newer one is here, answer that
                        catching_up = self.input.queued()
                except DeviceError as error:
                    self._trip_now(f"the controller's cycle stopped ({error})")
                    return
                if self.dynamic is not None:
                    self.states.append(cycle)
                if catching_up:
                    self._skipped += 1
                    continue
                row = self._log.row()
                row[0], row[1], row[4] = cycle.timestamp_s, cycle.received_s, 0
                row[Q_COLUMNS] = cycle.q
                start_s, end_s = self._window
                if start_s <= cycle.received_s <= end_s:
                    self._enabled_cycles += 1
                try:
                    batch = _take(self.sensor)
                except DeviceError as error:
                    self._trip_now(f"sensor error: {error}")
                    return
                samples = 0 if batch is None else len(batch)
                if batch is not None and samples:
                    saturated = np.count_nonzero(batch.saturated)
                    if saturated:
                        self._trip_now(f"the sensor reports saturation or an error status ({saturated} of "
                                       f"{samples} samples)")
                        return
                    filtered = self.filter(self._sensor_frame(batch, cycle))
                    held = filtered[-1]
                    newest_s = float(self._sample_clock.host_times(batch.time_s, batch.device_time_s)[-1])
                    self._samples += samples
                    row[4] = samples
                row[3] = newest_s
                if held is None:
                    continue  # nothing measured yet: nothing to feed (the input is not enabled before the first)
                now_s = self._clock_s()
                age_s = now_s - newest_s
                if age_s > settings.max_staleness_s and (start_s == np.inf or not self._written):
                    continue  # not enabled yet (a start-up burst of old samples): nothing written, nothing tripped
                if age_s > settings.max_staleness_s:
                    self._trip_now(f"the sensor went silent: newest sample {age_s * 1000:.0f} ms old (limit "
                                   f"{settings.max_staleness_s * 1000:.0f} ms)")
                    return
                fed = self.plan.fed_wrench(held)
                if previous is not None:
                    fx, fy, fz, tx, ty, tz = (fed - previous).tolist()
                    jump_f, jump_t = math.hypot(fx, fy, fz), math.hypot(tx, ty, tz)
                    if jump_f > settings.jump_force_n or jump_t > settings.jump_torque_nm:
                        self._trip_now(f"the fed wrench jumped by {jump_f:.1f} N / {jump_t:.2f} N·m in one "
                                       f"controller cycle (limits {settings.jump_force_n:g} N / "
                                       f"{settings.jump_torque_nm:g} N·m)")
                        return
                self.input.write(fed)
                row[2] = now_s  # the age checked is the age logged
                row[FED_COLUMNS] = fed
                previous = fed
                self._written += 1
                if start_s <= now_s <= end_s:
                    self._enabled_written += 1
        except Exception as error:  # noqa: BLE001 - any failure stops the feed and is reported as a trip
            self._trip_now(f"bridge failure: {type(error).__name__}: {error}")
        finally:
            self._log.complete = self._log.count
            self._done.set()

    def _trip_now(self, reason: str) -> None:
        if self._trip is None:
            self._trip = reason
        self._stop_feeding.set()

    # ------------------------------------------------------------------ caller's thread
    def run(self, duration_s: float | None = None, stop: threading.Event | None = None) -> BridgeSummary:
        """Feed until ``duration_s``, ``stop``, Ctrl-C or a watchdog trip; the input is disabled on every path."""
        stop = stop or threading.Event()
        self._log = _Log(int(self.settings.log_keep_s * self.controller_rate_hz),
                         expected_rows=None if duration_s is None else int(duration_s * self.controller_rate_hz * 1.2))
        self._late_answers, self._max_sample_age_s = 0, float("nan")
        self._window = (-np.inf if self.switch is None else np.inf, np.inf)
        summary = BridgeSummary(filter_delay_s=self.filter.delay_s, cutoff_hz=self.cutoff_hz,
                                sensor_rate_hz=self.sensor_rate_hz, controller_rate_hz=self.controller_rate_hz,
                                compensation=self.compensation)
        # both given back in the finally: the driver and the interpreter outlive this run
        previous_hold_s = self.sensor.prefer_low_latency(self.settings.sensor_hold_s)
        switch_interval_s = sys.getswitchinterval()
        sys.setswitchinterval(min(switch_interval_s, self.settings.switch_interval_s))
        # everything alive now (modules, drivers, the models) out of the cyclic collector's reach while feeding: a
        # full collection walking them holds the interpreter for 20-45 ms, longer than the staleness limit
        gc.freeze()
        start_s = time.monotonic()
        self._thread = thread = threading.Thread(target=self._feed, name="ftacq-bridge-feed", daemon=True)
        enabled = False
        published = 0
        try:
            thread.start()
            self._wait_first_write(start_s)
            if self.switch is not None and self._trip is None:
                self.switch.set_payload(self.plan.payload_kg, self.plan.payload_cog_m)
                self._window = (self._clock_s(), np.inf)  # the controller may take the input from the call on
                self.switch.enable_external_ft_input(True, self.plan.function, self.plan.sensor_mass_kg,
                                                     self.plan.sensor_measuring_offset_m, self.plan.sensor_cog_m)
                enabled = True
                self._notify(Notice(f"feeding: {self.plan.function} enabled, feed {self.plan.feed} "
                                    f"({self.compensation} compensation), feed thread {self.feed_priority}",
                                    source="bridge"))
            deadline_s = None if duration_s is None else start_s + duration_s
            while not stop.is_set() and not self._done.is_set():
                wait_s = PUBLISH_PERIOD_S
                if deadline_s is not None:
                    wait_s = min(wait_s, deadline_s - time.monotonic())
                    if wait_s <= 0:
                        break
                self._done.wait(wait_s)
                published = self._publish(published)
        except KeyboardInterrupt:
            summary.interrupted = True
        finally:
            # disable while still feeding fresh values (a trip has stopped the feed already), then stop feeding
            if enabled:
                summary.disabled = self._disable()
            self._stop_feeding.set()
            if thread.ident is not None:  # started
                thread.join(2 * self.settings.cycle_timeout_s + 1.0)
            self._publish(published)
            gc.unfreeze()
            sys.setswitchinterval(switch_interval_s)
            self.sensor.prefer_low_latency(previous_hold_s)
            summary.duration_s = time.monotonic() - start_s
            summary.feed_priority = self.feed_priority
            summary.trip = self._trip
            summary.cycles, summary.written, summary.samples = self._log.count, self._written, self._samples
            summary.log = self._log.rows(self._log.first_kept, self._log.count)
            summary.late_answers, summary.max_sample_age_s = self._late_answers, self._max_sample_age_s
            summary.enabled, summary.skipped_at_start = enabled, self._skipped
            summary.enabled_cycles, summary.enabled_written = self._enabled_cycles, self._enabled_written
            if self._window[0] < np.inf:  # enabled (or a program's input: the whole feed counts, from -inf)
                summary.enabled_from_s, summary.enabled_until_s = self._window
            input_state = self._input_state(summary)
            if self._trip:
                text = f"watchdog: {self._trip}; feed stopped, input {input_state}"
            else:
                text = f"feed stopped ({'Ctrl-C' if summary.interrupted else 'done'}), input {input_state}"
            self._notify(Notice(text, level="ERROR" if self._trip else "INFO", source="bridge"))
        return summary

    def _input_state(self, summary: BridgeSummary) -> str:
        if self.switch is None:
            return "left to the program"
        if not summary.enabled:
            return "never enabled"
        return "disabled" if summary.disabled else "NOT disabled"

    def _wait_first_write(self, start_s: float) -> None:
        while self._written < START_WRITES and self._trip is None:
            if time.monotonic() - start_s > START_TIMEOUT_S:
                self._trip_now(f"fewer than {START_WRITES} fresh sensor samples (at most "
                               f"{self.settings.max_staleness_s * 1000:.0f} ms old) and controller cycles within "
                               f"{START_TIMEOUT_S:g} s of the start")
                return
            self._done.wait(0.005)

    def _disable(self) -> bool:
        if self.switch is None:
            return False
        try:
            self.switch.enable_external_ft_input(False, self.plan.function)
            return True
        except (FtacqError, RuntimeError) as error:
            log.error("could not disable the external F/T input: %s (the controller pauses the program 0.1 s "
                      "after the input stops)", error)
            return False

    def _publish(self, published: int) -> int:
        """Hand the rows completed since ``published`` to the listeners and count them into the whole run's late
        answers and largest sample age (the per-cycle log keeps only the newest ``log_keep_s``)."""
        count = self._log.complete
        if count <= published:
            return count
        rows = self._log.rows(published, count)
        start_s, end_s = self._window
        rows = rows[np.isfinite(rows[:, 2])]  # the cycles a value was written in
        counted = rows[(rows[:, 2] >= start_s) & (rows[:, 2] <= end_s)]
        if len(counted):
            self._late_answers += int(np.count_nonzero(counted[:, 2] - counted[:, 1] > 1.0 / self.controller_rate_hz))
            self._max_sample_age_s = float(np.fmax(self._max_sample_age_s, np.max(counted[:, 2] - counted[:, 3])))
        if self.listeners:
            self._notify(FedWrenches(time_s=rows[:, 2], fed=rows[:, FED_COLUMNS], cycles=count - published,
                                     written=len(rows), joint_positions_rad=rows[:, Q_COLUMNS]))
        return count

    def _notify(self, event: Event) -> None:
        for listener in self.listeners:
            try:
                listener(event)
            except Exception:  # noqa: BLE001 - a broken viewer never stops the feed
                log.warning("bridge listener %r failed", listener, exc_info=True)
