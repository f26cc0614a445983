"""The controller's external F/T input driven by the real ur-rtde client and drivers/ur_ft_input.py, checked on
what the simulated controller received (tests/fakes/ur_external_ft.py), not on what the client meant to send."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from drivers.ur_ft_input import ExternalInputInUseError, URForceTorqueInput
from ftacq.bridge_convention import FT_RTDE_INPUT_ENABLE, FeedPlan, controller_tcp_force
from ftacq.kinematics import flange_pose, ur_model
from ftacq.so3 import rotation_from_rotvec
from tests.conftest import wait_until
from tests.fakes.ur_external_ft import ExternalFTInput
from tests.fakes.ur_process import URControllerProcess

rtde_control = pytest.importorskip("rtde_control")
Control = rtde_control.RTDEControlInterface
HOME_Q = [0.3, -1.2, 1.4, -1.7, -1.5708, 0.4]


@pytest.fixture(scope="module")
def fake():
    with URControllerProcess(time_scale=0.0, initial_q=HOME_Q) as process:
        yield process


def feed(client: URForceTorqueInput, wrenches) -> list:
    """Write one wrench per controller cycle; return the cycles."""
    cycles = []
    for wrench in wrenches:
        cycles.append(client.next_cycle())
        client.write(wrench)
    return cycles


class Feeder:
    """Feeds every controller cycle on a thread (as the bridge does; the controller pauses the program after 0.1 s
    without input): the queued wrenches one per cycle, then the last one again. ``last_cycle`` is the newest."""

    def __init__(self, client: URForceTorqueInput) -> None:
        self.client, self.queue, self.current = client, [], np.zeros(6)
        self.lock, self.stop = threading.Lock(), threading.Event()
        self.last_cycle = None
        self.error: Exception | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> "Feeder":
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.thread.join(2.0)

    def put(self, wrenches) -> None:
        with self.lock:
            self.queue.extend(np.asarray(wrenches, dtype=float))

    def drained(self) -> bool:
        with self.lock:
            return not self.queue

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                cycle = self.client.next_cycle(timeout_s=2.0)
            except Exception as error:  # noqa: BLE001 - reported by the test
                self.error = error
                return
            with self.lock:
                if self.queue:
                    self.current = self.queue.pop(0)
                self.client.write(self.current)
                self.last_cycle = cycle


def test_ur_rtde_set_external_force_torque_never_reaches_the_input(fake):
    """ur-rtde 1.6.5: command 55 on recipe 21 is 4 bytes short, the script has no branch for it; True anyway."""
    control = Control(fake.host)
    try:
        before = fake.external_ft()["received"]
        assert control.setExternalForceTorque([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]) is True
        # the client does not wait for 'done' on this command: wait until the script has taken it
        wait_until(lambda: any(e["event"] == "unhandled_command" and e["cmd"] == 55 for e in fake.events()),
                   what="command 55 to reach the control script")
        events = fake.events()
    finally:
        control.disconnect()
    assert fake.external_ft()["received"] == before  # nothing arrived on external_force_torque
    assert {"recipe": 21, "bytes": 52, "expected": 56} in [
        {k: e[k] for k in ("recipe", "bytes", "expected")} for e in events if e["event"] == "short_package"]


def test_second_owner_of_the_input_gets_in_use(fake):
    control = Control(fake.host)  # default flags: its recipe 23 holds external_force_torque
    try:
        with pytest.raises(ExternalInputInUseError, match="FLAG_NO_EXT_FT"):
            URForceTorqueInput(fake.host).start()
    finally:
        control.disconnect()
    with URForceTorqueInput(fake.host):
        with pytest.raises(RuntimeError, match="already in use"):  # ur-rtde's own IN_USE check
            Control(fake.host, -1.0, Control.FLAG_UPLOAD_SCRIPT)
        control = Control(fake.host, -1.0, Control.FLAG_UPLOAD_SCRIPT | Control.FLAG_NO_EXT_FT)
        control.disconnect()
    # closing the owner frees the input
    with URForceTorqueInput(fake.host) as client:
        assert client.frequency_hz == 500.0


def test_enable_feed_and_disable_as_the_controller_records_them(fake):
    control = Control(fake.host, -1.0, Control.FLAG_UPLOAD_SCRIPT | Control.FLAG_NO_EXT_FT)
    try:
        with URForceTorqueInput(fake.host) as client, Feeder(client) as feeder:
            assert control.setPayload(1.2, [0.01, -0.02, 0.06])
            assert control.ftRtdeInputEnable(True, 0.25, [0.0, 0.0, 0.035], [0.0, 0.0, 0.015])
            state = fake.external_ft()
            assert state["enabled"] and state["function"] == FT_RTDE_INPUT_ENABLE
            assert state["sensor_mass"] == 0.25
            assert state["sensor_measuring_offset"] == [0.0, 0.0, 0.035]
            assert state["sensor_cog"] == [0.0, 0.0, 0.015]
            sent = np.random.default_rng(0).normal(0, [10, 10, 10, 1, 1, 1], size=(100, 6))
            feeder.put(sent)
            wait_until(feeder.drained, what="100 cycles fed")

            def all_recorded():  # the controller records what arrives; the last packages may still be in flight
                rows = fake.external_ft_records()["received"]
                start = np.flatnonzero(np.all(rows[:, 2:] == sent[0], axis=1))
                return (rows, int(start[0])) if start.size and rows.shape[0] >= start[0] + 100 else None

            records, first = wait_until(all_recorded, what="the controller recorded the 100 inputs")
            np.testing.assert_array_equal(records[first:first + 100, 2:], sent)  # bit for bit, one per cycle
            assert np.all(np.diff(records[:, 0]) >= 0)  # arrival times (monotonic clock)
            # the controller's own report of the held value follows the documented model (ftacq.bridge_convention)
            plan = FeedPlan(feed="raw", function=FT_RTDE_INPUT_ENABLE, sensor_to_fed=np.eye(6), sensor_mass_kg=0.25,
                            sensor_measuring_offset_m=np.array([0.0, 0.0, 0.035]),
                            sensor_cog_m=np.array([0.0, 0.0, 0.015]), payload_kg=1.2,
                            payload_cog_m=np.array([0.01, -0.02, 0.06]), tool_kg=0.95,
                            flange_p_tool_com_m=np.zeros(3))
            base_R_flange = rotation_from_rotvec(flange_pose(ur_model("UR5e"), np.array(HOME_Q))[3:6])
            expected = controller_tcp_force(sent[-1], plan, base_R_flange, np.zeros(3), (0.0, 0.0, -9.81))
            wait_until(lambda: feeder.last_cycle is not None
                       and np.allclose(feeder.last_cycle.tcp_force, expected, atol=1e-9, rtol=0),
                       what=f"actual_TCP_force {expected} of the last fed wrench (last cycle {feeder.last_cycle})")
            assert control.ftRtdeInputEnable(False)
            assert not fake.external_ft()["enabled"]
            assert fake.external_ft()["watchdog_trips"] == []
            assert feeder.error is None
    finally:
        control.disconnect()


def test_old_controller_has_only_the_deprecated_enable():
    """CB3 3.15: 125 Hz; ur-rtde's script drops the ft_rtde_input_enable line below 5.9, so only
    enableExternalFtSensor reaches the controller."""
    with URControllerProcess(time_scale=0.0, version="3.15.7.0") as fake:
        control = Control(fake.host, -1.0, Control.FLAG_UPLOAD_SCRIPT | Control.FLAG_NO_EXT_FT)
        try:
            with URForceTorqueInput(fake.host) as client, Feeder(client):
                assert client.frequency_hz == 125.0
                assert control.ftRtdeInputEnable(True, 0.2) is True  # "done", yet nothing was enabled
                assert not fake.external_ft()["enabled"]
                assert any(e["event"] == "external_ft_not_called" for e in fake.events())
                assert control.enableExternalFtSensor(True, 0.2)
                state = fake.external_ft()
                assert state["enabled"] and state["function"] == "enable_external_ft_sensor"
                assert control.enableExternalFtSensor(False)
        finally:
            control.disconnect()


def test_controller_pauses_the_program_when_the_input_stops():
    """UR's default watchdog while enabled: no input for 0.1 s pauses the program."""
    with URControllerProcess(time_scale=0.0) as fake:
        control = Control(fake.host, -1.0, Control.FLAG_UPLOAD_SCRIPT | Control.FLAG_NO_EXT_FT)
        try:
            with URForceTorqueInput(fake.host) as client:
                assert control.ftRtdeInputEnable(True)
                feed(client, np.zeros((10, 6)))
                trips = wait_until(lambda: fake.external_ft()["watchdog_trips"], what="the controller's watchdog")
                assert len(trips) == 1
                assert fake.state()["runtime_state"] == 4  # PAUSED
        finally:
            control.disconnect()


