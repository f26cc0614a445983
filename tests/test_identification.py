"""Identification without noise (exactness of every step), degenerate pose sets, method and mount options."""

import numpy as np
import pytest

from ftacq.errors import IdentificationError
from ftacq.identification import identify
from ftacq.identification.lrom import lrom
from ftacq.identification.srom import match_special
from ftacq.identification.tilt import relative_tilt_deg
from ftacq.identification.torque import torque_least_squares
from ftacq.identification.wahba import wahba
from ftacq.so3 import rotation_from_rotvec
from tests.fakes.pose_records import (
    TOOL_DOWN_BASE_R_FLANGE,
    cone_orientations,
    random_orientations,
    simulate_record,
    special_orientations,
)
from tests.fakes.world import CellTruth

EXACT = 1e-9


def assert_matches_truth(calibration, truth: CellTruth, tolerance: float = EXACT) -> None:
    expected = truth.calibration()
    for name in ("sensor_rotation", "force_bias", "torque_bias", "gravity_base", "center_of_mass"):
        np.testing.assert_allclose(getattr(calibration, name), getattr(expected, name), atol=tolerance, err_msg=name)


MOUNTS = {
    "floor": CellTruth(),
    "wall": CellTruth().with_mount("wall"),
    "ceiling": CellTruth().with_mount("ceiling"),
    "tilted-85": CellTruth(base_tilt_deg=(5.0, 85.0)),
    "tilted-floor": CellTruth(base_tilt_deg=(-2.0, 3.5), mass_kg=3.2, sensor_rotation_zyx_deg=(-170.0, 40.0, -10.0)),
}


@pytest.mark.parametrize("mount", list(MOUNTS))
def test_lrom_noise_free_random_orientations_recovers_every_parameter(mount):
    truth = MOUNTS[mount]
    record = simulate_record(truth, random_orientations(20, seed=7), noise=False)
    direct = lrom(record.flange_R_base, record.wrench[:, :3])
    np.testing.assert_allclose(direct.gravity_base, truth.gravity_base, atol=EXACT)
    np.testing.assert_allclose(direct.rotation_raw, truth.sensor_rotation, atol=EXACT)
    for refine in (False, True):
        result = identify(record, refine=refine)
        assert result.method_used == "lrom" + ("+refine" if refine else "")
        assert_matches_truth(result.calibration, truth)
        assert result.outliers == ()


def test_lrom_noise_free_in_a_limited_cone():
    truth = CellTruth(base_tilt_deg=(1.0, -2.0))
    record = simulate_record(truth, cone_orientations(24, 30.0, seed=3), noise=False)
    assert_matches_truth(identify(record, refine=False).calibration, truth, 1e-8)
    assert_matches_truth(identify(record).calibration, truth)


def test_wahba_and_torque_steps_are_exact_given_the_weight():
    truth = CellTruth()
    rotations = random_orientations(12, seed=2)
    wrench = truth.calibration().predict(rotations)
    fit = wahba(rotations, wrench[:, :3], truth.gravity_base)
    np.testing.assert_allclose(fit.sensor_rotation, truth.sensor_rotation, atol=1e-12)
    np.testing.assert_allclose(fit.force_bias, truth.force_bias_n, atol=1e-12)
    assert fit.unique
    gravity_sensor = (rotations @ truth.gravity_base) @ truth.sensor_rotation.T
    com, torque_bias = torque_least_squares(gravity_sensor, wrench[:, 3:])
    np.testing.assert_allclose(com, truth.center_of_mass_m, atol=1e-12)
    np.testing.assert_allclose(torque_bias, truth.torque_bias_nm, atol=1e-12)


def test_wahba_refuses_forces_along_one_direction():
    truth = CellTruth()
    spin = rotation_from_rotvec(np.column_stack([np.zeros(8), np.zeros(8), np.linspace(0, 3, 8)]))
    rotations = np.swapaxes(spin @ TOOL_DOWN_BASE_R_FLANGE, -1, -2)  # turning about the vertical only
    wrench = truth.calibration().predict(rotations)
    with pytest.raises(IdentificationError, match="rank D < 2"):
        wahba(rotations, wrench[:, :3], truth.gravity_base)


@pytest.mark.parametrize(
    "case, message",
    [
        ("few", "too few poses"),
        ("one-orientation", "share one orientation"),
        ("vertical-axis", "one axis only"),
        ("horizontal-axis", "one axis only"),
    ],
)
def test_degenerate_pose_sets_are_refused_with_the_reason(case, message):
    n = 10
    angles = np.linspace(0.0, 2.5, n)
    zeros = np.zeros(n)
    rotations = {
        "few": special_orientations()[:4],
        "one-orientation": np.repeat(special_orientations()[:1], n, axis=0),
        "vertical-axis": np.swapaxes(
            rotation_from_rotvec(np.column_stack([zeros, zeros, angles])) @ TOOL_DOWN_BASE_R_FLANGE, -1, -2
        ),
        "horizontal-axis": np.swapaxes(rotation_from_rotvec(np.column_stack([angles, zeros, zeros])), -1, -2),
    }[case]
    record = simulate_record(CellTruth(), rotations, seed=1)
    with pytest.raises(IdentificationError, match=message):
        identify(record)


