"""One event path: the live monitor publishes :mod:`procedures.events` like the calibration procedure; listeners
run behind a :class:`procedures.delivery.BackgroundListener`; the calibration procedure's reads are tapped; the
monitor's seams (compensator, health checks); the live readout and the final line of ``ftacq monitor``."""

from __future__ import annotations

import ast
import io
import re
import threading
from pathlib import Path

import numpy as np
import pytest

from drivers.sensor import SensorHealth, WrenchBatch, open_sensor
from ftacq.app.readout import LiveReadout, format_summary
from procedures import events
from procedures.delivery import BackgroundListener, coalesce
from procedures.monitor import GravityCompensator, LiveMonitor, MonitorSummary
from procedures.tap import SensorTap
from tests.conftest import wait_until
from tests.fakes.netft import FakeNetFT
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose
from tests.scripted import BATCH_SAMPLES, Q_HOME_RAD, FixedRobotState, ScriptedSensor, physics_batches, \
    run_until_exhausted

ROOT = Path(__file__).resolve().parents[1]


def samples(n: int, start_s: float = 0.0, compensated: bool = False) -> events.WrenchSamples:
    batch = WrenchBatch(time_s=start_s + np.arange(n) * 1e-3, wrench=np.ones((n, 6)), counts=np.zeros((n, 6), int),
                        status=np.zeros(n, np.uint32), sequence=np.arange(n), saturated=np.zeros(n, bool))
    return events.WrenchSamples(batch, np.zeros((n, 6)) if compensated else None)


# ------------------------------------------------------------------------------------------------ delivery


def test_coalesce_joins_consecutive_samples_and_keeps_the_order():
    notice = events.Notice("hello")
    arm = events.RobotState(0.5, np.zeros(6), np.zeros(6))
    joined = coalesce([samples(3), arm, samples(2, 1.0), notice, samples(4, 2.0), samples(1, 3.0, compensated=True)])
    assert [type(e).__name__ for e in joined] == ["WrenchSamples", "RobotState", "Notice", "WrenchSamples",
                                                  "WrenchSamples"]
    assert [len(e) for e in joined if isinstance(e, events.WrenchSamples)] == [5, 4, 1]
    np.testing.assert_allclose(joined[0].batch.time_s, np.r_[np.arange(3) * 1e-3, 1.0 + np.arange(2) * 1e-3])


def test_background_listener_drops_only_samples_and_survives_a_failing_listener():
    release = threading.Event()
    seen: list[events.Event] = []

    def slow(event):
        release.wait(10.0)
        seen.append(event)

    def broken(event):
        raise RuntimeError("viewer exploded")

    background = BackgroundListener([broken, slow], max_queued=2, period_s=0.0)
    background(samples(5))
    wait_until(lambda: background.errors, "the broken listener to fail")  # first event in the slow listener's hands
    for k in range(6):
        background(samples(5, float(k + 1)))
    background(events.Notice("never dropped"))
    release.set()
    background.close()
    assert [str(error) for _, error in background.errors] == ["viewer exploded"]
    assert background.dropped_batches == 4 and background.dropped_samples == 20  # 6 offered, 2 could wait
    assert isinstance(seen[-1], events.Notice) and seen[-1].text == "never dropped"
    assert sum(len(e) for e in seen if isinstance(e, events.WrenchSamples)) == 15


# ------------------------------------------------------------------------------------------------ the tap


def test_the_tap_publishes_every_sample_the_drivers_own_average_reads():
    physics = SensorPhysics(CellTruth(), SettablePose(np.array([0.4, 0.1, 0.3, 2.0, -1.0, 0.5])), seed=3)
    published: list[events.WrenchSamples] = []
    with FakeNetFT(physics, rate_hz=1000.0) as device:
        sensor = open_sensor(device.url)
        try:
            sensor.start()
            with SensorTap(sensor, published.append):
                average = sensor.average(0.2)  # the Net F/T driver's average, reading through self.read
                assert "read" in vars(sensor)
            assert "read" not in vars(sensor)  # detached: the class's read again
            after = len(published)
            sensor.read(timeout_s=1.0)
        finally:
            sensor.close()
    assert len(published) == after  # nothing published once detached
    averaged = WrenchBatch.concatenate([p.batch for p in published])
    assert average.count >= 100 and len(averaged) >= average.count
    assert all(p.compensated is None and p.flange_pose is None for p in published)