def test_first_cycle_after_the_enable_reads_the_value_that_arrived_before_it():
    """The feeder answers every package, the enable call lands between a value and the next cycle: that cycle is
    fed (the value is new since the previous cycle), the one after it without a new value is missed."""
    period_s = 0.002
    ft = ExternalFTInput()
    assert not ft.count_cycle(0.0, 0.0, period_s)  # disabled: not counted
    ft.receive(np.ones(6), arrival_s=0.001, controller_time_s=0.001)
    ft.enable(FT_RTDE_INPUT_ENABLE, True, 0.2, np.zeros(3), np.zeros(3), controller_time_s=0.0015, now_s=0.0015)
    ft.count_cycle(0.002, 0.002, period_s)
    assert (ft.summary()["cycles_fed"], ft.summary()["cycles_missed"]) == (1, 0)
    ft.count_cycle(0.004, 0.004, period_s)
    assert (ft.summary()["cycles_fed"], ft.summary()["cycles_missed"]) == (1, 1)


def test_queued_tells_a_package_that_is_not_the_newest(fake):
    with URForceTorqueInput(fake.host) as client:
        first = client.next_cycle()
        # packages keep coming at 500 Hz while nobody reads: a newer one is waiting
        wait_until(lambda: client.queued(), what="a second package to queue")
        read = [first]
        while client.queued():  # the backlog, as the bridge skips it at start
            read.append(client.next_cycle())
        assert len(read) >= 2 and not client.queued()
        timestamps = [cycle.timestamp_s for cycle in read]
        assert timestamps == sorted(timestamps) and len(set(timestamps)) == len(timestamps)