def test_special_orientations_found_within_tolerance_only():
    rotations = special_orientations(perturbation_deg=2.5, seed=4)
    index, angle = match_special(rotations, 3.0)
    np.testing.assert_array_equal(index, np.arange(24))
    assert np.all(angle <= 2.5 + 1e-9)
    index, _ = match_special(rotations, 0.01)
    assert np.all(index[angle > 0.01] == -1)


def test_auto_picks_srom_only_with_all_24_and_method_can_be_forced():
    truth = CellTruth()
    full = simulate_record(truth, np.concatenate([special_orientations(0.5, 1), cone_orientations(10, 40.0, 2)]), seed=3)
    assert identify(full).method_used == "srom+refine"
    assert identify(full, method="lrom").method_used == "lrom+refine"
    partial = full.select(np.arange(1, 34))  # special orientation 1 missing
    result = identify(partial)
    assert result.method_used == "lrom+refine"
    assert any("23 of the 24 special" in w for w in result.warnings)
    with pytest.raises(IdentificationError, match="missing paper number\\(s\\) 1"):
        identify(partial, method="srom")
    with pytest.raises(IdentificationError, match="unknown method"):
        identify(full, method="magic")


@pytest.mark.parametrize("mount", ["floor", "wall", "ceiling"])
def test_tilt_relative_to_the_nominal_mount(mount):
    truth = CellTruth(mass_kg=2.0).with_mount(mount)
    tilted = CellTruth(mass_kg=2.0, base_tilt_deg=(truth.base_tilt_deg[0] + 0.7, truth.base_tilt_deg[1] - 1.2))
    record = simulate_record(tilted, random_orientations(16, seed=5), noise=False)
    result = identify(record, mount=mount)
    alpha_rel, beta_rel = result.calibration.metadata["base_tilt_relative_deg"]
    assert alpha_rel == pytest.approx(0.7, abs=1e-7)
    assert beta_rel == pytest.approx(-1.2, abs=1e-7)
    assert result.calibration.metadata["nearest_mount"] == mount
    assert not any("tilted" in w for w in result.warnings)
    wrong = "floor" if mount != "floor" else "ceiling"
    assert any(f"nominal {wrong} mount" in w for w in identify(record, mount=wrong).warnings)
    assert relative_tilt_deg(truth.gravity_base, mount)[2] == pytest.approx(0.0, abs=1e-9)


def test_base_tilt_branch_on_level_floor_and_ceiling():
    floor = identify(simulate_record(CellTruth(), random_orientations(12, 1), noise=False)).calibration
    assert floor.base_tilt_deg == pytest.approx((0.0, 0.0), abs=1e-7)
    ceiling = identify(simulate_record(CellTruth().with_mount("ceiling"), random_orientations(12, 1), noise=False))
    assert ceiling.calibration.base_tilt_deg == pytest.approx((0.0, 180.0), abs=1e-7)


def test_compensation_paths_agree():
    calibration = CellTruth(base_tilt_deg=(3.0, -20.0)).calibration()
    rotations = random_orientations(50, seed=3)
    wrench = np.random.default_rng(4).normal(size=(50, 6))
    expected = wrench - calibration.predict(rotations)
    np.testing.assert_allclose(calibration.compensate(wrench, rotations), expected, atol=1e-12)
    out = np.empty((50, 6))
    assert calibration.compensate(wrench, rotations, out=out) is out
    np.testing.assert_allclose(out, expected, atol=1e-12)
    in_place = wrench.copy()
    calibration.compensate(in_place, rotations, out=in_place)
    np.testing.assert_allclose(in_place, expected, atol=1e-12)
    one = calibration.compensate(wrench, rotations[7])  # one orientation for the whole batch
    np.testing.assert_allclose(one, wrench - calibration.predict(rotations[7]), atol=1e-12)
    np.testing.assert_allclose(calibration.compensate_sample(wrench[7], rotations[7]), expected[7], atol=1e-12)
    np.testing.assert_allclose(
        calibration.compensate_sample(wrench[7].tolist(), rotations[7].tolist()), expected[7], atol=1e-12
    )
    # the compensated contact-free reading is zero
    np.testing.assert_allclose(calibration.compensate(calibration.predict(rotations), rotations), 0.0, atol=1e-12)
