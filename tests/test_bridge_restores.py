"""What a bridge run (procedures/bridge.py) changes for its length and gives back on every path: the sensor driver's
hold (``prefer_low_latency``: a short hold costs CPU for as long as it stays) and the interpreter's thread switch
interval, and the cyclic garbage collector's reach (``gc.freeze`` while feeding). Stand-ins for the sensor and the controller's input: no network, no sleeps."""

from __future__ import annotations

import gc
import sys
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.sensor import SensorBase, SensorInfo, WrenchBatch
from ftacq.bridge_convention import plan_feed
from ftacq.errors import DeviceConnectionError, DeviceTimeoutError
from ftacq.kinematics import ur_model
import procedures.bridge as bridge_module
from procedures.bridge import SENSOR_HOLD_S, Bridge
from tests.fakes.world import CellTruth


class _Sensor(SensorBase):
    """A started sensor with nothing to read that records the holds it is asked for."""

    def __init__(self) -> None:
        super().__init__()
        self.info = SensorInfo(transport="stand-in", serial="", firmware="", force_unit="N", torque_unit="N-m",
                               counts_per_force=1.0, counts_per_torque=1.0, rate_hz=1000.0)
        self.applied: list[float | None] = []

    def _apply_hold(self) -> None:
        self.applied.append(self.max_hold_s)

    def read(self, timeout_s: float | None = 1.0) -> WrenchBatch:
        raise DeviceTimeoutError("no sample")


class _SilentController:
    """The controller's input, whose cycle stops at once: the run ends by a watchdog trip."""

    frequency_hz = 500.0

    def __init__(self) -> None:
        self.frozen_at_cycle: list[int] = []  # gc.get_freeze_count() when the feed thread asks for a cycle

    def next_cycle(self, timeout_s: float = 0.1):
        self.frozen_at_cycle.append(gc.get_freeze_count())
        raise DeviceConnectionError("robot controller: connection closed")

    def write(self, wrench) -> None:
        raise AssertionError("nothing is written without a cycle")


class _BrokenSwitch:
    def set_payload(self, mass_kg, cog_m):
        raise AssertionError("no payload is set before the first value is written")

    def enable_external_ft_input(self, enable, function="", sensor_mass_kg=0.0, sensor_measuring_offset_m=None,
                                 sensor_cog_m=None) -> None:
        raise AssertionError("the input is not enabled before the first value is written")


def _bridge(sensor: _Sensor, controller: _SilentController | None = None) -> Bridge:
    truth = CellTruth()
    plan = plan_feed(truth.calibration(), "compensated", np.array([0.0, 0.0, 0.035]), sensor_body_kg=0.3)
    return Bridge(sensor, controller or _SilentController(), _BrokenSwitch(), plan, truth.calibration(),
                  ur_model("UR5e"))


@pytest.mark.parametrize("before", [None, 0.002], ids=["driver-default", "another-reader"])
def test_a_run_gives_the_sensor_its_previous_hold_back(before):
    sensor = _Sensor()
    sensor.prefer_low_latency(before)
    switch_interval_s = sys.getswitchinterval()
    summary = _bridge(sensor).run(duration_s=5.0)
    assert summary.trip is not None and "cycle stopped" in summary.trip and summary.written == 0
    assert sensor.applied == [before, SENSOR_HOLD_S, before]  # shortened for the run, then given back
    assert sensor.max_hold_s == before
    assert sys.getswitchinterval() == switch_interval_s


def test_the_objects_alive_at_the_start_are_out_of_the_collectors_reach_while_feeding():
    controller = _SilentController()
    frozen_before = gc.get_freeze_count()
    _bridge(_Sensor(), controller).run(duration_s=5.0)
    assert controller.frozen_at_cycle and min(controller.frozen_at_cycle) > frozen_before + 1000  # the process's
    assert gc.get_freeze_count() == frozen_before  # given back


class _RefusedThread(threading.Thread):
    def start(self) -> None:
        raise RuntimeError("can't start new thread")


def test_the_hold_is_given_back_when_the_feed_thread_cannot_start(monkeypatch):
    sensor = _Sensor()
    bridge = _bridge(sensor)
    switch_interval_s, frozen_before = sys.getswitchinterval(), gc.get_freeze_count()
    # the bridge module's threads only (pytest's and xdist's own keep the real ones)
    monkeypatch.setattr(bridge_module, "threading", SimpleNamespace(Thread=_RefusedThread, Event=threading.Event,
                                                                    get_native_id=threading.get_native_id))
    with pytest.raises(RuntimeError, match="can't start new thread"):
        bridge.run(duration_s=1.0)
    assert sensor.applied == [SENSOR_HOLD_S, None] and sensor.max_hold_s is None
    assert sys.getswitchinterval() == switch_interval_s
    assert gc.get_freeze_count() == frozen_before
