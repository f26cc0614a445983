"""Capsule collision model: distances, table/wall/ceiling, self collision, tool, and checks along a move."""

from __future__ import annotations

import numpy as np
import pytest

from ftacq.kinematics import dh_transforms, ur_model
from procedures.collision import CollisionChecker, segment_distances
from ftacq.kinematics.ik import solve_ik_branches
from procedures.poses import special_poses

HOME = np.array([np.pi / 2, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])


def _brute_force_distance(p0, p1, q0, q1, n=201):
    s = np.linspace(0.0, 1.0, n)
    a = p0 + s[:, None] * (p1 - p0)
    b = q0 + s[:, None] * (q1 - q0)
    return np.min(np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1))


def test_segment_distance_matches_brute_force():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-1, 1, (80, 4, 3))
    pts[:20, 1] = pts[:20, 0]  # degenerate segments (points)
    pts[20:40, 3] = pts[20:40, 2] + 0.5 * (pts[20:40, 1] - pts[20:40, 0])  # parallel segments
    dist = segment_distances(pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3])
    for k in range(len(pts)):
        assert dist[k] <= _brute_force_distance(*pts[k]) + 1e-12
        assert dist[k] == pytest.approx(_brute_force_distance(*pts[k]), abs=1e-2)


@pytest.fixture(scope="module")
def floor():
    return CollisionChecker(ur_model("UR5e"), tool_radius_m=0.045, tool_length_m=0.1, mount="floor",
                            table_margin_m=0.02)


def test_home_is_clear(floor):
    assert floor.problems_at(HOME) == []


def test_segments_follow_the_dh_frames(floor):
    q = np.array([0.3, -1.0, 1.2, -0.5, 0.8, 0.1])
    seg = floor.segments(q)
    frames = dh_transforms(floor.model, q)
    np.testing.assert_allclose(seg[5, 1], frames[5, :3, 3], atol=1e-12)
    np.testing.assert_allclose(seg[6, 1], frames[5, :3, 3] + 0.1 * frames[5, :3, 2], atol=1e-12)


def test_tool_into_table(floor):
    q = HOME.copy()
    q[1] = -0.9  # shoulder down: the flange ends 0.11 m above the table, the 0.1 m tool 0.01 m above it
    problems = floor.problems_at(q)
    assert problems == ["tool 5 mm from the table (needs 20 mm)"]


def test_shorter_tool_clears_the_table():
    checker = CollisionChecker(ur_model("UR5e"), 0.045, 0.05, "floor", 0.02)
    q = HOME.copy()
    q[1] = -0.9
    assert checker.problems_at(q) == []


def test_elbow_into_table(floor):
    q = np.array([np.pi / 2, 0.4, -2.2, -1.0, -1.5, 0.0])  # upper arm points down, wrist back up
    problems = floor.problems_at(q)
    assert any(p.startswith("upper arm") and "table" in p for p in problems)
    assert not any(p.startswith(("tool", "wrist")) for p in problems)


def test_wall_mount_wall():
    wall = CollisionChecker(ur_model("UR5e"), 0.045, 0.1, "wall", 0.02)
    q = HOME.copy()
    q[1] = -0.5
    problems = wall.problems_at(q)
    assert any("tool" in p and "from the wall" in p for p in problems)
    ceiling = CollisionChecker(ur_model("UR5e"), 0.045, 0.1, "ceiling", 0.02)
    assert any("from the ceiling" in p for p in ceiling.problems_at(q))
    assert wall.problems_at(HOME) == []


def test_self_collision_folded_elbow(floor):
    q = HOME.copy()
    q[2] = 2.9  # forearm folded back onto the upper arm and base
    problems = floor.problems_at(q)
    assert any("hits base" in p for p in problems)
    assert any("wrist 1 hits upper arm" in p for p in problems)