# ------------------------------------------------------------------------------------------------ the monitor


def test_the_monitor_publishes_events_and_procedures_do_not_import_the_application():
    robot = FixedRobotState(Q_HOME_RAD)
    sensor = ScriptedSensor(physics_batches(robot.pose, 20))
    seen: list[events.Event] = []
    monitor = LiveMonitor(sensor, robot=robot, compensator=GravityCompensator(CellTruth().calibration()),
                          listeners=[seen.append], strict=True, batch_period_s=0.0, robot_rate_hz=1000.0)
    summary = run_until_exhausted(monitor, sensor)
    got = [e for e in seen if isinstance(e, events.WrenchSamples)]
    assert sum(len(e) for e in got) == summary.samples == 20 * BATCH_SAMPLES
    assert all(e.compensated is not None for e in got)
    assert sum(isinstance(e, events.RobotState) for e in seen) >= 1
    assert isinstance(seen[-1], events.SensorStatus)  # the final status, for the readout and the health plots
    for path in (ROOT / "procedures").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [alias.name for alias in node.names] if isinstance(node, ast.Import) else [node.module or ""]
                assert not any(name.startswith("ftacq.app") for name in names), path.name


class SpikeCheck:
    """A health check as issue 13 will plug in: warns once when |F| compensated exceeds a threshold."""

    def __init__(self, threshold_n: float) -> None:
        self.threshold_n = threshold_n
        self.warned = False

    def check(self, samples: events.WrenchSamples):
        peak = float(np.linalg.norm(samples.compensated[:, :3], axis=1).max())
        if peak > self.threshold_n and not self.warned:
            self.warned = True
            return [events.Notice(f"|F| {peak:.1f} N above {self.threshold_n} N", level="WARN", source="health",
                                  time_s=float(samples.batch.time_s[-1]))]
        return []


class ScaledCompensator:
    """A compensator as issue 12 will plug in: here the static one, scaled (any function of batch and state)."""

    def __init__(self, calibration, scale: float) -> None:
        self.inner, self.scale = GravityCompensator(calibration), scale

    def compensate(self, batch, robot):
        return self.scale * self.inner.compensate(batch, robot)


def test_compensator_and_health_check_seams():
    robot = FixedRobotState(Q_HOME_RAD)
    calibration = CellTruth().calibration()
    sensor = ScriptedSensor(physics_batches(robot.pose, 10, contact_after=5))
    seen: list[events.Event] = []
    monitor = LiveMonitor(sensor, robot=robot, compensator=ScaledCompensator(calibration, 2.0),
                          checks=[SpikeCheck(threshold_n=8.0)], listeners=[seen.append], batch_period_s=0.0)
    summary = run_until_exhausted(monitor, sensor)
    contact = [e for e in seen if isinstance(e, events.WrenchSamples)][-1].compensated
    np.testing.assert_allclose(contact[:, 2].mean(), 10.0, atol=0.1)  # the 5 N push, scaled by 2
    assert len(summary.warnings) == 1 and "above 8.0 N" in summary.warnings[0]
    assert [e.source for e in seen if isinstance(e, events.Notice)] == ["health"]


# ------------------------------------------------------------------------------------------------ the readout


def test_live_readout_prints_rate_forces_and_lost_from_the_events():
    stream = io.StringIO()
    readout = LiveReadout(stream, is_terminal=False)
    health = SensorHealth(lost=3, rate_hz=7000.0)
    readout(events.SensorStatus(10.0, health))
    batch = samples(3500, 10.0)
    compensated = np.tile([3.0, 0.0, 4.0, 0.0, 0.03, 0.04], (3500, 1))
    readout(events.WrenchSamples(batch.batch, compensated))
    readout(events.SensorStatus(10.5, health, dropped=0))
    (line,) = stream.getvalue().splitlines()
    assert re.fullmatch(r"\s*7000 Hz  \|F\|\s+5\.00 N  \|T\|\s+0\.050 N·m \(compensated\)  lost 3", line), line
    # a sensor with its own clock: how well the samples' times are known
    readout(events.WrenchSamples(batch.batch, compensated))
    readout(events.SensorStatus(11.0, health, clock_uncertainty_s=4e-5))
    assert stream.getvalue().splitlines()[-1].endswith("lost 3  sample times ±0.04 ms")


