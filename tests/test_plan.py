"""The plan: feasibility of the defaults, ordering, travel, duration, JSON, formatting, errors."""

from __future__ import annotations

import numpy as np
import pytest

from ftacq.errors import ConfigError, PlanError
from ftacq.kinematics import UR_MODELS, forward_kinematics, ur_model
from ftacq.mounts import MOUNTS
from ftacq.so3 import rotation_from_rotvec
from ftacq.kinematics.ik import branch_of
from ftacq.kinematics.trapezoid import trapezoid_duration_s
from procedures.plan import (
    Plan, PlanSettings, check_path, default_center_m, format_plan, home_configuration_rad, make_plan,
)
from procedures.tour import nearest_neighbour_order, two_opt

HOME = home_configuration_rad()
POSE_TOLERANCE = 1e-9
TRAVEL_GOAL = 0.7  # chosen order at least 30 % shorter than the listing order


@pytest.fixture(scope="module")
def default_plan() -> Plan:
    return make_plan(PlanSettings(), HOME)


def _assert_plan_consistent(plan: Plan) -> None:
    model = plan.settings.ur
    for pose, q in zip(plan.poses, plan.joint_targets_rad):
        t = forward_kinematics(model, q)
        np.testing.assert_allclose(t[:3, 3], pose[:3], atol=POSE_TOLERANCE)
        np.testing.assert_allclose(t[:3, :3], rotation_from_rotvec(pose[3:]), atol=POSE_TOLERANCE)
    assert np.all(plan.joint_targets_rad >= np.array(model.joint_min_rad))
    assert np.all(plan.joint_targets_rad <= np.array(model.joint_max_rad))
    assert len({branch_of(model, q) for q in plan.joint_targets_rad}) == 1  # no flips between poses
    assert len(set(plan.labels)) == len(plan.labels)


def test_default_plan_is_feasible(default_plan):
    plan = default_plan
    assert plan.rejected == ()
    assert len(plan) == 60 and plan.srom_ready
    assert len(plan.indices("A")) == 24 and len(plan.indices("E")) == 24 and len(plan.indices("V")) == 12
    np.testing.assert_allclose(plan.center_m, default_center_m("UR5e", "floor"))
    _assert_plan_consistent(plan)


def test_default_plan_moves_are_clear(default_plan):
    plan = default_plan
    targets = np.vstack([HOME[None, :], plan.joint_targets_rad])
    for q_from, q_to in zip(targets[:-1], targets[1:]):
        assert check_path(plan.settings, q_from, q_to) == []
    assert plan.warnings == ()


def test_drift_revisit_target_is_the_first_pose_and_clear(default_plan):
    plan = default_plan
    revisit = np.array(plan.revisit_target_rad)
    model = plan.settings.ur
    np.testing.assert_allclose(forward_kinematics(model, revisit), forward_kinematics(model, plan.joint_targets_rad[0]),
                               atol=POSE_TOLERANCE)
    assert check_path(plan.settings, plan.joint_targets_rad[-1], revisit) == []
    assert make_plan(PlanSettings(drift_check=False), HOME).revisit_target_rad is None


@pytest.mark.parametrize("model, mount", [("UR30", "wall"), ("UR5", "ceiling")])
def test_drift_revisit_is_made_clear(model, mount):
    plan = make_plan(PlanSettings(model=model, mount=mount), HOME)
    assert not any("revisit" in w for w in plan.warnings)
    assert check_path(plan.settings, plan.joint_targets_rad[-1], np.array(plan.revisit_target_rad)) == []


def test_order_is_shorter_than_listing(default_plan):
    assert default_plan.joint_travel_rad < TRAVEL_GOAL * default_plan.listing_travel_rad


def test_duration_estimate_is_consistent(default_plan):
    s = default_plan.settings
    n = len(default_plan)
    per_pose = s.settle_time_s + s.average_time_s
    assert default_plan.estimated_duration_s > (n + 1) * per_pose
    assert default_plan.estimated_duration_s < 300.0  # goal: a default A+E+V run within 5 min
    slower = make_plan(PlanSettings(joint_speed_rad_s=0.25), HOME)
    assert slower.estimated_duration_s > default_plan.estimated_duration_s