def test_tool_into_forearm():
    checker = CollisionChecker(ur_model("UR5e"), 0.045, 0.1, "floor", 0.02)
    q = np.array([2.8, -0.9, -0.4, -1.3, 3.0, -0.8])  # flange turned back towards the forearm
    assert any(p.startswith("tool hits forearm") for p in checker.problems_at(q))
    short = CollisionChecker(ur_model("UR5e"), 0.02, 0.02, "floor", 0.02)
    assert not any(p.startswith("tool hits") for p in short.problems_at(q))


def test_tool_up_pose_is_allowed_with_a_short_tool(floor):
    center = np.array([-0.245, -0.368, 0.368])
    tool_up = special_poses(center).poses[0]  # A01: flange_R_base = I, the tool points up
    q = solve_ik_branches(floor.model, tool_up, HOME)
    clear = [r.q_rad for r in q.values() if r.ok and not floor.problems_at(r.q_rad)]
    assert clear, "a 0.1 m tool pointing up must be allowed"


def test_move_through_the_table_is_caught_between_clear_ends(floor):
    a = HOME.copy()
    b = HOME.copy()
    a[1], b[1] = -1.2, -1.2
    a[0], b[0] = np.pi / 2, np.pi / 2
    # both ends clear, but the straight joint move swings the tool down through the table
    a[3], b[3] = -1.5, -1.5
    b[2] = 0.2
    mid = 0.5 * (a + b)
    mid_problems = floor.problems_at(mid)
    assert floor.problems_at(a) == [] and floor.problems_at(b) == [] or mid_problems
    q_from = HOME.copy()
    q_to = HOME.copy()
    q_to[0] = HOME[0] + 0.5
    assert floor.problems_along(q_from, q_to) == []  # a base rotation at home is clear
    down = HOME.copy()
    down[1] = -0.5  # reached only through the table
    along = floor.problems_along(HOME, down)
    assert along and "% of the move" in along[0]


def test_path_samples_bound_the_displacement(floor):
    q_from, q_to = HOME, HOME + np.array([1.0, -0.3, 0.4, 0.8, -0.5, 2.0])
    samples = floor.path_samples(q_from, q_to, max_displacement_m=0.01)
    np.testing.assert_array_equal(samples[0], q_from)
    np.testing.assert_allclose(samples[-1], q_to)
    seg = floor.segments(samples)
    moved = np.linalg.norm(np.diff(seg, axis=0), axis=-1).max()  # any segment end, between samples
    assert moved <= 0.01
    assert len(samples) <= 1 + np.ceil(floor.displacement_bound_m(q_from, q_to) / 0.01)


def test_batched_segments_equal_pinocchio_segments(floor):
    q = np.random.default_rng(2).uniform(-3, 3, (20, 6))
    batch = floor.segments(q)
    for k in range(len(q)):
        np.testing.assert_allclose(batch[k], floor.segments(q[k]), atol=1e-12)


def test_path_check_is_a_bound_between_samples(floor):
    """A move that grazes the table between coarse samples is still caught."""
    q_from, q_to = HOME.copy(), HOME.copy()
    q_from[1], q_to[1] = -1.2, -1.2
    q_from[0], q_to[0] = 0.5, 2.6
    q_mid = 0.5 * (q_from + q_to)
    # lower the shoulder until the tool at mid-move just touches the margin, ends stay clear
    for q2 in np.linspace(-1.2, -0.8, 81):
        q_from[1] = q_to[1] = q_mid[1] = q2
        if floor.problems_at(q_mid):
            break
    assert floor.problems_along(q_from, q_to)


def test_joint_limit_along_a_move(floor):
    q_to = HOME.copy()
    q_to[2] = 3.3  # elbow limit is ±π
    problems = floor.problems_along(HOME, q_to)
    assert any("joint limit" in p and "q3" in p for p in problems)


def test_unknown_mount_is_refused():
    with pytest.raises(ValueError, match="mount"):
        CollisionChecker(ur_model("UR5e"), mount="desk")
