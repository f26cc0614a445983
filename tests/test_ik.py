"""Analytic UR inverse kinematics: round trips, branches, continuity, limits, singularities."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ftacq.kinematics import UR_MODELS, flange_pose, forward_kinematics, ur_model
from ftacq.kinematics.ik import (
    Branch, analytic_ik, branch_of, pose_error, singularity_reason, solve_ik, solve_ik_batch, solve_ik_branches,
    wrap_near,
)

ROUND_TRIP_TOLERANCE = 1e-9


def _random_regular_configuration(model, rng):
    """A random configuration away from the singularities (so the pose is reachable and well conditioned)."""
    while True:
        q = rng.uniform(-np.pi, np.pi, 6)
        if not singularity_reason(model, q):
            return q


@pytest.mark.parametrize("name", sorted(UR_MODELS))
def test_round_trip_fk_of_ik_is_the_pose(name):
    model = UR_MODELS[name]
    rng = np.random.default_rng(11)
    for _ in range(25):
        q_true = _random_regular_configuration(model, rng)
        pose = flange_pose(model, q_true)
        results = solve_ik_branches(model, pose, q_true)
        solved = {b: r for b, r in results.items() if r.ok}
        assert branch_of(model, q_true) in solved
        for branch, result in solved.items():
            position_error, rotation_error = pose_error(model, result.q_rad, pose)
            assert position_error < ROUND_TRIP_TOLERANCE and rotation_error < ROUND_TRIP_TOLERANCE
            assert branch_of(model, result.q_rad) == branch
        # the solution in the original branch, wrapped near the original, is the original configuration
        np.testing.assert_allclose(solved[branch_of(model, q_true)].q_rad, q_true, atol=1e-9)


def test_a_batch_of_poses_solves_as_each_pose_alone():
    """The planner solves a whole pose set at once: every pose, reachable or not, near a singularity or a limit,
    gets in the batch exactly the branches, solutions and reasons it gets alone (none taken from a neighbour)."""
    model = ur_model("UR5e")
    rng = np.random.default_rng(4)
    q = rng.uniform(-np.pi, np.pi, (40, 6))
    q[::5, 4] = 0.01  # near the wrist singularity
    q[1::5, 2] = 0.02  # near the elbow singularity
    poses = np.array([flange_pose(model, qi) for qi in q])
    poses[2::5, :3] *= 3.0  # out of reach
    reference = rng.uniform(-np.pi, np.pi, 6)
    batch = solve_ik_batch(model, poses, reference)
    assert len(batch) == len(poses)
    kinds = set()
    for pose, together in zip(poses, batch):
        alone = solve_ik_branches(model, pose, reference)
        assert list(together) == list(alone)
        for branch, result in alone.items():
            assert together[branch].reason == result.reason and together[branch].branch == result.branch
            if result.ok:
                np.testing.assert_array_equal(together[branch].q_rad, result.q_rad)
            kinds.add(result.reason.split(" ")[0] if result.reason else "ok")
    assert {"ok", "out", "wrist", "elbow", "joint"} <= kinds  # each outcome is in the batch


def test_eight_distinct_branches_for_a_generic_pose():
    model = ur_model("UR5e")
    pose = flange_pose(model, np.array([0.4, -1.2, 1.3, -0.9, 1.1, 0.3]))
    solutions = [q for _, q, _ in analytic_ik(model, pose)]
    assert len(solutions) == 8 and all(q is not None for q in solutions)
    for i in range(8):
        for j in range(i + 1, 8):
            assert np.max(np.abs(np.angle(np.exp(1j * (solutions[i] - solutions[j]))))) > 1e-3
    assert len({b for b, _, _ in analytic_ik(model, pose)}) == 8


def test_branch_continuity_along_a_smooth_path():
    model = ur_model("UR10e")
    q_a = np.array([1.4, -1.3, 1.6, -1.8, -1.5, 0.2])
    q_b = np.array([2.2, -1.0, 1.1, -1.2, -1.2, 2.9])
    previous = q_a
    for s in np.linspace(0.0, 1.0, 40):
        pose = flange_pose(model, (1 - s) * q_a + s * q_b)
        result = solve_ik(model, pose, previous)
        assert result.ok, result.reason
        assert result.branch == branch_of(model, q_a)
        assert np.max(np.abs(result.q_rad - previous)) < 0.2  # no jump to another branch or 2π-equivalent
        previous = result.q_rad
    np.testing.assert_allclose(previous, q_b, atol=1e-9)


def test_nearest_two_pi_equivalent_is_chosen():
    model = ur_model("UR5e")
    q = np.array([0.5, -1.2, 1.3, -1.0, 1.2, 0.4])
    shift = np.array([-2 * np.pi, 0.0, 0.0, 2 * np.pi, 0.0, -2 * np.pi])
    result = solve_ik(model, flange_pose(model, q), q + shift + 0.01)
    assert result.ok
    np.testing.assert_allclose(result.q_rad, q + shift, atol=1e-9)


def test_wrap_near_respects_limits():
    lower, upper = -np.full(6, 3 * np.pi), np.full(6, 3 * np.pi)
    wrapped = wrap_near(np.full(6, 3.0), np.full(6, 14.0), lower, upper)
    np.testing.assert_allclose(wrapped, np.full(6, 3.0 + 2 * np.pi))  # 3 + 4π would be nearer but is outside
    np.testing.assert_allclose(wrap_near(np.full(6, 3.0), np.full(6, -3.0), lower, upper), np.full(6, 3.0 - 2 * np.pi))
    assert wrap_near(np.full(6, 3.0), np.zeros(6), np.full(6, 3.5), np.full(6, 4.0)) is None


def test_joint_limit_is_reported():
    model = ur_model("UR5e")
    q = np.array([0.5, -1.2, 1.3, -1.0, 1.2, 0.4])
    tight = dataclasses.replace(model, joint_min_rad=(-1.0,) * 6, joint_max_rad=(0.45,) + (1.0,) * 5)
    result = solve_ik(tight, flange_pose(model, q), np.zeros(6), branch=branch_of(model, q))
    assert not result.ok
    assert "joint limit" in result.reason


def test_out_of_reach_is_reported():
    model = ur_model("UR5e")
    far = np.array([2.0, 0.0, 0.3, np.pi, 0.0, 0.0])
    result = solve_ik(model, far, np.array([0.0, -1.5, 1.5, -1.5, -1.5, 0.0]))
    assert not result.ok and "out of reach" in result.reason


def test_wrist_singularity_is_refused():
    model = ur_model("UR5e")
    q = np.array([0.5, -1.2, 1.3, -1.0, 0.0, 0.4])  # q5 = 0: flange z parallel to joints 2-4
    assert "wrist singularity" in singularity_reason(model, q)
    result = solve_ik(model, flange_pose(model, q), q + 0.01)
    assert not result.ok and "singularity" in result.reason


def test_branch_change_is_refused_and_named():
    model = ur_model("UR5e")
    q_prev = np.array([0.5, -1.2, 1.3, -1.0, 1.2, 0.4])
    branch = branch_of(model, q_prev)
    # the same pose solved in the branch with the other wrist sign, then asked from q_prev's branch
    flipped = Branch(branch.shoulder, branch.elbow, -branch.wrist)
    q_target = solve_ik_branches(model, flange_pose(model, q_prev), q_prev)[flipped].q_rad
    # a pose reachable in q_prev's branch only through a flip: make that branch singular at the target
    q_singular = q_prev.copy()
    q_singular[4] = 0.02
    result = solve_ik(model, flange_pose(model, q_singular), q_prev)
    assert not result.ok
    assert "singularity" in result.reason
    ok = solve_ik(model, flange_pose(model, q_target), q_prev)  # same pose in q_prev's branch: q_prev itself
    assert ok.ok and ok.branch == branch
    np.testing.assert_allclose(ok.q_rad, q_prev, atol=1e-9)
    forced = solve_ik(model, flange_pose(model, q_prev), q_target, branch=branch)
    assert forced.ok and forced.branch == branch


def test_refusal_names_a_branch_change_when_only_another_branch_reaches():
    model = ur_model("UR5e")
    q = np.array([0.5, -1.2, 1.3, -1.0, 1.2, 0.4])  # wrist branch + (sin q5 > 0)
    pose = flange_pose(model, q)
    # allow only q5 ≤ 0: q's own branch fails, the wrist-flipped branch still solves
    lower, upper = np.array(model.joint_min_rad), np.array(model.joint_max_rad)
    lower[4], upper[4] = -np.pi, 0.0
    restricted = dataclasses.replace(model, joint_min_rad=tuple(lower), joint_max_rad=tuple(upper))
    results = solve_ik_branches(restricted, pose, q)
    assert not results[branch_of(model, q)].ok
    flipped = Branch(branch_of(model, q).shoulder, branch_of(model, q).elbow, -1)
    assert results[flipped].ok
    result = solve_ik(restricted, pose, q)
    assert not result.ok and "changing branch" in result.reason and "joint limit" in result.reason


def test_transform_input_equals_pose_input():
    model = ur_model("UR3e")
    q = np.array([-0.7, -1.9, 1.1, 0.3, 0.8, -2.0])
    a = solve_ik(model, forward_kinematics(model, q), q)
    b = solve_ik(model, flange_pose(model, q), q)
    np.testing.assert_allclose(a.q_rad, b.q_rad, atol=1e-12)
