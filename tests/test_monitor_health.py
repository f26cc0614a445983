"""Live calibration health in ``ftacq monitor`` on the simulated cell (real Net F/T and RTDE on loopback): a
calibration of another sensor is refused, a push on the still tool is not absorbed into the biases with
--auto-tare, and a swapped tool is flagged; the dashboard records the tracked drift."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest

from drivers.sensor import open_sensor
from drivers.ur import URStateReader
from ftacq.app.cli import main
from ftacq.calfile import save_calibration
from ftacq.drift_health import BiasHealth
from procedures import events
from procedures.bias_health import DriftCheck, DriftCompensator
from procedures.monitor import LiveMonitor
from tests.conftest import wait_until
from tests.fakes.cell import SimulatedCell
from tests.fakes.world import CellTruth

PUSH = np.array([2.0, -4.0, 6.0, 0.1, 0.05, -0.08])
"""A steady push on the tool while the arm is still (sensor frame, N and N·m)."""


@pytest.fixture()
def cell():
    with SimulatedCell(sensor="netft", time_scale=0.0, rate_hz=2000.0, seed=4) as simulated:
        yield simulated


def write_config(tmp_path, cell) -> str:
    path = tmp_path / "CELL.toml"
    path.write_text(f'[robot]\nhost = "{cell.robot_host}"\n[sensor]\nurl = "{cell.sensor_url}"\n')
    return str(path)


def test_monitor_refuses_a_calibration_of_another_sensor(cell, tmp_path, capsys) -> None:
    foreign = replace(CellTruth().calibration(), metadata={"sensor": {
        "serial": "FT99999", "model": "", "transport": "netft", "counts_per_force": 1e6, "counts_per_torque": 5e5,
        "force_unit": "N", "torque_unit": "N-m", "firmware": ""}})
    save_calibration(tmp_path / "cal.json", foreign)
    code = main(["monitor", "--config", write_config(tmp_path, cell), "--calibration", str(tmp_path / "cal.json"),
                 "--seconds", "0.5", "--save", str(tmp_path / "m.rrd")])
    err = capsys.readouterr().err
    assert code == 2 and "FT99999" in err and "FT12345" in err and "--force" in err and "Traceback" not in err


def run_monitor(cell, compensator, collected: list, stop: threading.Event) -> threading.Thread:
    sensor = open_sensor(cell.sensor_url)
    robot = URStateReader(cell.robot_host, model=cell.model_name)

    def body():
        try:
            robot.start()
            sensor.start()
            monitor = LiveMonitor(sensor, robot=robot, compensator=compensator, checks=[DriftCheck(compensator)],
                                  listeners=[collected.append], strict=True)
            monitor.run(duration_s=60.0, stop=stop)
        finally:
            sensor.close()
            robot.close()

    thread = threading.Thread(target=body, name="test-monitor")
    thread.start()
    return thread


@pytest.mark.slow(seconds=10)
def test_a_push_on_the_still_tool_is_not_absorbed_and_a_swapped_tool_is_flagged(cell) -> None:
    """The arm stands still; the tracker learns the biases; a steady push is held until the tracker has refused
    four of its windows: the estimate does not move (auto-tare on) and the compensated wrench shows the push
    whole. Then the tool is swapped: the at-rest warning follows."""
    compensator = DriftCompensator(BiasHealth(cell.truth.calibration(), age_s=0.0, auto_tare=True))
    tracker = compensator.health.tracker
    collected: list = []
    stop = threading.Event()
    thread = run_monitor(cell, compensator, collected, stop)
    try:
        wait_until(lambda: tracker.accepted >= 4, "the tracker to learn the biases at rest")
        before = tracker.offset()
        refused = tracker.rejected_contact + tracker.rejected_gate
        cell.set_contact(PUSH)
        wait_until(lambda: tracker.rejected_contact + tracker.rejected_gate >= refused + 4,
                   "the tracker to refuse the push's windows")
        during = tracker.offset()
        cell.set_contact(np.zeros(6))
        accepted = tracker.accepted
        wait_until(lambda: tracker.accepted >= accepted + 2, "the tracker to go on after the push")
        np.testing.assert_allclose(during, before, atol=1e-9)  # not one window of the push was used
        assert np.all(np.abs(tracker.offset() - before) < [0.01] * 3 + [5e-4] * 3)
        pushed = [e for e in collected if isinstance(e, events.WrenchSamples) and e.compensated is not None]
        fz = np.concatenate([e.compensated[:, 2] for e in pushed])
        plateau = fz[fz > PUSH[2] / 2]  # the samples while pushed (set at once: no ramp)
        assert len(plateau) > 100 and float(np.mean(plateau)) == pytest.approx(PUSH[2], abs=0.05)  # whole, not tared
        warnings = lambda: [e for e in collected if isinstance(e, events.Notice) and e.level == "WARN"]  # noqa: E731
        wait_until(lambda: not compensator.health.check.warning, "the at-rest check to clear after the push")
        warned_before = len(warnings())
        cell.swap_tool(0.9, (0.0, 0.01, 0.04))
        wait_until(lambda: len(warnings()) > warned_before, "the at-rest warning after the swap")
        assert "not the tracked drift" in warnings()[warned_before].text
        wait_until(lambda: any("a step, not drift" in w.text for w in warnings()[warned_before:]),
                   "the swap called a step")
    finally:
        stop.set()
        thread.join(30.0)
    assert any(isinstance(e, events.BiasDrift) and e.applied for e in collected)
