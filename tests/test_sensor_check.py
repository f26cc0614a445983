"""The sensor check (issue 41): the force gain/cross-talk matrix C and the torque gains' differences from gravity,
what is identifiable with and without a reference weight, and the verdict's sensor line."""

import numpy as np
import pytest
from scipy.linalg import sqrtm
from scipy.spatial.transform import Rotation

from ftacq.identification import identify
from ftacq.identification.sensor_gain import ReferenceWeight, fit_sensor_gain
from ftacq.posefile import PoseRecord
from ftacq.sensor_check import sensor_finding
from ftacq.so3 import cube_rotations, rotation_zyx_deg
from ftacq.verdict import FAIL, PASS, WARN, identification_findings
from tests.fakes.pose_records import example_record
from tests.fakes.world import BAD_SENSOR_GAIN_ERROR, CellTruth

ISSUE_ERROR = np.zeros((6, 6))
ISSUE_ERROR[2, 2], ISSUE_ERROR[0, 0], ISSUE_ERROR[1, 0], ISSUE_ERROR[3, 3] = 0.010, -0.006, 0.007, 0.008
"""The issue's independent cell: Fz 1.0 % high, Fx 0.6 % low, 0.7 % of Fx on Fy, Tx 0.8 % high."""


def _as_truth(error: np.ndarray, **changes) -> CellTruth:
    return CellTruth(sensor_gain_error=tuple(map(tuple, error)), **changes)


def _exact_data(force_gain: np.ndarray, torque_gain: np.ndarray):
    """Noise-free wrenches at the 24 special + 24 random orientations through a sensor with these gain matrices."""
    rotations = np.concatenate([cube_rotations(), Rotation.random(24, random_state=2).as_matrix()])
    sensor_rotation = rotation_zyx_deg(30.0, -20.0, 75.0)
    gravity_base = np.array([0.0, 0.0, -1.35 * 9.80665])
    force_bias, torque_bias = np.array([3.2, -1.5, 7.8]), np.array([0.12, -0.31, 0.05])
    center = np.array([0.004, -0.012, 0.065])
    applied = np.einsum("ab,nbc,c->na", sensor_rotation, rotations, gravity_base)
    wrench = np.hstack([applied @ force_gain.T + force_bias, np.cross(center, applied) @ torque_gain.T + torque_bias])
    start = {"S": sensor_rotation, "g": gravity_base * 1.01, "F0": force_bias, "c": center, "T0": torque_bias}
    whiten = np.tile(np.diag(1.0 / np.array([0.002] * 3 + [1e-4] * 3)), (len(rotations), 1, 1))
    return rotations, wrench, start, whiten


@pytest.mark.parametrize("reference", [None, ReferenceWeight(1.35)])
def test_an_injected_gain_matrix_is_recovered_from_noise_free_data(reference):
    # any C (gains, one-way cross-talk): gravity shows its symmetric polar factor P = √(C Cᵀ), the rotation part
    # being the mounting rotation; without a reference only P up to scale (normalised to trace 3)
    force_gain = np.eye(3) + np.array([[-0.006, 0.002, 0.0], [0.007, 0.003, -0.004], [0.001, 0.0, 0.010]])
    rotations, wrench, start, whiten = _exact_data(force_gain, np.eye(3))
    fit = fit_sensor_gain(rotations, wrench, start, whiten, reference=reference)
    polar = np.real(sqrtm(force_gain @ force_gain.T))
    expected = polar if reference else 3.0 * polar / np.trace(polar)
    np.testing.assert_allclose(fit.force_gain, expected, atol=1e-9)
    assert np.abs(fit.residual).max() < 1e-9
    assert fit.mass_kg == pytest.approx(1.35 if reference else 1.35 * np.trace(polar) / 3.0, rel=1e-9)
    assert fit.significant


