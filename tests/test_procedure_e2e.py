"""End to end: the procedure against the simulated cell (UR controller subprocess over RTDE + Net F/T on loopback
or NETCANOEM on a virtual CAN bus) recovers the cell's true parameters within the noise."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from drivers.robot import MotionLimits
from ftacq.calfile import load_calibration
from ftacq.app.cli import main
from procedures import events
from procedures.measured import drift_label
from procedures.run_folder import RunFolder, RunFolderWriter
from tests.fakes.cell import SimulatedCell, fast_config, motion_problems, plan_for, run_calibration
from tests.fakes.world import CellTruth

SIGMAS = 6.0
"""Identified parameters must lie within this many reported 1σ of the truth (plus a small absolute floor)."""

def assert_recovers_truth(calibration, truth: CellTruth) -> None:
    unc = calibration.uncertainty
    true = truth.calibration()
    for key, got, want, floor in (
        ("force_bias", calibration.force_bias, true.force_bias, 1e-3),
        ("torque_bias", calibration.torque_bias, true.torque_bias, 5e-5),
        ("gravity_base", calibration.gravity_base, true.gravity_base, 1e-3),
        ("center_of_mass_m", calibration.center_of_mass, true.center_of_mass, 5e-5),
    ):
        sigma = np.asarray(unc[key])
        assert np.all(sigma > 0), key
        assert np.all(np.abs(got - want) <= SIGMAS * sigma + floor), (key, got, want, sigma)
    assert abs(calibration.mass_kg - truth.mass_kg) <= SIGMAS * unc["mass_kg"] + 1e-4
    # rotation error as a small rotation about the sensor axes, against its 1σ (rad)
    delta = calibration.sensor_rotation @ true.sensor_rotation.T
    angle = np.arccos(np.clip((np.trace(delta) - 1) / 2, -1, 1))
    assert angle <= SIGMAS * np.linalg.norm(unc["sensor_rotation_rad"]) + 1e-4


def run_and_check(tmp_path, sensor: str) -> None:
    seen: list = []
    with SimulatedCell(sensor=sensor, time_scale=0.0, seed=3) as cell:
        config = fast_config(cell)
        plan = plan_for(cell, config)
        folder = RunFolder.create(tmp_path, config.to_dict(), plan.to_json())
        plan, result = run_calibration(cell, config, listeners=[RunFolderWriter(folder), seen.append], plan=plan)
        commands = cell.controller.commands()
    assert result.status == "done", result.message
    assert_recovers_truth(result.identification.calibration, cell.truth)
    # validation: the held-out poses are compensated to the noise level (no contact in the simulation)
    v = result.validation
    assert set(v.labels) == {label for label, s in zip(plan.labels, plan.set_names) if s == "V"}
    assert np.all(v.max_abs[:3] < 0.1) and np.all(v.max_abs[3:] < 0.004), v.max_abs
    assert np.all(v.rms <= v.max_abs)
    # identification used A and E only, never V
    assert set(result.identification.sets) <= {"A", "E"}
    assert len(result.identification.labels) == sum(1 for s in plan.set_names if s in "AE")
    # drift check: no drift in this truth, so the revisit agrees within the noise
    assert result.drift is not None and result.drift.warning == ""
    assert np.linalg.norm(result.drift.drift[:3]) < 0.1
    # every pose measured once, in plan order, then the revisit; all of it on disk
    measured_labels = [e.label for e in seen if isinstance(e, events.PoseMeasured)]
    assert measured_labels == [*plan.labels, drift_label(plan.labels[0])]
    record = folder.read_record()
    assert record.labels == tuple(measured_labels)
    assert json.loads((folder.path / "run.json").read_text())["status"] == "done"
    # the controller executed exactly the plan's moves (plus the revisit) at the configured limits
    limits = MotionLimits(joint_speed_rad_s=config.robot.joint_speed_rad_s,
                          joint_acceleration_rad_s2=config.robot.joint_acceleration_rad_s2)
    assert motion_problems(commands, plan, limits) == []
    moves = [c for c in commands if c["kind"] == "movej"]
    assert len(moves) == len(plan) + 1
    states = [e.state for e in seen if isinstance(e, events.StateChanged)]
    assert states[0] == "planning" and states[-1] == "done"
    assert states.index("identifying") > max(i for i, s in enumerate(states) if s == "averaging")


@pytest.mark.slow(seconds=9)
def test_procedure_with_can_sensor_recovers_the_truth(tmp_path):
    run_and_check(tmp_path, "can")


@pytest.mark.slow(seconds=9)
def test_procedure_with_netft_sensor_recovers_the_truth(tmp_path):
    run_and_check(tmp_path, "netft")


def test_dry_run_prints_the_plan_and_moves_nothing(tmp_path, capsys):
    with SimulatedCell(sensor="can", time_scale=0.0) as cell:
        config_path = tmp_path / "CELL.toml"
        config_path.write_text(
            f'[robot]\nhost = "{cell.robot_host}"\nmodel = "UR5e"\n'
            f'[sensor]\nurl = "{cell.sensor_url}"\n'
            '[poses]\nrandom_count = 6\nvalidation_count = 4\n', encoding="utf-8")
        before = cell.controller.state()["q"]
        status = main(["calibrate", "--config", str(config_path), "--dry-run", "--out", str(tmp_path / "runs")])
        commands = cell.controller.commands()
        after = cell.controller.state()["q"]
    out = capsys.readouterr().out
    assert status == 0
    assert "Pose plan for UR5e" in out and "A 24/24, E 6/6, V 4/4" in out
    assert "estimated duration" in out and "dry run: the robot did not move" in out
    total = int(re.search(r"\(total (\d+)\)", out)[1])
    assert f"path check: {total + 1} moves checked" in out  # every pose and the drift revisit
    assert [c for c in commands if c["kind"] not in ()] == []  # the controller recorded no motion command
    np.testing.assert_array_equal(before, after)
    assert not (tmp_path / "runs").exists()  # nothing measured, no run folder


def test_without_yes_and_without_a_terminal_the_robot_does_not_move(tmp_path, capsys, monkeypatch):
    import io

    monkeypatch.setattr("sys.stdin", io.StringIO(""))
    with SimulatedCell(sensor="can", time_scale=0.0) as cell:
        config_path = tmp_path / "CELL.toml"
        config_path.write_text(
            f'[robot]\nhost = "{cell.robot_host}"\n[sensor]\nurl = "{cell.sensor_url}"\n'
            '[poses]\nrandom_count = 6\nvalidation_count = 4\n', encoding="utf-8")
        status = main(["calibrate", "--config", str(config_path), "--out", str(tmp_path / "runs")])
        commands = cell.controller.commands()
    err = capsys.readouterr().err
    assert status == 2
    assert "refusing to move the robot" in err and "--yes" in err
    assert commands == []
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow(seconds=11)
def test_calibration_file_and_report_from_the_command(tmp_path, capsys):
    status = main(["calibrate", "--sim", "--sensor", "can", "--time-scale", "0", "--yes",
                   "--config", str(_fast_toml(tmp_path)), "--out", str(tmp_path / "runs"),
                   "--save", str(tmp_path / "view.rrd")])
    out, err = capsys.readouterr()
    assert status == 0, out[-2000:] + err[-2000:]
    from ftacq.app.dashboard import layout
    from tests.rrd_reader import entity_paths, read_scalars

    paths = entity_paths(tmp_path / "view.rrd")  # the dashboard listener was attached and drew the run
    assert {"world/plan/A", "calibration/measured/force", "calibration/residuals/force",
            "calibration/validation_norm/force"} <= paths
    # the four wrench plots: every sample the procedure read (raw), compensated once the calibration is known
    raw_time_s, raw_force = read_scalars(tmp_path / "view.rrd", layout.RAW_FORCE)
    _, raw_torque = read_scalars(tmp_path / "view.rrd", layout.RAW_TORQUE)
    compensated_time_s, compensated_force = read_scalars(tmp_path / "view.rrd", layout.COMPENSATED_FORCE)
    _, compensated_torque = read_scalars(tmp_path / "view.rrd", layout.COMPENSATED_TORQUE)
    assert raw_time_s.size > 35 * 10 and raw_torque.shape == raw_force.shape  # 35 poses, many samples each
    assert 0 < compensated_time_s.size <= raw_time_s.size and compensated_torque.shape == compensated_force.shape
    # each averaging window's line ends with a row of NaN: the plot never joins two windows across a move
    breaks = np.isnan(compensated_force).all(axis=1)
    assert np.isnan(compensated_torque[breaks]).all() and np.isfinite(compensated_force[~breaks]).all()
    assert breaks.sum() >= 35 and not breaks[0] and not (breaks[1:] & breaks[:-1]).any()  # one per window
    compensated_force = compensated_force[~breaks]
    assert np.median(np.abs(raw_force)) > 1.0  # the tool's weight ...
    assert np.linalg.norm(compensated_force, axis=1).max() < 1.0  # ... is gone in every averaging window: no
    # contact while calibrating (and no sample from before a move compensated with the pose after it)
    (run_dir,) = list((tmp_path / "runs").iterdir())
    calibration = load_calibration(run_dir / "calibration.json")
    assert_recovers_truth(calibration, CellTruth())
    assert len(calibration.metadata["validation"]["labels"]) == 4
    assert calibration.metadata["input"]["sets"] == {"A": 24, "D": 1, "E": 6, "V": 4}
    report = (run_dir / "report.md").read_text(encoding="utf-8")
    from tests.test_run_report import assert_tables_render

    assert_tables_render(report)  # the validation table's "max |error|" header split into 6 cells over a 4-cell rule
    for part in ("## Identified parameters", "## Validation on held-out poses", "## Drift check",
                 "![residuals](residuals.png)", "Against the simulation's ground truth"):
        assert part in report
    for png in ("wrench_per_pose.png", "residuals.png", "validation.png"):
        assert (run_dir / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "true (simulation)" in out and "validation on 4 held-out poses" in out
    assert f"calibration: {run_dir / 'calibration.json'}" in out


def _fast_toml(tmp_path):
    path = tmp_path / "FAST.toml"
    path.write_text("[poses]\nrandom_count = 6\nvalidation_count = 4\n"
                    "[sampling]\nsettle_time_s = 0.0\nsettle_window_s = 0.02\naverage_time_s = 0.1\n",
                    encoding="utf-8")
    return path


def test_drift_check_warns_about_a_drifting_sensor(tmp_path):
    from dataclasses import replace

    drifting = replace(CellTruth(), drift_n_per_s=(0.05, 0.0, 0.05))
    with SimulatedCell(truth=drifting, sensor="can", time_scale=0.0) as cell:
        config = fast_config(cell, random_count=0, validation_count=2, drift_warn_force_n=0.05)
        plan, result = run_calibration(cell, config)
    assert result.status == "done", result.message
    drift = result.drift
    elapsed = drift.elapsed_s
    assert elapsed > 0
    # the revisit differs from the first measurement by the drift rate × the time between them
    np.testing.assert_allclose(drift.drift[[0, 2]], [0.05 * elapsed] * 2, rtol=0.25, atol=0.05)
    assert drift.warning and "warm up" in drift.warning
    assert drift.warning in result.warnings
