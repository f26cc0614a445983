"""Tare with the tool on (``ftacq tare``): biases re-estimated within their stated 1σ at one pose and at N planned
poses on the simulated cell, the rest of the calibration kept, provenance recorded, a foreign sensor refused."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from drivers.robot import MotionLimits
from drivers.sensor import open_sensor
from drivers.ur import URRobot
from ftacq.app.cli import main
from ftacq.bias_estimate import apply_estimate, compensation_sigma, estimate_biases
from ftacq.calfile import calibration_to_dict, load_calibration, save_calibration
from ftacq.identification import identify
from ftacq.kinematics import MEASURED_ANGLE_TOLERANCE_RAD
from ftacq.so3 import rotation_from_rotvec
from procedures.calibration_procedure import ProcedureOptions
from procedures.plan import make_plan
from procedures.settle import SettleSettings
from procedures.tare import TareProcedure, tare_here, tare_plan_settings
from tests.fakes.cell import SimulatedCell, fast_config, motion_problems
from tests.fakes.pose_records import example_record
from tests.fakes.world import CellTruth

CHI2_6_AT_3_SIGMA = 20.06
"""χ² with 6 degrees of freedom exceeded with the probability of a 3σ excursion (0.27 %): the six channels'
errors, whitened by the estimate's stated covariance, must lie within it (one bound for all six channels keeps a
3σ test from failing 1.6 % of the time by chance, as six separate 3σ bounds would)."""
SHIFT = np.array([0.4, -0.3, 0.5, 0.01, -0.012, 0.006])
"""How far the simulated sensor's biases are from the calibration's (N, N·m)."""
FAST_SETTLE = SettleSettings(settle_time_s=0.0, window_s=0.02, average_time_s=0.2, timeout_s=5.0)


def shifted_truth(truth: CellTruth | None = None) -> CellTruth:
    truth = truth or CellTruth()
    return replace(truth, force_bias_n=tuple(np.add(truth.force_bias_n, SHIFT[:3])),
                   torque_bias_nm=tuple(np.add(truth.torque_bias_nm, SHIFT[3:])))


def whitened_chi2(estimate, truth: CellTruth) -> float:
    error = estimate.bias - np.concatenate([truth.force_bias_n, truth.torque_bias_nm])
    return float(error @ np.linalg.solve(estimate.covariance, error))


def test_noise_free_tare_is_exact_and_keeps_the_model() -> None:
    truth = CellTruth()
    calibration = truth.calibration()
    rotations = np.array([rotation_from_rotvec(v) for v in np.random.default_rng(3).normal(size=(5, 3))])
    readings = shifted_truth().calibration().predict(rotations)
    estimate = estimate_biases(calibration, rotations, readings)
    np.testing.assert_allclose(estimate.change, SHIFT, atol=1e-12)
    tared = apply_estimate(calibration, estimate)
    for name in ("sensor_rotation", "gravity_base", "center_of_mass"):
        np.testing.assert_array_equal(getattr(tared, name), getattr(calibration, name))
    np.testing.assert_allclose(tared.compensate(readings, rotations), 0.0, atol=1e-12)
    history = tared.metadata["bias_history"]
    assert [entry["method"] for entry in history] == ["calibration (unknown method)", "tare, 5 poses"]
    assert history[0]["time"] is None and history[1]["time"].endswith("+00:00")


def test_kept_parameters_uncertainty_enters_the_bias_sigma() -> None:
    """A calibration whose rotation, weight and centre of mass are uncertain gives a wider bias 1σ than the
    noise alone; the compensated wrench's 1σ at rest includes every parameter's."""
    identified = identify(example_record(seed=2), mount="floor").calibration
    exact = replace(identified, uncertainty={}, metadata={})
    rotation = np.eye(3)[None]
    wrench = identified.predict(rotation)
    noise = np.full((1, 6), 0.05)
    with_model = estimate_biases(identified, rotation, wrench, std=noise, count=np.array([1e6]))
    noise_only = estimate_biases(exact, rotation, wrench, std=noise, count=np.array([1e6]))
    assert np.all(with_model.sigma > noise_only.sigma)
    np.testing.assert_allclose(noise_only.sigma, 0.05 / 1e3, rtol=1e-6)
    assert np.all(compensation_sigma(identified, rotation) >= np.concatenate(
        [identified.uncertainty["force_bias"], identified.uncertainty["torque_bias"]]))


@pytest.fixture()
def shifted_cell():
    with SimulatedCell(truth=shifted_truth(), sensor="netft", time_scale=0.0, rate_hz=1000.0, seed=11) as cell:
        yield cell


def test_one_pose_tare_recovers_the_biases_within_their_sigma(shifted_cell) -> None:
    calibration = CellTruth().calibration()
    robot = URRobot(shifted_cell.robot_host, MotionLimits())
    sensor = open_sensor(shifted_cell.sensor_url)
    try:
        robot.start()
        sensor.start()
        q_before = robot.joint_positions()
        result = tare_here(robot, sensor, calibration, FAST_SETTLE)
        # the same angles, within the encoders' jitter (the cell reports them as a real arm does)
        np.testing.assert_allclose(robot.joint_positions(), q_before, rtol=0, atol=MEASURED_ANGLE_TOLERANCE_RAD)
    finally:
        sensor.close()
        robot.close()
    assert shifted_cell.controller.commands() == []  # nothing moved
    estimate = result.estimate
    assert estimate.poses == 1 and result.count[0] >= 100
    assert np.all(estimate.sigma > 0)
    assert whitened_chi2(estimate, shifted_cell.truth) <= CHI2_6_AT_3_SIGMA, (estimate.bias, estimate.sigma)
    np.testing.assert_allclose(estimate.change, SHIFT, atol=0.05)


def test_n_pose_tare_moves_through_the_checked_plan_and_recovers_the_biases(shifted_cell) -> None:
    config = fast_config(shifted_cell)
    settings = tare_plan_settings(config.plan_settings(), 4)
    limits = MotionLimits(joint_speed_rad_s=settings.joint_speed_rad_s,
                          joint_acceleration_rad_s2=settings.joint_acceleration_rad_s2)
    robot = URRobot(shifted_cell.robot_host, limits, model=settings.model)
    sensor = open_sensor(shifted_cell.sensor_url)
    try:
        robot.start()
        sensor.start()
        plan = make_plan(settings, robot.joint_positions())
        assert len(plan) == 4 and set(plan.set_names) == {"E"}
        procedure = TareProcedure(plan, robot, sensor, CellTruth().calibration(), ProcedureOptions.from_config(config))
        outcome = procedure.run()
    finally:
        sensor.close()
        robot.close()
    assert outcome.status == "done", outcome.message
    assert motion_problems(shifted_cell.controller.commands(), plan, limits) == []
    assert len([c for c in shifted_cell.controller.commands() if c["kind"] == "movej"]) == 4
    estimate = procedure.result.estimate
    assert estimate.poses == 4 and np.isfinite(estimate.chi2_per_dof)
    assert whitened_chi2(estimate, shifted_cell.truth) <= CHI2_6_AT_3_SIGMA, (estimate.bias, estimate.sigma)


def write_config(tmp_path, cell) -> str:
    path = tmp_path / "CELL.toml"
    path.write_text(f'[robot]\nhost = "{cell.robot_host}"\n[sensor]\nurl = "{cell.sensor_url}"\n'
                    "[sampling]\nsettle_time_s = 0.0\nsettle_window_s = 0.02\naverage_time_s = 0.1\n"
                    '[tool]\nname = "gripper-A"\n')
    return str(path)


def sensor_record(serial: str) -> dict:
    return {"serial": serial, "model": "Net F/T (simulated)", "transport": "netft", "counts_per_force": 1e6,
            "counts_per_torque": 5e5, "force_unit": "N", "torque_unit": "N-m", "firmware": ""}


def test_cli_refuses_a_calibration_of_another_sensor_unless_forced(shifted_cell, tmp_path, capsys) -> None:
    calibration = CellTruth().calibration()
    foreign = replace(calibration, metadata={"sensor": sensor_record("FT99999")})
    save_calibration(tmp_path / "cal.json", foreign)
    config = write_config(tmp_path, shifted_cell)
    out = tmp_path / "new.json"
    assert main(["tare", "--config", config, "--calibration", str(tmp_path / "cal.json"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "FT99999" in err and "FT12345" in err and "--force" in err and "Traceback" not in err
    assert not out.exists()
    assert main(["tare", "--config", config, "--calibration", str(tmp_path / "cal.json"), "-o", str(out),
                 "--force"]) == 0
    assert "WARNING (--force)" in capsys.readouterr().err
    tared = load_calibration(out)
    assert tared.metadata["sensor"]["serial"] == "FT12345"  # the biases were measured on the sensor connected
    entry = tared.metadata["bias_history"][-1]
    assert entry["method"].startswith("tare") and entry["sensor"] == "FT12345"
    assert entry["previous_sensor"] == "FT99999"  # and the tare says whose calibration it was


def test_tare_prints_each_sigma_with_two_significant_digits() -> None:
    """1σ of 0.00045 N and 0.000034 N·m print as 0.00045 and 0.000034 (not 0.0004 and 0.00003); each value to
    the same decimal."""
    from ftacq.app.commands.tare import format_estimate
    from ftacq.bias_estimate import BiasEstimate

    sigma = np.array([0.00045, 0.0012, 0.0031, 0.000034, 0.000051, 0.000027])
    estimate = BiasEstimate(force_bias=np.array([3.21234, -1.5, 7.8]), torque_bias=np.array([0.12, -0.31, 0.05]),
                            covariance=np.diag(sigma**2), previous=np.array([3.2, -1.5, 7.8, 0.12, -0.31, 0.05]),
                            poses=1, residuals=np.zeros((1, 6)), chi2_per_dof=float("nan"), method="tare, 1 pose")
    rows = format_estimate(estimate, 3500).splitlines()[2:]
    assert rows[0].split()[2:] == ["3.20000", "3.21234", "0.00045", "+0.01234"]
    assert rows[3].split()[3:5] == ["0.120000", "0.000034"]


def test_cli_tares_a_version_1_file_into_version_2_with_provenance(shifted_cell, tmp_path, capsys) -> None:
    """An old (version 1) calibration file loads; the tare writes version 2 with the sensor, the bias history
    (the calibration's own biases first) and the new biases; every other parameter is unchanged."""
    calibration = CellTruth().calibration()
    document = calibration_to_dict(calibration)
    document["version"] = 1
    for key in ("sensor", "tool", "bias_history"):
        document.pop(key, None)
    old = tmp_path / "v1.json"
    old.write_text(json.dumps(document))
    loaded = load_calibration(old)
    np.testing.assert_array_equal(loaded.force_bias, calibration.force_bias)
    out = tmp_path / "new.json"
    code = main(["tare", "--config", write_config(tmp_path, shifted_cell), "--calibration", str(old), "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "sensor match not checked" in captured.err
    for name in ("Fx [N]", "old", "new", "1σ", "change"):
        assert name in captured.out
    written = json.loads(out.read_text())
    assert written["version"] == 2
    assert written["sensor"]["serial"] == "FT12345" and written["sensor"]["transport"] == "netft"
    assert written["tool"] == {"name": "gripper-A"}  # CELL.toml tool.name
    assert [e["method"] for e in written["bias_history"]] == ["calibration (unknown method)", "tare, 1 pose"]
    assert written["bias_history"][0]["force_bias"] == list(calibration.force_bias)
    assert written["sensor_rotation"] == document["sensor_rotation"]
    assert written["center_of_mass_m"] == document["center_of_mass_m"]
    assert written["mass_kg"] == document["mass_kg"]
    np.testing.assert_allclose(np.subtract(written["force_bias"], calibration.force_bias), SHIFT[:3], atol=0.05)


@pytest.mark.parametrize("change, expected", [
    (lambda d: d.update(sensor="FT1"), "key 'sensor': expected an object"),
    (lambda d: d.update(sensor={"serial": 12}), "key 'sensor.serial'"),
    (lambda d: d.update(sensor={"counts_per_force": "x"}), "key 'sensor.counts_per_force'"),
    (lambda d: d.update(tool={"name": 3}), "key 'tool'"),
    (lambda d: d.update(bias_history={}), "key 'bias_history': expected a list"),
    (lambda d: d.update(bias_history=[{"time": "t", "method": "m", "force_bias": [1, 2], "torque_bias": [0, 0, 0]}]),
     "bias_history\\[0\\].force_bias"),
])
def test_bad_provenance_is_refused_with_the_key(tmp_path, change, expected) -> None:
    from ftacq.errors import InputError

    document = calibration_to_dict(CellTruth().calibration())
    change(document)
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(document))
    with pytest.raises(InputError, match=expected):
        load_calibration(path)
