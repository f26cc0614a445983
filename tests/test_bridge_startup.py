"""The bridge's start-up and the figures it prints (procedures/bridge.py, ftacq/app/commands/bridge.py): the
controller's packages queued before the feed began are skipped, not answered with old values; the input is enabled
only after a fresh value; a sample's age runs from its sample time (the sensor's count), not its arrival; the
figures cover the cycles while the input was enabled. Stand-ins for the sensor, the controller's input and the
enable call on a simulated host clock: no network, no sleeps, no timing."""

from __future__ import annotations

import threading

import numpy as np

from drivers.sensor import SensorBase, SensorInfo, WrenchBatch
from drivers.ur_ft_input import ControllerCycle
from ftacq.app.commands.bridge import summary_line
from ftacq.bridge_convention import plan_feed
from ftacq.errors import DeviceTimeoutError
from ftacq.kinematics import ur_model
from procedures.bridge import START_WRITES, Bridge, BridgeSettings, BridgeSummary
from procedures.events import Notice
from tests.fakes.world import CellTruth

RATE_HZ = 7000.0
CYCLE_S = 0.002
PER_CYCLE = 14
"""Sensor samples per controller cycle (7 kHz / 500 Hz)."""
TRUTH = CellTruth()
PLAN = plan_feed(TRUTH.calibration(), "compensated", np.array([0.0, 0.0, 0.035]), sensor_body_kg=0.3)
SETTINGS = BridgeSettings(realtime_priority=0)


class _Clock:
    """The host clock of the stand-ins (the bridge's ``clock_s``), advanced by the controller one cycle a package
    and by a microsecond a reading (no two readings alike, as a real clock's)."""

    def __init__(self) -> None:
        self.now_s = 1000.0

    def __call__(self) -> float:
        self.now_s += 1e-6
        return self.now_s


class _Sensor(SensorBase):
    """A Net F/T-like sensor at 7 kHz with its own sample clock (``device_time_s``: its count over its rate): each
    read returns the samples taken up to ``delay_s`` before now on ``clock``, all stamped as arriving now
    (``arrived_when_taken``: stamped with their own sample times, as if each had arrived at once)."""

    def __init__(self, clock: _Clock) -> None:
        super().__init__()
        self.info = SensorInfo(transport="netft", serial="", firmware="", force_unit="N", torque_unit="N-m",
                               counts_per_force=1.0, counts_per_torque=1.0, rate_hz=RATE_HZ)
        self.clock = clock
        self.origin_s = clock() - 0.1  # streaming for 0.1 s when the feed begins
        self.taken = 0
        self.delay_s = 0.0
        self.arrived_when_taken = False

    def read(self, timeout_s: float | None = 1.0) -> WrenchBatch:
        upto = int((self.clock() - self.delay_s - self.origin_s) * RATE_HZ)
        n = upto - self.taken
        if n <= 0:
            raise DeviceTimeoutError("no new sample")
        sequence = np.arange(self.taken + 1, upto + 1)
        self.taken = upto
        wrench = np.tile(TRUTH.calibration().force_bias.tolist() + TRUTH.calibration().torque_bias.tolist(), (n, 1))
        arrival_s = self.origin_s + sequence / RATE_HZ if self.arrived_when_taken else np.full(n, self.clock())
        return WrenchBatch(time_s=arrival_s, wrench=wrench, counts=np.zeros((n, 6), dtype=np.int64),
                           status=np.zeros(n, dtype=np.uint32), sequence=sequence, saturated=np.zeros(n, dtype=bool),
                           device_time_s=sequence / RATE_HZ)


class _Controller:
    """A controller's output stream as the input client sees it: ``backlog`` packages already queued when the feed
    begins (2 ms apart, received at once), then one package per cycle, each 2 ms later on ``clock``, received
    ``late_by_s`` after it was sent. Stops the run (``stop``) after ``cycles`` fresh ones, or raises (a controller
    gone) when ``vanish`` is set. With ``gate``, once the bridge wrote what it writes before enabling, the next
    package waits for the enable call (a fixed order for the test). Records which cycle each written value answered."""

    frequency_hz = 500.0

    def __init__(self, clock: _Clock, stop: threading.Event, backlog: int = 0, cycles: int = 400,
                 vanish: bool = False) -> None:
        self.clock, self.stop, self.cycles, self.vanish = clock, stop, cycles, vanish
        self.backlog = backlog
        self.count = 0
        self.answered: list[int] = []
        self.on_cycle = lambda count: None
        self.late_by_s = 0.0
        self.enabled = threading.Event()
        self.gate = False

    def next_cycle(self, timeout_s: float = 0.1) -> ControllerCycle:
        if self.gate and len(self.answered) >= START_WRITES:
            assert self.enabled.wait(10.0)
        self.count += 1
        if self.count > self.backlog:
            if self.vanish and self.count > self.backlog + self.cycles:
                raise DeviceTimeoutError("robot controller: no RTDE data for 100 ms (controller cycle)")
            self.clock.now_s += CYCLE_S
            if self.count >= self.backlog + self.cycles:
                self.stop.set()
        self.on_cycle(self.count)
        zeros = np.zeros(6)
        return ControllerCycle(timestamp_s=self.count * CYCLE_S, q=np.array([0.3, -1.2, 1.4, -1.7, -1.5708, 0.4]),
                               qd=zeros, tcp_force=zeros, runtime_state=1, safety_status_bits=1,
                               received_s=self.clock() - self.late_by_s, tcp_pose=zeros, target_qd=zeros, target_qdd=zeros)

    def queued(self) -> bool:
        return self.count < self.backlog

    def write(self, wrench) -> None:
        self.answered.append(self.count)


