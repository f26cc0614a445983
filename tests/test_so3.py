"""Rotation helpers against Pinocchio's SO(3) maps and the cube-group identities of method.md."""

import numpy as np
import pinocchio as pin
import pytest

from ftacq.so3 import (angle_between_deg, cube_rotations, rotation_from_rotvec, rotation_of_rotvec, rotation_zyx_deg,
                       rotvec_from_rotation)


def test_rotvec_round_trip_matches_pinocchio():
    rng = np.random.default_rng(1)
    rotvecs = rng.normal(size=(200, 3))
    rotvecs *= (rng.uniform(0, np.pi, 200) / np.linalg.norm(rotvecs, axis=1))[:, None]
    matrices = rotation_from_rotvec(rotvecs)
    for rotvec, matrix in zip(rotvecs, matrices):
        np.testing.assert_allclose(matrix, pin.exp3(rotvec), atol=1e-12)
    np.testing.assert_allclose(rotvec_from_rotation(matrices), rotvecs, atol=1e-9)


@pytest.mark.parametrize("angle", [0.0, 1e-10, 1e-5, np.pi - 1e-6, np.pi])
def test_rotvec_edge_angles(angle):
    axis = np.array([0.48, -0.6, 0.64])
    matrix = pin.exp3(axis * angle)
    back = rotation_from_rotvec(rotvec_from_rotation(matrix))
    np.testing.assert_allclose(back, matrix, atol=1e-9)


@pytest.mark.parametrize("angle", [0.0, 1e-10, 1e-5, 1.0, np.pi - 1e-6, np.pi])
def test_one_rotation_is_the_batched_one(angle):
    rotvec = np.array([0.48, -0.6, 0.64]) * angle
    np.testing.assert_allclose(rotation_of_rotvec(rotvec), rotation_from_rotvec(rotvec), rtol=0, atol=1e-15)
    np.testing.assert_allclose(rotation_of_rotvec(list(rotvec)), rotation_from_rotvec(rotvec), rtol=0, atol=1e-15)


def test_cube_group_identities_used_by_srom():
    rotations = cube_rotations()
    assert rotations.shape == (24, 3, 3)
    np.testing.assert_allclose(np.linalg.det(rotations), 1.0)
    np.testing.assert_allclose(rotations.sum(axis=0), 0.0, atol=1e-15)
    second_moment = np.einsum("iab,icd->abcd", rotations, rotations) / 8.0
    np.testing.assert_allclose(second_moment, np.einsum("ac,bd->abcd", np.eye(3), np.eye(3)))
    # all distinct, first columns in the paper's block order
    assert len({tuple(r.ravel()) for r in rotations}) == 24
    firsts = rotations[::4, :, 0]
    np.testing.assert_array_equal(firsts, [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])


def test_zyx_euler_and_angle_between():
    yaw = rotation_zyx_deg(90.0, 0.0, 0.0)
    np.testing.assert_allclose(yaw @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    assert angle_between_deg(np.eye(3), rotation_zyx_deg(10.0, 0.0, 0.0)) == pytest.approx(10.0)
