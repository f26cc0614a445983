"""``ftacq bridge`` on the simulated cell: the procedure (procedures/bridge.py) with the real Net F/T driver, the
real ur-rtde control interface and the external-input client, checked on what the simulated controller received;
the watchdog (silent sensor, saturation, Ctrl-C) and ``--check`` (procedures/bridge_check.py)."""

from __future__ import annotations

import _thread
import sys
import threading
import time

import numpy as np
import pytest

from drivers.netft.receiver import COALESCE_S
from drivers.robot import MotionLimits
from drivers.sensor import open_sensor
from drivers.ur import URRobot
from drivers.ur_ft_input import URForceTorqueInput
from ftacq import STANDARD_GRAVITY_M_S2
from ftacq.bridge_convention import plan_feed
from ftacq.kinematics import ur_model
from procedures.bridge import Bridge, BridgeSettings
from procedures.events import FedWrenches, Notice
from procedures.bridge_check import judge, run_check
from tests.conftest import wait_until
from tests.fakes.cell import SimulatedCell

pytest.importorskip("rtde_control")
SENSOR_RATE_HZ = 1000.0
LOADED = BridgeSettings(max_staleness_s=0.5, cycle_timeout_s=1.0)
"""Sensor, driver and bridge share this test process on a shared machine: where the watchdog is not what is tested,
the bridge allows 0.5 s and the controller's input watchdog is set to 1 s (as ``rtde_set_watchdog`` would)."""
SENSOR_OFFSET_M = np.array([0.0, 0.0, 0.035])
CONTACT = np.array([3.0, -4.0, 12.0, 0.2, -0.1, 0.05])
"""A push on the tool, sensor frame (N, N·m)."""
UR5E = ur_model("UR5e")


@pytest.fixture(scope="module")
def cell():
    with SimulatedCell(sensor="netft", time_scale=0.0, rate_hz=SENSOR_RATE_HZ) as simulated:
        simulated.controller.control("set external_ft_watchdog 1.0")
        yield simulated


@pytest.fixture(scope="module")
def robot(cell):
    with URRobot(cell.robot_host, MotionLimits(), model="UR5e", leave_external_ft_input=True) as ur:
        yield ur


@pytest.fixture
def parts(cell, robot):
    """A started sensor and input client, and the convention for the cell's true tool (compensated feed)."""
    sensor = open_sensor(cell.sensor_url)
    sensor.start()
    client = URForceTorqueInput(cell.robot_host).start()
    plan = plan_feed(cell.truth.calibration(), "compensated", SENSOR_OFFSET_M, sensor_body_kg=0.3)
    robot.restart_control_script()  # a previous test's trip may have let the controller pause the program
    try:
        yield sensor, client, plan
    finally:
        client.close()
        sensor.close()
        cell.set_contact(np.zeros(6))
        cell.netft.resume()
        cell.netft.clear_status()
        cell.controller.control("set external_ft_axes 1 1 1 1 1 1")


def later(delay_s: float, action) -> threading.Timer:
    timer = threading.Timer(delay_s, action)
    timer.start()
    return timer


def test_bridge_feeds_the_contact_wrench_every_cycle_and_disables_at_the_end(cell, robot, parts):
    sensor, client, plan = parts
    cell.set_contact(CONTACT)
    events = []
    bridge = Bridge(sensor, client, robot, plan, cell.truth.calibration(), UR5E, LOADED, listeners=(events.append,))
    assert sensor.max_hold_s is None
    summary = bridge.run(duration_s=1.5)
    assert summary.trip is None and summary.disabled and not summary.interrupted, summary.trip
    # the driver's own receive hold is back (the bridge shortened it to SENSOR_HOLD_S while feeding)
    assert sensor.max_hold_s is None and sensor._receiver.coalesce_s == COALESCE_S
    state = cell.controller.external_ft()
    calls = state["enable_calls"]
    assert [c["enable"] for c in calls[-2:]] == [True, False]
    assert calls[-2]["sensor_mass"] == pytest.approx(plan.sensor_mass_kg)
    np.testing.assert_allclose(calls[-2]["sensor_measuring_offset"], SENSOR_OFFSET_M)
    assert state["payload"] == pytest.approx(plan.payload_kg)
    np.testing.assert_allclose(state["payload_cog"], plan.payload_cog_m)
    # what the controller received: the contact in the convention's frame (noise filtered), one value per cycle
    wait_until(lambda: cell.controller.external_ft()["received"] >= summary.written, what="the last value to arrive")
    received = cell.controller.external_ft_records()["received"][:, 2:]
    assert len(received) >= summary.written > 100  # the rate is a benchmark figure (benchmarks/bridge.py)
    expected = plan.fed_wrench(CONTACT)
    np.testing.assert_allclose(received[-100:].mean(axis=0), expected, atol=0.05)
    np.testing.assert_array_equal(received[-summary.written:], summary.log[np.isfinite(summary.log[:, 2])][:, 5:11])
    assert summary.staleness_s().max() <= LOADED.max_staleness_s
    fed = [e for e in events if isinstance(e, FedWrenches)]
    assert sum(e.written for e in fed) == summary.written
    np.testing.assert_array_equal(np.concatenate([e.fed for e in fed]), received[-summary.written:])
    assert isinstance(events[-1], Notice) and events[-1].source == "bridge" and events[-1].level == "INFO"


