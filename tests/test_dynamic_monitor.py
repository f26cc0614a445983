"""``ftacq monitor`` compensates dynamically when the calibration has inertia, statically (and says so) when not,
with the drift tracker in both cases; the live compensator's sensor clock."""

from __future__ import annotations

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
    """The contact wrench ``monitor`` computes while the simulated technician jogs (no contact then: the truth is
    zero) is checked against the truth over the reads the live compensator itself counted as dynamically
    compensated: its error must be a fraction of the static model's on the same samples (the tool's inertial
    wrench). A monitor that compensates statically while saying "dynamic" fails (ratio ≈ 1, or no dynamic reads);
    a loaded machine only moves reads into the static fallback, which are left out of the comparison."""
    from ftacq.app.commands import monitor as command

    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m), inertia=truth.inertia)
    path = tmp_path / "calibration.json"
    save_calibration(path, calibration)
    reads: list[tuple[np.ndarray, np.ndarray]] = []  # (contact, static model's contact) of each dynamic read
    choose = command._choose_compensator

    def observed(*args, **kwargs):
        live = choose(*args, **kwargs)
        compensate = live.compensate

        def compensate_and_keep(batch, robot=None):
            dynamic_before = getattr(live, "dynamic_batches", 0)
            contact = compensate(batch, robot)
            if contact is not None and getattr(live, "dynamic_batches", 0) > dynamic_before:
                # the static model on the same samples: the orientation at the times the compensator used
                flange_R_base = live.orientations.flange_R_base_at(live._times)
                if flange_R_base is not None:
                    reads.append((contact.copy(), calibration.compensate(batch.wrench, flange_R_base)))
            return contact

        live.compensate = compensate_and_keep
        return live

    monkeypatch.setattr(command, "_choose_compensator", observed)
    monkeypatch.setattr(command, "SIM_CONTACT_WRENCH", np.zeros(6))  # the technician never pushes: no contact
    assert ftacq_main(["monitor", "--sim", "--calibration", str(path), "--seconds", "5",
                       "--save", str(tmp_path / "monitor.rrd")]) == 0
    assert reads, "no read was compensated dynamically"
    contact = np.vstack([r[0] for r in reads])
    static = np.vstack([r[1] for r in reads])
    # the truth is no contact: the error is the contact wrench itself; forces (N) and torques (N·m) apart
    for part, noise in ((slice(0, 3), 1.0), (slice(3, 6), 0.05)):
        error_dynamic = np.linalg.norm(contact[:, part], axis=1)
        error_static = np.linalg.norm(static[:, part], axis=1)
        accelerating = error_static > noise  # the static model is off by more than the noise: the inertial wrench
        assert accelerating.sum() > 1000, accelerating.sum()
        ratio = np.median(error_dynamic[accelerating]) / np.median(error_static[accelerating])
        print(f"dynamic/static median error while accelerating: {ratio:.3f} over {accelerating.sum()} samples")
        assert ratio < 0.3, ratio
