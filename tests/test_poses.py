"""Pose sets A (cube rotations), E and V (random in a cone), explicit poses."""

from __future__ import annotations

import numpy as np
import pytest

from ftacq.mounts import MOUNT_TABLE, MOUNTS
from ftacq.so3 import angle_between_deg, cube_rotations, rotation_from_rotvec
from procedures.poses import explicit_poses, random_cone_poses, special_poses, tool_down_rotation

CENTER = np.array([-0.25, -0.37, 0.37])


def test_special_poses_are_the_cube_rotations_in_paper_order():
    poses = special_poses(CENTER)
    assert len(poses) == 24
    assert poses.labels[0] == "A01" and poses.labels[-1] == "A24"
    assert set(poses.set_names) == {"A"}
    flange_R_base = np.swapaxes(rotation_from_rotvec(poses.poses[:, 3:]), -1, -2)
    np.testing.assert_allclose(flange_R_base, cube_rotations(), atol=1e-12)
    np.testing.assert_allclose(poses.poses[:, :3], np.tile(CENTER, (24, 1)))


def test_special_poses_pivot_keeps_a_point_on_the_tool_fixed():
    poses = special_poses(CENTER, pivot_offset_m=0.05)
    base_R_flange = rotation_from_rotvec(poses.poses[:, 3:])
    pivot = poses.poses[:, :3] + 0.05 * base_R_flange[:, :, 2]
    np.testing.assert_allclose(pivot, np.tile(CENTER, (24, 1)), atol=1e-12)


@pytest.mark.parametrize("mount", MOUNTS)
def test_mount_gravity_direction_agrees_with_its_tilt(mount):
    # gravity_base = −m g [cos α sin β, −sin α, cos α cos β] (the model's tilt convention)
    alpha, beta = np.radians(MOUNT_TABLE[mount].tilt_deg)
    from_tilt = -np.array([np.cos(alpha) * np.sin(beta), -np.sin(alpha), np.cos(alpha) * np.cos(beta)])
    np.testing.assert_allclose(MOUNT_TABLE[mount].down_base, from_tilt, atol=1e-12)


@pytest.mark.parametrize("mount", MOUNTS)
def test_tool_down_points_along_gravity(mount):
    rotation = tool_down_rotation(mount)
    np.testing.assert_allclose(rotation[:, 2], MOUNT_TABLE[mount].down_base)
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)


@pytest.mark.parametrize("half_angle", [10.0, 40.0, 75.0])
def test_cone_poses_stay_in_the_cone_and_fill_it(half_angle):
    poses = random_cone_poses(400, half_angle, center_m=CENTER, seed=3)
    axes = rotation_from_rotvec(poses.poses[:, 3:])[:, :, 2]
    angle = np.degrees(np.arccos(np.clip(axes @ np.array([0.0, 0.0, -1.0]), -1, 1)))
    assert angle.max() <= half_angle + 1e-9
    assert angle.max() > 0.9 * half_angle  # reaches the rim
    # uniform over the cap's solid angle: the median tilt is where the cap area halves
    median_expected = np.degrees(np.arccos((1 + np.cos(np.radians(half_angle))) / 2))
    assert np.median(angle) == pytest.approx(median_expected, rel=0.1)
    np.testing.assert_allclose(poses.poses[:, :3], np.tile(CENTER, (400, 1)))


def test_cone_about_a_given_nominal():
    nominal = rotation_from_rotvec(np.array([0.3, -0.2, 1.0]))
    poses = random_cone_poses(50, 20.0, nominal_base_R_flange=nominal, seed=1)
    angle = angle_between_deg(rotation_from_rotvec(poses.poses[:, 3:]), nominal)
    assert angle.max() <= 20.0 + 1e-9


def test_seed_reproducible_and_e_v_differ():
    e1 = random_cone_poses(24, seed=5, set_name="E")
    e2 = random_cone_poses(24, seed=5, set_name="E")
    v = random_cone_poses(24, seed=5, set_name="V")
    e_other = random_cone_poses(24, seed=6, set_name="E")
    np.testing.assert_array_equal(e1.poses, e2.poses)
    assert not np.allclose(e1.poses, v.poses)
    assert not np.allclose(e1.poses, e_other.poses)
    assert v.labels[0] == "V01" and set(v.set_names) == {"V"}


def test_position_jitter_bounds():
    poses = random_cone_poses(200, center_m=CENTER, position_jitter_m=0.03, seed=2)
    offset = poses.poses[:, :3] - CENTER
    assert np.abs(offset).max() <= 0.03
    assert np.abs(offset).max() > 0.02


def test_explicit_poses_and_bad_input():
    data = np.array([[0.1, -0.4, 0.4, np.pi, 0, 0], [0.0, -0.4, 0.5, 0, np.pi, 0]])
    poses = explicit_poses(data)
    assert poses.labels == ("X01", "X02") and poses.set_names == ("E", "E")
    with pytest.raises(ValueError, match="row 2, column ry"):
        explicit_poses(np.array([[0, 0, 0, 0, 0, 0], [0, 0, 0, 0, np.nan, 0]]))
    with pytest.raises(ValueError, match=r"\(N, 6\)"):
        explicit_poses(np.zeros((3, 5)))


def test_concatenation_keeps_labels_and_sets():
    both = special_poses(CENTER) + random_cone_poses(3, seed=0, set_name="V")
    assert len(both) == 27 and both.labels[24] == "V01" and both.set_names[-1] == "V"