def test_silent_sensor_stops_the_feed_and_disables_the_input(cell, robot, parts):
    sensor, client, plan = parts
    settings = BridgeSettings(max_staleness_s=0.3, cycle_timeout_s=1.0)  # no trip from a busy machine first
    bridge = Bridge(sensor, client, robot, plan, cell.truth.calibration(), UR5E, settings)
    silenced = []
    timer = later(0.6, lambda: (cell.netft.go_silent(), silenced.append(time.monotonic())))
    summary = bridge.run(duration_s=10.0)
    ended = time.monotonic()
    timer.join()
    assert summary.trip is not None and "silent" in summary.trip
    assert silenced and silenced[0] < ended < silenced[0] + 2.0, "tripped for the silence, soon after it"
    assert summary.disabled
    assert not cell.controller.external_ft()["enabled"]
    # nothing stale was written: every written value's newest sample was within the limit when it was written
    assert summary.staleness_s().max() <= settings.max_staleness_s


def test_saturation_stops_the_feed(cell, robot, parts):
    sensor, client, plan = parts
    bridge = Bridge(sensor, client, robot, plan, cell.truth.calibration(), UR5E, LOADED)
    timer = later(0.6, cell.netft.saturate)
    summary = bridge.run(duration_s=10.0)
    timer.join()
    assert summary.trip is not None and "saturation" in summary.trip
    assert summary.disabled and not cell.controller.external_ft()["enabled"]


def test_a_jump_of_the_fed_wrench_stops_the_feed(cell, robot, parts):
    sensor, client, plan = parts
    settings = BridgeSettings(max_staleness_s=0.5, cycle_timeout_s=1.0, jump_force_n=1.0)
    bridge = Bridge(sensor, client, robot, plan, cell.truth.calibration(), UR5E, settings)
    timer = later(0.6, lambda: cell.set_contact(np.array([0.0, 0.0, 40.0, 0.0, 0.0, 0.0])))
    summary = bridge.run(duration_s=10.0)
    timer.join()
    assert summary.trip is not None and "jumped" in summary.trip, summary.trip
    assert summary.disabled and not cell.controller.external_ft()["enabled"]
    written = summary.log[np.isfinite(summary.log[:, 2])][:, 5:8]
    assert np.all(np.linalg.norm(np.diff(written, axis=0), axis=1) <= 1.0)  # the jump itself was never written


def test_ctrl_c_disables_the_input_while_still_feeding(cell, robot, parts):
    sensor, client, plan = parts
    before = cell.controller.external_ft()
    bridge = Bridge(sensor, client, robot, plan, cell.truth.calibration(), UR5E, LOADED)
    timer = later(0.8, _thread.interrupt_main)  # what Ctrl-C does: KeyboardInterrupt in the main thread
    summary = bridge.run(duration_s=10.0)
    timer.join()
    assert summary.interrupted and summary.trip is None and summary.disabled, summary.trip
    state = cell.controller.external_ft()
    assert not state["enabled"]
    assert state["watchdog_trips"] == before["watchdog_trips"]  # disabled before the feed stopped


