"""The verdict: PASS, WARN or FAIL against stated tolerances, with reasons in plain words (ftacq.verdict)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ftacq.identification import identify
from ftacq.verdict import (DRIFT_FAIL_FACTOR, FAIL, PASS, WARN, Finding, conditioning_finding, drift_finding,
                           format_verdict, held_out_covariance, identification_findings, judge, outlier_finding,
                           poses_finding, validation_finding)
from tests.fakes.pose_records import cone_orientations, example_record, simulate_record, special_orientations
from tests.fakes.world import CellTruth

VALIDATION_POSES = 8


def held_out(truth: CellTruth, seed: int, orientation_error_deg: float = 0.0):
    labels = tuple(f"V{i + 1:02d}" for i in range(VALIDATION_POSES))
    return simulate_record(truth, cone_orientations(VALIDATION_POSES, 40.0, seed + 100), seed=seed + 200,
                           labels=labels, sets=("V",) * VALIDATION_POSES,
                           orientation_error_deg=orientation_error_deg)


def test_a_right_calibration_has_validation_errors_of_the_predicted_size():
    """Σ d² / dof averages 1 over many calibrations (the predicted covariance is neither too small nor too big)."""
    ratios, statuses = [], []
    for seed in range(12):
        truth = CellTruth()
        result = identify(example_record(truth, seed=seed, cone_poses=6), mount="floor")
        finding = identification_findings(result, held_out(truth, seed))[0]
        ratios.append(finding.figures["chi2"] / finding.figures["dof"])
        statuses.append(finding.status)
    # 12 × 48 degrees of freedom: the mean of χ²/dof has a standard deviation of √(2/576) ≈ 0.06
    assert 0.8 < np.mean(ratios) < 1.2, ratios
    assert statuses.count(FAIL) == 0 and statuses.count(WARN) <= 2, statuses


def test_the_parameter_covariance_matters_with_few_poses():
    truth = CellTruth()
    record = example_record(truth, seed=3, cone_poses=0)  # 24 poses: the parameters' 1σ is not negligible
    result = identify(record, mount="floor")
    validation = held_out(truth, 3)
    with_parameters = held_out_covariance(result, validation)
    without = held_out_covariance(dataclasses.replace(result, parameter_covariance=None), validation)
    extra = np.einsum("naa->na", with_parameters - without)
    assert np.all(extra > 0.0)
    assert np.max(extra / np.einsum("naa->na", without)) > 0.05  # a visible share of the expected error


def test_validation_poses_with_another_tool_fail_with_the_reason():
    truth = CellTruth()
    result = identify(example_record(truth, seed=1, cone_poses=6), mount="floor")
    heavier = dataclasses.replace(truth, mass_kg=truth.mass_kg + 0.1)  # a 100 g part left in the gripper
    verdict = judge(identification_findings(result, held_out(heavier, 1)))
    assert verdict.status == FAIL
    assert verdict.finding("validation").status == FAIL
    assert "held-out poses disagree with the calibration" in verdict.reasons[0]
    assert "the tool, its load or the sensor changed" in verdict.reasons[0]
    assert verdict.headline().startswith("FAIL: the 8 held-out poses disagree")


def test_robot_orientation_error_is_part_of_the_prediction():
    truth = CellTruth()
    statuses = []
    for seed in range(4):
        rotations = np.concatenate([special_orientations(0.2, seed), cone_orientations(12, 40.0, seed + 1)])
        record = simulate_record(truth, rotations, seed=seed, labels=tuple(f"A{i:02d}" for i in range(36)),
                                 sets=("A",) * 36, orientation_error_deg=0.05)
        result = identify(record, mount="floor")
        assert result.calibration.metadata["noise"]["orientation_error_deg"] > 0.0
        statuses.append(identification_findings(result, held_out(truth, seed, 0.05))[0].status)
    assert FAIL not in statuses and statuses.count(PASS) >= 3, statuses


def test_validation_thresholds_and_band():
    covariance = np.tile(np.eye(6) * 0.01**2, (5, 1, 1))  # σ = 0.01 per axis
    rng = np.random.default_rng(0)
    labels = [f"V{i}" for i in range(5)]
    good = validation_finding(rng.standard_normal((5, 6)) * 0.01, covariance, labels)
    assert good.status == PASS and "read zero within the sensor noise" in good.summary
    np.testing.assert_allclose(good.figures["expected_sigma"], 0.01, rtol=1e-6)
    one_bad = rng.standard_normal((5, 6)) * 0.01
    one_bad[2, 0] = 0.06  # 6σ on one pose
    finding = validation_finding(one_bad, covariance, labels)
    assert finding.status == WARN and "V2" in finding.summary
    assert validation_finding(np.full((5, 6), 0.5), covariance, labels).status == FAIL
    assert validation_finding(np.zeros((0, 6)), np.zeros((0, 6, 6)), []).status == WARN
    assert validation_finding(np.zeros((2, 6)), covariance[:2], labels[:2]).status == WARN  # too few poses


def test_drift_thresholds():
    assert drift_finding(np.array([0.1, 0, 0, 0.001, 0, 0]), 600, 0.5, 0.02, "A01").status == PASS
    warn = drift_finding(np.array([0.6, 0, 0, 0, 0, 0]), 600, 0.5, 0.02, "A01")
    assert warn.status == WARN and "drifted" in warn.summary
    fail = drift_finding(np.array([0, 0, 0, 0, 0, 0.02 * DRIFT_FAIL_FACTOR * 1.01]), 600, 0.5, 0.02, "A01")
    assert fail.status == FAIL and "warm up" in fail.summary


def test_outliers_conditioning_and_poses():
    assert outlier_finding([], 30).status == PASS
    assert outlier_finding(["E03"], 30).status == WARN
    assert outlier_finding([f"E{i}" for i in range(7)], 30).status == FAIL
    assert conditioning_finding(12.0, []).status == PASS
    weak = conditioning_finding(2e6, ["centre of mass poorly determined (1σ up to 3.1 mm)"])
    assert weak.status == WARN and "centre of mass" in weak.summary
    wanted = {"A": 24, "E": 30, "V": 6}
    assert poses_finding({"A": 24, "E": 30, "V": 6}, wanted, 61, 61).status == PASS
    short = poses_finding({"A": 20, "E": 30, "V": 6}, wanted, 57, 57)
    assert short.status == WARN and "4 of the 24 special orientations" in short.summary
    stopped = poses_finding({"A": 24, "E": 30, "V": 6}, wanted, 23, 61, "interrupted at pose 24/61 (E15)")
    assert stopped.status == FAIL and "23 of 61" in stopped.summary


def test_judge_takes_the_worst_and_keeps_method_names_out_of_the_plain_words():
    findings = [Finding("outliers", WARN, "1 of 30 poses looked disturbed", "robust fit"),
                Finding("validation", PASS, "fine", "χ² = 40 on 48 degrees of freedom"),
                Finding("drift", FAIL, "the sensor drifted", "A01 revisited")]
    verdict = judge(findings)
    assert verdict.status == FAIL and verdict.reasons == ["the sensor drifted", "1 of 30 poses looked disturbed"]
    assert judge([]).status == PASS
    text = format_verdict(verdict)
    assert text.splitlines()[0] == "verdict: FAIL"
    plain, details = text.split("  details:")
    assert "χ²" not in plain and "χ²" in details
    with pytest.raises(ValueError):
        judge([Finding("x", "MAYBE", "")])
    document = verdict.to_dict()
    assert document["status"] == FAIL and document["findings"][0]["check"] == "outliers"