def test_trapezoid_profile():
    assert trapezoid_duration_s(0.0, 1.0, 2.0) == 0.0
    assert trapezoid_duration_s(2.0, 1.0, 2.0) == pytest.approx(2.0 / 1.0 + 1.0 / 2.0)  # cruise phase
    assert trapezoid_duration_s(0.2, 1.0, 2.0) == pytest.approx(2 * np.sqrt(0.2 / 2.0))  # triangular


def test_two_opt_untangles_a_line():
    rng = np.random.default_rng(0)
    x = np.concatenate([[0.0], rng.permutation(np.arange(1.0, 30.0))])
    dist = np.abs(x[:, None] - x[None, :])
    order = two_opt(nearest_neighbour_order(dist), dist)
    assert order[0] == 0
    assert np.all(np.diff(x[order]) == 1.0)


def test_json_round_trip(default_plan):
    again = Plan.from_json(default_plan.to_json())
    assert again.labels == default_plan.labels and again.set_names == default_plan.set_names
    np.testing.assert_array_equal(again.poses, default_plan.poses)
    np.testing.assert_array_equal(again.joint_targets_rad, default_plan.joint_targets_rad)
    assert again.settings == default_plan.settings
    assert again.estimated_duration_s == default_plan.estimated_duration_s
    assert again.center_m == default_plan.center_m and again.branch == default_plan.branch
    assert again.revisit_target_rad == default_plan.revisit_target_rad and again.warnings == default_plan.warnings


def test_json_errors_are_plan_errors(default_plan):
    with pytest.raises(PlanError, match="invalid"):
        Plan.from_json("not json")
    with pytest.raises(PlanError, match="invalid"):
        Plan.from_json('{"format_version": 1}')
    text = default_plan.to_json().replace('"format_version": 1', '"format_version": 99')
    with pytest.raises(PlanError, match="format_version"):
        Plan.from_json(text)


def test_format_plan(default_plan):
    text = format_plan(default_plan)
    for expected in ("UR5e", "A 24/24", "E 24/24", "V 12/12", "SROM closed form: available", "% shorter",
                     "0.50 rad/s", "1.00 rad/s²", "estimated duration", "A01"):
        assert expected in text


def test_impossible_centre_raises_with_reasons():
    with pytest.raises(PlanError) as info:
        make_plan(PlanSettings(center_m=(2.0, 0.0, 0.3)), HOME)
    message = str(info.value)
    assert "only 0 identification poses" in message
    assert "A01: out of reach" in message and "V12: out of reach" in message


def test_some_special_poses_lost_blocks_srom_only_when_required():
    centre = (0.0, -0.45, 0.45)  # the tool along −x is parallel to the shoulder axis: wrist singular
    plan = make_plan(PlanSettings(center_m=centre), HOME)
    lost = [label for label, _ in plan.rejected]
    assert lost and all(label.startswith("A") for label in lost)
    assert not plan.srom_ready and "not available" in format_plan(plan)
    assert all("singularity" in reason for _, reason in plan.rejected)
    with pytest.raises(PlanError, match="SROM needs all 24"):
        make_plan(PlanSettings(center_m=centre, require_srom=True), HOME)


def test_explicit_poses_join_the_identification_set():
    q = np.array([np.pi / 2, -1.4, 1.6, -1.8, -1.5, 0.3])
    model = ur_model("UR5e")
    t = forward_kinematics(model, q)
    from ftacq.so3 import rotvec_from_rotation
    pose = np.concatenate([t[:3, 3], rotvec_from_rotation(t[:3, :3])])
    plan = make_plan(PlanSettings(random_count=0, explicit_poses=[pose.tolist()]), HOME)
    i = plan.labels.index("X01")
    assert plan.set_names[i] == "E"
    np.testing.assert_allclose(plan.poses[i], pose)


