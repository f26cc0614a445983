"""``ftacq monitor`` compensates dynamically when the calibration has inertia, statically (and says so) when not,
with the drift tracker in both cases; the live compensator's sensor clock."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest

from ftacq.app.cli import main as ftacq_main
from ftacq.calfile import save_calibration
from ftacq.timebase import SampleClock
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


def test_monitor_removes_the_inertial_wrench_while_the_technician_jogs(tmp_path, monkeypatch):
    """The contact wrench ``monitor`` computes while the simulated technician jogs (no contact: the truth is zero) is
    checked against the truth over the reads the live compensator itself counted as dynamically compensated: its
    error must be a fraction of the static model's on the same samples (the tool's inertial wrench). A monitor that
    compensates statically while saying "dynamic" fails (ratio ≈ 1, or no dynamic reads). A loaded machine only
    moves reads into the static fallback, left out of the comparison, and makes the run longer: it stops once
    ENOUGH samples of the inertial wrench were compared (at most 60 s)."""
    from ftacq.app import session, sim_technician
    from procedures.monitor import LiveMonitor

    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m), inertia=truth.inertia)
    path = tmp_path / "calibration.json"
    save_calibration(path, calibration)
    # each part (N; N·m) and the static model's error above which a sample shows the inertial wrench (the filtered
    # noise is about a tenth of it)
    parts = {"force": (slice(0, 3), 1.0), "torque": (slice(3, 6), 0.05)}
    enough = 2000
    errors: dict[str, list[np.ndarray]] = {name: [] for name in parts}  # (dynamic, static) error rows per part
    counted = dict.fromkeys(parts, 0)
    done = threading.Event()
    choose = session._live_compensator

    def observed(*args, **kwargs):
        live = choose(*args, **kwargs)
        compensate = live.compensate

        def compensate_and_keep(batch, robot=None):
            dynamic_before = getattr(live, "dynamic_batches", 0)
            contact = compensate(batch, robot)
            if contact is None or getattr(live, "dynamic_batches", 0) == dynamic_before:
                return contact
            # the static model on the same samples: the orientation at the times the compensator used (the shared
            # sample clock gives a batch it has seen the same times again)
            times = live.clock.host_times(batch.time_s, batch.device_time_s) - live.lag_s
            flange_R_base = live.orientations.flange_R_base_at(times)
            if flange_R_base is None:
                return contact
            static = calibration.compensate(batch.wrench, flange_R_base)
            for name, (part, noise) in parts.items():
                rows = np.column_stack([np.linalg.norm(contact[:, part], axis=1),
                                        np.linalg.norm(static[:, part], axis=1)])
                rows = rows[rows[:, 1] > noise]
                errors[name].append(rows)
                counted[name] += len(rows)
            if min(counted.values()) >= enough:
                done.set()
            return contact

        live.compensate = compensate_and_keep
        return live

    stream = LiveMonitor.stream
    monkeypatch.setattr(session, "_live_compensator", observed)
    monkeypatch.setattr(LiveMonitor, "stream", lambda self, duration_s=None, stop=None: stream(self, duration_s, done))
    monkeypatch.setattr(sim_technician, "SIM_CONTACT_WRENCH", np.zeros(6))  # the technician never pushes: no contact
    monkeypatch.setattr(sim_technician, "SIM_PHASE_S", 3600.0)  # and jogs all along, however long the start-up takes
    assert ftacq_main(["monitor", "--sim", "--calibration", str(path), "--seconds", "60",
                       "--save", str(tmp_path / "monitor.rrd")]) == 0
    for name in parts:
        assert counted[name] >= enough, (name, counted, "samples of the inertial wrench dynamically compensated")
        dynamic, static = np.vstack(errors[name]).T
        ratio = np.median(dynamic) / np.median(static)
        print(f"{name}: dynamic/static median error while accelerating {ratio:.3f} over {len(static)} samples")
        assert ratio < 0.3, (name, ratio)