def test_the_final_line_adds_up():
    summary = MonitorSummary(samples=35190, first_sample_s=100.0, last_sample_s=105.027, lost=0,
                             duration_s=3.0, driver_rate_hz=7652.0)
    line = format_summary(summary)
    match = re.search(r"(\d+) samples received over ([\d.]+) s \(first to last sample, host monotonic clock\) = "
                      r"(\d+) Hz", line)
    assert match, line
    count, seconds, rate = int(match[1]), float(match[2]), int(match[3])
    assert abs(count / seconds - rate) <= printing_tolerance_hz(count, seconds)


def printing_tolerance_hz(count: int, seconds: float) -> float:
    """How far samples / seconds may be from the printed rate through rounding alone (rate to 1 Hz, seconds to
    0.1 ms)."""
    return 0.5 + count / seconds**2 * 0.5e-4 + 1e-9


@pytest.mark.slow
def test_ftacq_monitor_prints_a_live_readout_and_a_consistent_last_line(tmp_path, capsys):
    from ftacq.app.cli import main

    assert main(["monitor", "--sim", "--sim-still", "--seconds", "2.5", "--save", str(tmp_path / "m.rrd")]) == 0
    captured = capsys.readouterr()
    readouts = [line for line in captured.err.splitlines() if "Hz  |F|" in line]
    assert len(readouts) >= 3  # about twice a second
    kinds = []
    for line in readouts:  # rates per half second vary with the machine's load: the format and the counts here
        match = re.fullmatch(r"\s*\d+ Hz  \|F\|\s+[\d.]+ N  \|T\|\s+[\d.]+ N·m \((compensated|raw)\)  lost 0.*", line)
        assert match, line
        kinds.append(match[1])
    assert "compensated" in kinds
    # a loaded machine may starve the robot-state reader: a read with no state near its samples is shown raw
    # (never compensated with a pose of another time), and the last line counts such reads
    uncompensated = re.search(r"(\d+) had no robot state near their samples", captured.out)
    if "raw" in kinds:
        assert uncompensated and int(uncompensated[1]) >= 1, captured.out
    match = re.search(r"(\d+) samples received over ([\d.]+) s .*= (\d+) Hz", captured.out)
    assert match, captured.out
    count, seconds, rate = int(match[1]), float(match[2]), int(match[3])
    assert abs(count / seconds - rate) <= printing_tolerance_hz(count, seconds)
    assert 0.5 * 7000 < rate < 1.5 * 7000  # the simulated sensor's 7 kHz (loosely: the machine may be loaded)


def test_fanout_hands_direct_listeners_each_event_in_the_publishers_thread():
    """A ``direct`` listener is called at once by the publisher (the monitor's acquisition thread), the others from
    the background thread; a direct listener that raises gets nothing more and the others go on."""
    from procedures.delivery import Fanout

    seen: dict[str, list] = {"direct": [], "background": []}

    def direct(event):
        seen["direct"].append((event, threading.current_thread().name))

    def broken(event):
        raise RuntimeError("a consumer failed")

    direct.direct = True  # type: ignore[attr-defined]
    broken.direct = True  # type: ignore[attr-defined]
    fanout = Fanout([direct, broken, lambda event: seen["background"].append(event)], period_s=0.0)
    notices = [events.Notice(f"n{k}") for k in range(3)]
    for notice in notices:
        fanout(notice)
        assert seen["direct"][-1] == (notice, threading.current_thread().name)  # delivered before the call returned
    fanout.background.close()
    assert seen["background"] == notices
    assert isinstance(fanout.first_error, RuntimeError) and len(fanout.errors) == 1  # called once, then dropped
