"""Joint limits in planning and execution: planned targets keep a margin, measured angles may jitter past a limit.

A run on an arm whose encoders jitter by ~1e-6 rad used to die at its last pose: winding the wrist by shortest
moves put targets exactly on ±360°, and the executor's re-check of the measured start of the next move allowed
1e-9 rad. Issue 26, item 1.
"""

from __future__ import annotations

import numpy as np
import pytest

from ftacq.kinematics import (
    JOINT_LIMIT_MARGIN_RAD,
    MEASURED_ANGLE_TOLERANCE_RAD,
    forward_kinematics,
    planning_limits_rad,
    ur_model,
)
from procedures.plan import PlanSettings, check_path, collision_checker, format_plan, home_configuration_rad, make_plan
from procedures.tour import MoveGraph

HOME = home_configuration_rad()
SIMULATOR_START = np.array([0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])
ENCODER_JITTER_RAD = 1e-6
"""The reported angles' noise at rest on a real UR5e (1σ), as the simulated controller's default."""


def _all_targets(plan) -> np.ndarray:
    return np.vstack([plan.joint_targets_rad, np.asarray(plan.revisit_target_rad)[None, :]])


@pytest.mark.parametrize("start", [HOME, SIMULATOR_START], ids=["home", "simulator-start"])
def test_every_planned_target_keeps_the_margin_from_each_limit(start):
    plan = make_plan(PlanSettings(), start)
    lower, upper = planning_limits_rad(plan.settings.ur)
    targets = _all_targets(plan)
    assert np.all(targets >= lower) and np.all(targets <= upper), (
        f"closest to a limit: {np.degrees(np.min(np.minimum(targets - lower, upper - targets))):.6f} deg "
        "inside the margin")
    assert len(plan) == 60 and plan.rejected == ()


@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["+360", "-360"])
def test_a_target_winding_onto_a_limit_goes_to_the_middle_equivalent(sign):
    """From q6 = ±315°, the shortest move to a pose whose q6 is 0 lands exactly on ±360°: the planner takes 0°."""
    settings = PlanSettings()
    model = settings.ur
    start = HOME.copy()
    start[5] = sign * 1.75 * np.pi
    graph = MoveGraph(collision_checker(settings, planning=True), model, start, HOME[None, :])
    np.testing.assert_allclose((start + graph.move(0, 1))[5], sign * 2.0 * np.pi)  # where winding would go
    targets, failed = graph.sequence([0, 1])
    assert failed == []
    np.testing.assert_allclose(targets[0], HOME, atol=1e-12)  # q6 = 0°, the middle of [-360°, 360°]
    np.testing.assert_allclose(forward_kinematics(model, targets[0]), forward_kinematics(model, HOME), atol=1e-12)
    assert check_path(settings, start, targets[0]) == []


def test_a_measured_angle_jittered_past_a_limit_is_accepted():
    settings = PlanSettings()
    for sign in (1.0, -1.0):
        at_limit = HOME.copy()
        at_limit[5] = sign * (2.0 * np.pi + 5 * ENCODER_JITTER_RAD)  # 5σ of jitter beyond the limit
        assert check_path(settings, at_limit, HOME) == []
        assert collision_checker(settings).problems_at(at_limit, measured=True) == []


def test_an_angle_truly_beyond_a_limit_and_a_target_inside_the_margin_are_refused():
    settings = PlanSettings()
    beyond = HOME.copy()
    beyond[5] = 2.0 * np.pi + 10 * MEASURED_ANGLE_TOLERANCE_RAD
    problems = check_path(settings, beyond, HOME)
    assert len(problems) == 1 and problems[0].startswith("joint limit: q6") and "at 0 % of the move" in problems[0]
    near = HOME.copy()
    near[5] = 2.0 * np.pi - JOINT_LIMIT_MARGIN_RAD / 2  # inside the limits but within the margin
    problems = check_path(settings, HOME, near)
    assert len(problems) == 1 and "planning margin" in problems[0] and "at 100 % of the move" in problems[0]
    assert collision_checker(settings).problems_at(near) != []


def test_a_plan_starts_from_a_measured_configuration_jittered_past_a_limit():
    start = HOME.copy()
    start[5] = -2.0 * np.pi - 5 * ENCODER_JITTER_RAD
    plan = make_plan(PlanSettings(random_count=4, validation_count=2), start)
    lower, upper = planning_limits_rad(ur_model("UR5e"))
    targets = _all_targets(plan)
    assert np.all(targets >= lower) and np.all(targets <= upper)
    assert check_path(plan.settings, start, plan.joint_targets_rad[0]) == []


def test_the_plan_summary_states_the_margin():
    plan = make_plan(PlanSettings(random_count=4, validation_count=2), HOME)
    assert f"every target at least {np.degrees(JOINT_LIMIT_MARGIN_RAD):.0f}° inside each joint limit" in format_plan(plan)