def test_feed_runs_at_normal_priority_where_real_time_is_refused(cell, robot, parts, monkeypatch):
    """Without CAP_SYS_NICE or an rtprio limit SCHED_FIFO is refused: the bridge feeds anyway and says so; the
    interpreter's switch interval is restored afterwards."""
    sensor, client, plan = parts

    def refuse(*_args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr("os.sched_setscheduler", refuse)
    switch_interval_s = sys.getswitchinterval()
    summary = Bridge(sensor, client, robot, plan, cell.truth.calibration(), UR5E, LOADED).run(duration_s=0.5)
    assert summary.trip is None and summary.written > 0
    assert summary.feed_priority == "normal (SCHED_FIFO 80 refused: Operation not permitted)"
    assert summary.compensation == "static"
    assert sys.getswitchinterval() == switch_interval_s
    assert len(summary.answer_time_s()) == summary.written


def test_program_mode_only_feeds(cell, robot, parts):
    """--enable program: the PolyScope program enables the input; the bridge makes no enable call of its own."""
    sensor, client, plan = parts
    calls = len(cell.controller.external_ft()["enable_calls"])
    summary = Bridge(sensor, client, None, plan, cell.truth.calibration(), UR5E, LOADED).run(duration_s=0.5)
    assert summary.trip is None and summary.written > 0 and not summary.disabled
    assert len(cell.controller.external_ft()["enable_calls"]) == calls


def test_check_passes_on_a_matching_controller_and_catches_a_flipped_sign(cell, robot, parts):
    _sensor, client, plan = parts
    gravity = np.array([0.0, 0.0, -STANDARD_GRAVITY_M_S2])
    report = run_check(client, robot, plan, UR5E, gravity, hold_s=0.2)
    assert report.ok, report.lines()
    raw = plan_feed(cell.truth.calibration(), "raw", SENSOR_OFFSET_M, sensor_body_kg=0.3)
    assert run_check(client, robot, raw, UR5E, gravity, hold_s=0.2).ok  # the controller removes the tool weight
    cell.controller.control("set external_ft_axes 1 1 1 1 -1 1")  # a controller reading Ty the other way
    report = run_check(client, robot, plan, UR5E, gravity, hold_s=0.2)
    assert not report.ok
    verdicts = {step.name: step.verdict for step in report.steps}
    assert verdicts["+Ty"] == "sign flipped"
    assert all(verdicts[name] == "ok" for name in ("zero", "+Fx", "+Fy", "+Fz", "+Tx", "+Tz"))
    assert report.lines()[-1].startswith("FAIL: +Ty: sign flipped")


def test_judge_names_sign_and_frame_errors():
    expected = np.array([0.0, 0.0, 10.0])
    assert judge(expected, expected + 0.1, 0.5) == "ok"
    assert judge(expected, -expected, 0.5) == "sign flipped"
    assert judge(expected, np.array([10.0, 0.0, 0.0]), 0.5) == "frame rotated by 90°"
    assert judge(expected, np.zeros(3), 0.5).startswith("mismatch")


def test_cli_check_on_the_simulated_cell_passes(capsys):
    from ftacq.app.cli import main

    assert main(["bridge", "--sim", "--check"]) == 0
    out = capsys.readouterr().out
    assert "PASS: frame, signs and payload handling match the convention" in out
    assert "+Tz:" in out


def test_cli_config_without_calibration_is_a_one_line_error(tmp_path, capsys):
    from ftacq.app.cli import main

    config = tmp_path / "cell.toml"
    config.write_text('[robot]\nhost = "127.0.0.1"\n')
    assert main(["bridge", "--config", str(config)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["ftacq: error: ftacq bridge --config needs --calibration CAL.json (the tool the sensor carries)"]


@pytest.mark.parametrize("value, why", [("120", "120 is outside 0-99 (0 = normal scheduling)"),
                                        ("high", "'high' is not a whole number")])
def test_cli_realtime_priority_out_of_range_is_a_one_line_error(capsys, value, why):
    from ftacq.app.cli import main

    with pytest.raises(SystemExit) as stop:
        main(["bridge", "--sim", "--realtime-priority", value])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"ftacq bridge: error: argument --realtime-priority: {why}"


@pytest.mark.parametrize("order", [2, 4])
def test_wrench_filter_in_batches_equals_one_sosfilt_pass_from_steady_state(order):
    from scipy import signal

    from procedures.bridge import WrenchFilter

    wrench = np.random.default_rng(order).standard_normal((2000, 6)) + np.array([5.0, -3.0, 20.0, 0.1, 0.2, -0.3])
    batched = WrenchFilter(100.0, 7000.0, order)
    edges = np.cumsum([14, 1, 30, 14] * 34)  # batches of 14, 1, 30, 14 samples: 2006 in all
    out = np.vstack([batched(part) for part in np.split(wrench, edges[edges < len(wrench)])])
    zi = signal.sosfilt_zi(batched.sos)[:, :, None] * wrench[0][None, None, :]
    expected, _ = signal.sosfilt(batched.sos, wrench, axis=0, zi=zi)
    np.testing.assert_allclose(out, expected, atol=1e-10)
    constant = WrenchFilter(100.0, 7000.0, order)
    np.testing.assert_allclose(constant(np.tile(wrench[:1], (50, 1))), np.tile(wrench[:1], (50, 1)), atol=1e-10)