def test_path_into_the_table_is_reported():
    down = HOME.copy()
    down[1] = -0.5
    problems = check_path(PlanSettings(), HOME, down)
    assert problems and any("table" in p for p in problems)
    assert check_path(PlanSettings(), HOME, HOME) == []
    assert check_path(PlanSettings(), HOME, np.full(6, np.nan)) == ["joint values are not finite"]


@pytest.mark.parametrize("model", sorted(set(UR_MODELS) - {"UR5e"}))
def test_every_model_plans_all_special_poses_on_a_floor(model):
    # the CB3 arms' wrists are short for the default 0.05 × 0.1 m tool: the UR3's (d5, d6 ≈ 0.08 m) in every pose,
    # the UR5's forearm passes 7 mm inside a 0.05 m tool at 4 special orientations from every centre tried
    tool = {"UR3": {"tool_radius_m": 0.035, "tool_length_m": 0.08}, "UR5": {"tool_radius_m": 0.045}}.get(model, {})
    plan = make_plan(PlanSettings(model=model, **tool), HOME)
    assert plan.srom_ready and len(plan) >= 56
    assert plan.joint_travel_rad < TRAVEL_GOAL * plan.listing_travel_rad
    _assert_plan_consistent(plan)


def test_every_mount_has_a_default_centre():
    for mount in MOUNTS:
        assert np.all(np.isfinite(default_center_m("UR5e", mount)))


@pytest.mark.parametrize("mount", ["wall", "ceiling"])
def test_wall_and_ceiling_mounts(mount):
    plan = make_plan(PlanSettings(mount=mount), HOME)
    assert plan.srom_ready and plan.rejected == ()
    _assert_plan_consistent(plan)
    # E poses point their tool along gravity for the mount, within the cone
    down = {"wall": np.array([-1.0, 0.0, 0.0]), "ceiling": np.array([0.0, 0.0, 1.0])}[mount]
    axes = rotation_from_rotvec(plan.poses[plan.indices("E"), 3:])[:, :, 2]
    assert np.degrees(np.arccos(np.clip(axes @ down, -1, 1))).max() <= 40.0 + 1e-9


@pytest.mark.parametrize("kwargs, key", [
    ({"joint_speed_rad_s": 4.0}, "robot.joint_speed_rad_s"),
    ({"joint_acceleration_rad_s2": 0.0}, "robot.joint_acceleration_rad_s2"),
    ({"model": "UR7"}, "robot.model"),
    ({"mount": "desk"}, "robot.mount"),
    ({"cone_half_angle_deg": 120.0}, "poses.cone_half_angle_deg"),
    ({"random_count": -1}, "poses.random_count"),
    ({"center_m": (0.1, 0.2)}, "poses.center_m"),
    ({"explicit_poses": [[0, 0, 0, 0, float("nan"), 0]]}, "poses.explicit"),
    ({"special": False, "random_count": 0}, "no identification poses"),
])
def test_bad_settings_name_the_key(kwargs, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        PlanSettings(**kwargs)


def test_settings_dict_round_trip():
    settings = PlanSettings(center_m=(0.1, -0.4, 0.4), explicit_poses=[[0.1, -0.4, 0.4, 3.14, 0, 0]])
    assert PlanSettings.from_dict(settings.to_dict()) == settings
    with pytest.raises(ConfigError, match="unknown key"):
        PlanSettings.from_dict({**settings.to_dict(), "colour": "red"})


def test_start_outside_limits_is_refused():
    with pytest.raises(PlanError, match="joint limits"):
        make_plan(PlanSettings(), np.array([0.0, 0.0, 4.0, 0.0, 0.0, 0.0]))


def test_start_in_collision_is_refused_with_advice():
    with pytest.raises(PlanError, match="jog it clear"):
        make_plan(PlanSettings(), np.zeros(6))  # arm stretched along the table, the flange 6 cm above it


def test_plan_from_another_branch_start_still_plans():
    start = np.array([np.pi / 2, -1.2, -1.6, -1.9, 1.5, 0.0])  # elbow and wrist in the other branches
    plan = make_plan(PlanSettings(), start)
    assert len(plan) == 60
    assert check_path(plan.settings, start, plan.joint_targets_rad[0]) == []