def test_the_torque_gains_differences_are_seen_through_the_lever_arm():
    torque_gain = np.diag([1.008, 1.0, 0.995])
    rotations, wrench, start, whiten = _exact_data(np.eye(3), torque_gain)
    fit = fit_sensor_gain(rotations, wrench, start, whiten)
    np.testing.assert_allclose(fit.force_gain, np.eye(3), atol=1e-9)
    differences = {tuple(d["axes"]): d["value"] for d in fit.torque_gain_differences()}
    # d_k − d_j to first order (the common factor goes into the centre of mass)
    assert differences[("Tx", "Ty")] == pytest.approx(-0.008, rel=0.01)
    assert differences[("Tx", "Tz")] == pytest.approx(-0.013, rel=0.01)
    assert differences[("Ty", "Tz")] == pytest.approx(-0.005, rel=0.01)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_issue_cell_gains_are_recovered_within_their_sigma_and_the_verdict_names_no_drift(seed):
    truth = _as_truth(ISSUE_ERROR)
    result = identify(example_record(truth, seed=seed), sensor_check=True, reference=ReferenceWeight(truth.mass_kg))
    check = result.calibration.metadata["sensor_check"]
    polar = np.real(sqrtm((np.eye(3) + ISSUE_ERROR[:3, :3]) @ (np.eye(3) + ISSUE_ERROR[:3, :3]).T))
    error = np.asarray(check["force_gain"]) - polar
    assert np.all(np.abs(error) <= 3.0 * np.asarray(check["force_gain_sigma"]))  # honest 1σ
    assert check["significant"]
    findings = {f.check: f for f in identification_findings(result)}
    assert findings["sensor"].status == PASS  # within the certificate's 1.25 %: measured, named, not a fault
    assert "Fz reads 1.6 % more than Fx" in findings["sensor"].summary  # +1.0 % and −0.6 %
    assert findings["trend"].status == PASS


def test_a_gain_error_is_not_taken_for_a_drift():
    # a 5 kg tool on the issue's sensor, the poses measured over 30 min with the tool axis sweeping from down to up:
    # the paper's model sees its gain residuals trend with time and fits a drift the sensor does not have
    truth = _as_truth(ISSUE_ERROR, mass_kg=5.0)
    record = example_record(truth, seed=0)
    record = record.select(np.argsort(record.flange_R_base[:, 2, 2]))
    t = np.linspace(0.0, 1800.0, len(record))
    record = PoseRecord(pose=record.pose, wrench=record.wrench, std=record.std, count=record.count,
                        labels=record.labels, sets=record.sets, extra={"t_start_s": t, "t_end_s": t + 0.5})
    assert identify(record).calibration.metadata["drift_model"]["model"] == "linear"  # today: a false drift
    checked = identify(record, sensor_check=True)
    assert checked.calibration.metadata["drift_model"]["model"] == "none"
    assert {f.check: f for f in identification_findings(checked)}["trend"].status == PASS


@pytest.mark.parametrize("reference", [None, ReferenceWeight(1.35)])
def test_the_verdict_names_the_bad_axis(reference):
    truth = _as_truth(np.asarray(BAD_SENSOR_GAIN_ERROR))
    result = identify(example_record(truth, seed=4), sensor_check=True, reference=reference)
    sensor = {f.check: f for f in identification_findings(result)}["sensor"]
    assert sensor.status == FAIL
    assert "Fz" in sensor.summary and "certificate accuracy 1.25 %" in sensor.summary
    if reference:
        assert "Fz gain 4 % high" in sensor.summary
    else:
        assert "Fz reads 5.5 % more than Fx" in sensor.summary


@pytest.mark.parametrize("seed", range(6))
def test_a_healthy_sensor_passes_and_changes_nothing(seed):
    record = example_record(CellTruth(), seed=seed)
    plain = identify(record)
    checked = identify(record, sensor_check=True, reference=ReferenceWeight(1.35, 0.001))
    findings = {f.check: f for f in identification_findings(checked)}
    assert findings["sensor"].status == PASS and "within the noise" in findings["sensor"].summary
    np.testing.assert_array_equal(checked.calibration.gravity_base, plain.calibration.gravity_base)
    np.testing.assert_array_equal(checked.calibration.sensor_rotation, plain.calibration.sensor_rotation)


def _check(gain, sigma, mass_kg=1.35, reference=None):
    covariance = np.diag(np.r_[np.diag(sigma), sigma[0, 1], sigma[0, 2], sigma[1, 2]] ** 2)
    return {"force_gain": gain, "force_gain_sigma": sigma, "force_gain_covariance": covariance, "mass_kg": mass_kg,
            "reference_mass_kg": reference, "torque_gain_differences": [], "chi2": 100.0, "dof": 11,
            "p_value": 1e-12, "significant": True}