class _Switch:
    """The enable call: records the controller's answered cycles when the input was enabled and disabled."""

    def __init__(self, controller: _Controller) -> None:
        self.controller = controller
        self.calls: list[tuple[bool, int]] = []

    def set_payload(self, mass_kg, cog_m) -> None:
        pass

    def enable_external_ft_input(self, enable, function="", sensor_mass_kg=0.0, sensor_measuring_offset_m=None,
                                 sensor_cog_m=None) -> None:
        self.calls.append((bool(enable), len(self.controller.answered)))
        if enable:
            self.controller.enabled.set()


def _run(controller: _Controller, sensor: _Sensor, clock: _Clock, stop: threading.Event,
         switch: _Switch | None = None) -> tuple[BridgeSummary, list]:
    events: list = []
    bridge = Bridge(sensor, controller, switch if switch is not None else _Switch(controller), PLAN,
                    TRUTH.calibration(), ur_model("UR5e"), SETTINGS, listeners=(events.append,), clock_s=clock)
    return bridge.run(duration_s=30.0, stop=stop), events


def test_cycles_queued_before_the_feed_are_skipped_and_the_input_enabled_after_a_fresh_answer():
    clock, stop = _Clock(), threading.Event()
    controller = _Controller(clock, stop, backlog=500)  # 1 s of packages queued while the sensor was opened
    switch = _Switch(controller)
    summary, _ = _run(controller, _Sensor(clock), clock, stop, switch)
    assert summary.trip is None, summary.trip
    assert summary.skipped_at_start == 500 - 1  # all but the newest queued one
    assert controller.answered[0] == 500  # the first value answers the newest package, not the oldest
    assert summary.written == len(controller.answered) and summary.cycles == controller.count - 499
    assert switch.calls[0][0] and switch.calls[0][1] >= START_WRITES  # enabled after fresh values were written
    assert summary.enabled and summary.disabled


def test_figures_count_only_the_cycles_while_the_input_was_enabled():
    clock, stop = _Clock(), threading.Event()
    controller = _Controller(clock, stop, cycles=400)
    controller.gate = True
    switch = _Switch(controller)

    def late_until_enabled(count: int) -> None:  # the packages before the enable call waited 10 ms
        controller.late_by_s = 0.0 if controller.enabled.is_set() else 0.010

    controller.on_cycle = late_until_enabled
    summary, _ = _run(controller, _Sensor(clock), clock, stop, switch)
    assert summary.trip is None, summary.trip
    assert switch.calls[0] == (True, START_WRITES)  # enabled after the start-up's values
    assert summary.enabled_written == summary.written - START_WRITES
    assert summary.enabled_cycles == summary.cycles - START_WRITES
    assert summary.late_answers == 0 and summary.max_sample_age_s < CYCLE_S
    assert len(summary.staleness_s(while_enabled=True)) == summary.enabled_written
    assert "nan" not in summary_line(summary)


def test_a_late_burst_of_samples_is_old_by_its_sample_time_and_trips_the_watchdog():
    clock, stop = _Clock(), threading.Event()
    controller = _Controller(clock, stop, cycles=1000)
    sensor = _Sensor(clock)

    def samples_queue_somewhere(count: int) -> None:  # from cycle 200 on, samples wait 1 ms longer each cycle
        sensor.delay_s = max(0.0, (count - 200) * 0.001)  # (half of them arrive: each read still has new ones)

    controller.on_cycle = samples_queue_somewhere
    summary, _ = _run(controller, sensor, clock, stop)
    # arrival stamps (each read has samples arriving now) would have fed all 1000 cycles
    assert summary.trip is not None and "the sensor went silent: newest sample 5" in summary.trip, summary.trip
    assert 240 <= max(controller.answered) <= 252  # the newest sample 40-52 ms old by its own count
    assert summary.disabled


def test_a_stop_before_the_input_was_enabled_says_so_and_prints_no_nan():
    clock, stop = _Clock(), threading.Event()
    controller = _Controller(clock, stop, cycles=30, vanish=True)
    sensor = _Sensor(clock)
    sensor.delay_s, sensor.arrived_when_taken = 0.06, True  # samples arrive 60 ms late: none fresh enough to write
    summary, events = _run(controller, sensor, clock, stop)
    assert summary.trip is not None and "cycle stopped" in summary.trip
    assert summary.written == 0 and not summary.enabled and not summary.disabled
    notice = [e for e in events if isinstance(e, Notice)][-1]
    assert "never enabled" in notice.text and "NOT disabled" not in notice.text
    line = summary_line(summary)
    assert "never enabled" in line and "nan" not in line and "NOT disabled" not in line


def test_old_samples_before_the_input_is_enabled_hold_the_feed_back_without_tripping():
    clock, stop = _Clock(), threading.Event()
    controller = _Controller(clock, stop, cycles=300)
    controller.gate = True  # the enable call comes after the start-up's values, at a known cycle
    switch = _Switch(controller)
    sensor = _Sensor(clock)
    sensor.arrived_when_taken = True

    def old_samples_first(count: int) -> None:  # cycles 1-40: every sample 60 ms old when it arrives
        sensor.delay_s = 0.06 if count <= 40 else 0.0

    controller.on_cycle = old_samples_first
    summary, _ = _run(controller, sensor, clock, stop, switch)
    assert summary.trip is None, summary.trip
    assert min(controller.answered) > 40  # nothing written from the old samples
    assert switch.calls[0] == (True, START_WRITES) and summary.enabled and summary.disabled
