"""The paper's numerical experiment (Sec. IV-A, Table I): identify from the 24 special rotations without
noise, compensate 200 random orientations carrying a contact wrench; every error ≤ 1e-9."""

import numpy as np
import pytest

from ftacq.calibration import Calibration
from ftacq.identification import identify
from ftacq.identification.srom import srom_gravity_base
from ftacq.so3 import cube_rotations, rotation_zyx_deg
from ftacq.posefile import PoseRecord
from tests.fakes.pose_records import poses_from_orientations, random_orientations

TOLERANCE = 1e-9

# Table I: eR as Z-Y-X angles (deg), F_b (N), sP (m), sF0 (N), sT0 (N·m)
TABLE_I = [
    ((0, 7, 3), (0, 0, -10), (0, 0, 2), (0, 0, 0), (0, 0, 0)),
    ((0, 7, 3), (0, 0, -10), (0, 0, 2), (0, 0, 0), (87, 45, 6)),
    ((0, 7, 3), (0, 0, -10), (0, 0, 2), (63, 5, 21), (87, 45, 6)),
    ((0, 7, 3), (0, 0, -10), (0.1, 0.1, 1), (63, 5, 21), (87, 45, 6)),
    ((45, 7, 3), (1, 3, -40), (0.1, 0.1, 1), (63, 5, 21), (87, 45, 6)),
    ((70, 15, 13), (1, 3, -40), (0.1, 0.1, 1), (63, 5, 21), (87, 45, 6)),
]
CONTACT_FORCE_N = 1.0
CONTACT_TORQUE_NM = 0.5


def truth_of(setup) -> Calibration:
    angles, gravity, com, force_bias, torque_bias = setup
    return Calibration(
        sensor_rotation=rotation_zyx_deg(*angles),
        force_bias=force_bias,
        torque_bias=torque_bias,
        gravity_base=gravity,
        center_of_mass=com,
    )


def paper_p_formulas(forces: np.ndarray) -> np.ndarray:
    """Eqs 17-23 exactly as printed (1-based pose numbers), for comparison with the order-free form."""
    f = {i + 1: forces[i] for i in range(24)}

    def p(plus, minus):
        return (sum(f[i] for i in plus) - sum(f[i] for i in minus)) / 8.0

    p11, p12, p13 = p([1, 2, 3, 4], [5, 6, 7, 8]), p([9, 10, 11, 12], [13, 14, 15, 16]), p([17, 18, 19, 20], [21, 22, 23, 24])
    p21, p22, p23 = p([9, 13, 17, 21], [10, 14, 18, 22]), p([1, 5, 19, 23], [2, 6, 20, 24]), p([3, 7, 11, 15], [4, 8, 12, 16])
    p31, p32, p33 = p([11, 16, 20, 23], [12, 15, 19, 24]), p([4, 7, 17, 22], [3, 8, 18, 21]), p([1, 6, 10, 13], [2, 5, 9, 14])
    return np.cbrt([np.linalg.det(np.column_stack(c)) for c in ((p11, p12, p13), (p21, p22, p23), (p31, p32, p33))])


def special_record(truth: Calibration) -> PoseRecord:
    rotations = cube_rotations()
    poses = poses_from_orientations(rotations)
    as_read = PoseRecord(pose=poses, wrench=np.zeros((24, 6))).flange_R_base  # through the rotation vectors
    return PoseRecord(pose=poses, wrench=truth.predict(as_read))


@pytest.mark.parametrize("setup_number", range(1, 7))
@pytest.mark.parametrize("refine", [False, True], ids=["closed-form", "refined"])
def test_table_one_setup_identification_and_compensation(setup_number, refine):
    truth = truth_of(TABLE_I[setup_number - 1])
    record = special_record(truth)
    result = identify(record, refine=refine)
    assert result.method_used.startswith("srom")
    estimate = result.calibration
    for name in ("sensor_rotation", "force_bias", "torque_bias", "gravity_base", "center_of_mass"):
        error = np.linalg.norm(getattr(estimate, name) - getattr(truth, name))
        assert error <= TOLERANCE * max(1.0, np.linalg.norm(getattr(truth, name))), (name, error)
    assert abs(estimate.mass_kg - truth.mass_kg) <= TOLERANCE
    # 200 random orientations with a contact wrench of 1 N and 0.5 N·m in random directions
    rng = np.random.default_rng(setup_number)
    rotations = random_orientations(200, seed=100 + setup_number)
    directions = rng.normal(size=(200, 2, 3))
    directions /= np.linalg.norm(directions, axis=2, keepdims=True)
    contact = np.hstack([CONTACT_FORCE_N * directions[:, 0], CONTACT_TORQUE_NM * directions[:, 1]])
    readings = truth.predict(rotations) + contact
    compensated = estimate.compensate(readings, rotations)
    assert np.max(np.linalg.norm(compensated[:, :3] - contact[:, :3], axis=1)) <= TOLERANCE
    assert np.max(np.linalg.norm(compensated[:, 3:] - contact[:, 3:], axis=1)) <= TOLERANCE
    single = np.array([estimate.compensate_sample(readings[k], rotations[k]) for k in range(5)])
    np.testing.assert_allclose(single, contact[:5], atol=TOLERANCE)


@pytest.mark.parametrize("setup_number", range(1, 7))
def test_order_free_srom_equals_the_printed_p_formulas(setup_number):
    truth = truth_of(TABLE_I[setup_number - 1])
    rotations = cube_rotations()
    forces = truth.predict(rotations)[:, :3]
    order_free = srom_gravity_base(rotations, forces, np.arange(24))
    np.testing.assert_allclose(order_free, paper_p_formulas(forces), atol=1e-12)
    np.testing.assert_allclose(order_free, truth.gravity_base, atol=1e-12)