def test_the_sensor_line_warns_beyond_the_accuracy_and_fails_beyond_twice_it():
    sigma = np.full((3, 3), 0.001)
    warn = sensor_finding(_check(np.diag([1.0, 1.0, 1.018]), sigma, reference=1.35), 1.25)
    assert warn.status == WARN and warn.summary.startswith("the sensor's own calibration is off: Fz gain 1.8 % high "
                                                           "(± 0.1 %); certificate accuracy 1.25 %")
    assert sensor_finding(_check(np.diag([1.0, 1.0, 1.03]), sigma, reference=1.35), 1.25).status == FAIL
    within = sensor_finding(_check(np.diag([1.0, 1.0, 1.014]), sigma, reference=1.35), 1.25)  # 1.4 − 3σ < 1.25
    assert within.status == PASS
    crosstalk = np.eye(3)
    crosstalk[0, 1] = crosstalk[1, 0] = 0.02
    assert "cross-talk between Fx and Fy 2 %" in sensor_finding(_check(crosstalk, sigma), 1.25).summary


def test_on_a_light_tool_a_gain_error_within_the_mismatch_tolerance_is_not_a_fault():
    # 0.2 kg: a 3 % gain difference is 0.03 N, what a cable or the arm's own errors make
    finding = sensor_finding(_check(np.diag([0.99, 1.0, 1.02]), np.full((3, 3), 0.001), mass_kg=0.2), 1.25,
                             (0.1, 0.005))
    assert finding.status == PASS and "heavier reference weight" in finding.summary


@pytest.mark.parametrize("seed", [0, 1])
def test_a_real_drift_is_not_taken_for_a_gain_error(seed):
    # the reverse: a sensor that drifts 1.6 N/h over 30 min, its gains perfect. Fitting the gains alone would absorb
    # part of the drift (the poses' order follows their orientation); the drift and the gains are fitted together
    from tests.test_identification_realdata import drifting_record

    record, _truth, _ = drifting_record(seed)
    result = identify(record, sensor_check=True)
    assert result.calibration.metadata["drift_model"]["model"] == "linear"
    sensor = {f.check: f for f in identification_findings(result)}["sensor"]
    assert sensor.status == PASS and "within the noise" in sensor.summary


def test_the_yumi_recording_shows_gain_ratios_it_cannot_tell_from_other_errors():
    # a real 0.22 kg tool on an ABB YuMi (tests/data/yumi-gravitylog): the check is significant (Fx reads ~5 % more
    # than Fz), but at 2.2 N that is 0.05 N, within the mismatch tolerance: named, not a fault (a correct
    # calibration is never rejected)
    from tests.test_yumi_recording import _import

    result = identify(_import().record, sensor_check=True)
    check = result.calibration.metadata["sensor_check"]
    gain = np.asarray(check["force_gain"])
    assert check["significant"] and 0.02 < gain[0, 0] - gain[2, 2] < 0.08
    sensor = {f.check: f for f in identification_findings(result)}["sensor"]
    assert sensor.status == PASS and "heavier reference weight" in sensor.summary


def test_identify_reads_the_reference_mass_and_refuses_a_bad_one(tmp_path, capsys):
    from ftacq.app.cli import main
    from ftacq.calfile import load_calibration
    from ftacq.posefile import write_pose_csv
    from ftacq.sensor_check import parse_reference_mass

    assert parse_reference_mass("1.35+-0.002") == ReferenceWeight(1.35, 0.002)
    poses = tmp_path / "poses.csv"
    write_pose_csv(poses, example_record(CellTruth(), seed=2))
    out = tmp_path / "cal.json"
    assert main(["identify", str(poses), "-o", str(out), "--reference-mass", "1.3x"]) == 2
    assert "--reference-mass: '1.3x' is not KG or KG±SIGMA" in capsys.readouterr().err and not out.exists()
    assert main(["identify", str(poses), "-o", str(out), "--reference-mass", "1.35±0.002"]) in (0, 1)
    check = load_calibration(out).metadata["sensor_check"]
    assert check["reference_mass_kg"] == 1.35 and check["reference_sigma_kg"] == 0.002
    findings = {f["check"]: f for f in load_calibration(out).metadata["verdict"]["findings"]}
    assert findings["sensor"]["status"] == "PASS"
