"""The bridge's per-cycle log over a long run (procedures/bridge.py ``_Log``): fixed chunks, never copied while
feeding, the newest ``log_keep_s`` kept, and the whole run's counts in the summary. Stand-ins for the sensor and
the controller's input on a simulated host clock: no network, no sleeps, no timing."""

from __future__ import annotations

import threading

import numpy as np

import procedures.bridge as bridge_module
from drivers.sensor import SensorBase, SensorInfo, WrenchBatch
from drivers.ur_ft_input import ControllerCycle
from ftacq.bridge_convention import plan_feed
from ftacq.kinematics import ur_model
from procedures.bridge import LOG_COLUMNS, Bridge, BridgeSettings, _Log
from procedures.events import FedWrenches
from tests.fakes.world import CellTruth


def test_rows_live_in_chunks_that_are_never_reallocated_and_the_oldest_are_dropped():
    log = _Log(keep_rows=10, chunk_rows=4)  # keeps ceil(10 / 4) + 1 = 4 chunks
    first_chunk_row = log.row()
    first_chunk_row[:] = 0.0
    for i in range(1, 16):  # 4 chunks: nothing dropped yet
        log.row()[:] = i
    chunks = {id(chunk) for chunk in log._kept[1]}
    assert len(chunks) == 4
    assert first_chunk_row[0] == 0.0 and log.rows(0, 1)[0, 0] == 0.0
    first_chunk_row[1] = -1.0  # the row handed out is the one kept: not a copy
    assert log.rows(0, 1)[0, 1] == -1.0
    for i in range(16, 43):
        log.row()[:] = i
    assert log.count == 43
    assert {id(chunk) for chunk in log._kept[1]} == chunks  # the dropped chunks' memory reused: nothing allocated
    assert log.first_kept == 28  # chunks 7..10 kept: rows 28..43
    kept = log.rows(0, log.count)
    np.testing.assert_array_equal(kept[:, 0], np.arange(28, 43))
    np.testing.assert_array_equal(log.rows(30, 37)[:, 3], np.arange(30, 37))  # across a chunk boundary
    assert log.rows(5, 20).shape == (0, len(LOG_COLUMNS))  # all dropped


class _Clock:
    """The host clock of the stand-ins (the bridge's ``clock_s``): the controller advances it one cycle (2 ms) per
    package, so the figures do not depend on how fast this machine runs the feed thread. Dated by the real clock,
    a loaded machine made tens of answers "late" (once ``assert 120 == 2`` in a full run)."""

    def __init__(self) -> None:
        self.now_s = 1000.0

    def __call__(self) -> float:
        return self.now_s


class _Sensor(SensorBase):
    """One fresh sample each read, dated by ``clock``."""

    def __init__(self, clock: _Clock) -> None:
        super().__init__()
        self.info = SensorInfo(transport="stand-in", serial="", firmware="", force_unit="N", torque_unit="N-m",
                               counts_per_force=1.0, counts_per_torque=1.0, rate_hz=7000.0)
        self.clock = clock
        self.sequence = 0

    def read(self, timeout_s: float | None = 1.0) -> WrenchBatch:
        self.sequence += 1
        return WrenchBatch(time_s=np.array([self.clock()]), wrench=np.zeros((1, 6)),
                           counts=np.zeros((1, 6), dtype=np.int64), status=np.zeros(1, dtype=np.uint32),
                           sequence=np.array([self.sequence]), saturated=np.zeros(1, dtype=bool))


class _Controller:
    """Cycles as fast as the bridge asks, each 2 ms later on ``clock``; sets ``stop`` after ``cycles``. The cycles
    listed in ``late`` arrived ``late_by_s`` before the bridge got them (their answer is later than one cycle). At
    each cycle of ``gates`` it waits until the bridge has handed ``gates[cycle]`` cycles to its listeners
    (``published``)."""

    frequency_hz = 500.0

    def __init__(self, cycles: int, stop: threading.Event, late: set[int], late_by_s: float,
                 gates: dict[int, int], clock: _Clock) -> None:
        self.cycles, self.stop, self.late, self.late_by_s, self.gates = cycles, stop, late, late_by_s, gates
        self.clock = clock
        self.count = 0
        self.written = 0
        self.published = 0
        self.progress = threading.Condition()

    def listener(self, event) -> None:
        if isinstance(event, FedWrenches):
            with self.progress:
                self.published += event.cycles
                self.progress.notify_all()

    def next_cycle(self, timeout_s: float = 0.1) -> ControllerCycle:
        self.count += 1
        if self.count in self.gates:
            with self.progress:
                assert self.progress.wait_for(lambda: self.published >= self.gates[self.count], timeout=10.0)
        if self.count >= self.cycles:
            self.stop.set()
        self.clock.now_s += 1.0 / self.frequency_hz
        received_s = self.clock() - (self.late_by_s if self.count in self.late else 0.0)
        zeros = np.zeros(6)
        return ControllerCycle(timestamp_s=self.count * 0.002, q=np.array([0.3, -1.2, 1.4, -1.7, -1.5708, 0.4]),
                               qd=zeros, tcp_force=zeros, runtime_state=1, safety_status_bits=1,
                               received_s=received_s, tcp_pose=zeros, target_qd=zeros, target_qdd=zeros)

    def queued(self) -> bool:
        return False

    def write(self, wrench) -> None:
        self.written += 1


def test_a_run_longer_than_the_kept_log_counts_every_cycle(monkeypatch):
    monkeypatch.setattr(bridge_module, "LOG_CHUNK_ROWS", 256)
    stop = threading.Event()
    clock = _Clock()
    # late answers at cycles 100 and 2900; each is handed on before its chunk can be dropped (3 chunks kept)
    controller = _Controller(cycles=3000, stop=stop, late={100, 2900}, late_by_s=0.01, gates={400: 101, 2990: 2901},
                             clock=clock)
    truth = CellTruth()
    plan = plan_feed(truth.calibration(), "compensated", np.array([0.0, 0.0, 0.035]), sensor_body_kg=0.3)
    settings = BridgeSettings(log_keep_s=1.0, realtime_priority=0)  # 500 rows at 500 Hz: 3 chunks of 256 kept
    bridge = Bridge(_Sensor(clock), controller, None, plan, truth.calibration(), ur_model("UR5e"), settings,
                    listeners=(controller.listener,), clock_s=clock)
    summary = bridge.run(stop=stop)
    assert summary.trip is None
    assert summary.cycles == controller.count >= 3000 and summary.written == controller.written == summary.cycles
    assert controller.published == summary.cycles
    assert summary.enabled_written == summary.written  # a program's input (no enable call): the whole feed counts
    assert 500 <= len(summary.log) <= 768 < summary.cycles  # the newest chunks only
    assert np.all(np.diff(summary.log[:, 0]) > 0) and summary.log[-1, 0] == controller.count * 0.002
    assert summary.late_answers == 2  # cycle 100 left the log long before the end: still counted
    assert summary.max_sample_age_s == 0.0  # each sample is read in the cycle that dates it
