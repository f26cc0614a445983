"""``ftacq monitor`` compensates dynamically when the calibration has inertia, statically (and says so) when not,
with the drift tracker in both cases; the live compensator's sensor clock."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ftacq.app.cli import main as ftacq_main
from ftacq.calfile import save_calibration
from ftacq.dynamics.clock import SampleClock
from tests.fakes.world import CellTruth

pytest.importorskip("rtde_control")


@pytest.mark.parametrize("with_inertia", [True, False])
def test_monitor_chooses_the_model_by_the_calibration(tmp_path, capsys, with_inertia):
    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m))
    if with_inertia:
        calibration = replace(calibration, inertia=truth.inertia)
    path = tmp_path / "calibration.json"
    save_calibration(path, calibration)
    assert ftacq_main(["monitor", "--sim", "--sim-still", "--calibration", str(path), "--seconds", "1.5",
                       "--save", str(tmp_path / "monitor.rrd")]) == 0
    captured = capsys.readouterr()
    err = captured.err
    assert "drift tracker" in captured.out  # the tracker runs with either model
    if with_inertia:
        assert "dynamic compensation (tool inertia from the calibration" in err
    else:
        assert "static compensation (the pose at each sample's time): this calibration has no inertia" in err


def test_sensor_clock_removes_arrival_jitter_and_restarts_after_a_power_cycle():
    rng = np.random.default_rng(1)
    clock = SampleClock()
    counter = np.arange(20000)
    true = 50.0 + counter / 7000.0
    arrival = true + 0.0003 + rng.exponential(0.001, counter.size)
    arrival[12000:] += 0.2  # a stall: the rest arrives 0.2 s later, and the box power-cycled (its counter restarts)
    device = np.where(counter < 12000, 1000.0 + counter / 7000.0, (counter - 12000) / 7000.0)
    out = np.concatenate([clock.host_times(arrival[i:i + 70], device[i:i + 70]) for i in range(0, 20000, 70)])
    settled = slice(2000, 12000)
    assert np.abs(out[settled] - (true[settled] + 0.0003)).max() < 2e-4
    assert np.abs(out[14100:] - (true[14100:] + 0.2003)).max() < 2e-4
    assert clock.clock.restarts == 1
    # no device clock (a polled CAN sensor): the receive stamps
    np.testing.assert_array_equal(SampleClock().host_times(arrival[:70], np.full(70, np.nan)), arrival[:70])
