"""The bridge's feed convention (ftacq/bridge_convention.py): sensor-frame wrench → what the controller expects,
checked against the documented controller behaviour for random tools, mountings and poses."""

from __future__ import annotations

import numpy as np
import pytest

from ftacq import STANDARD_GRAVITY_M_S2
from ftacq.bridge_convention import (
    ENABLE_EXTERNAL_FT_SENSOR,
    FT_RTDE_INPUT_ENABLE,
    controller_tcp_force,
    enable_function_for,
    plan_feed,
    skew,
    wrench_map,
)
from ftacq.calibration import Calibration
from ftacq.errors import ConfigError
from ftacq.so3 import rotation_from_rotvec

G_BASE = np.array([0.0, 0.0, -STANDARD_GRAVITY_M_S2])


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    return rotation_from_rotvec(rng.normal(size=3))


def random_cell(rng: np.random.Generator):
    """A calibration (truth, no noise) plus the geometry the calibration does not hold."""
    mass = rng.uniform(0.3, 3.0)
    calibration = Calibration(sensor_rotation=random_rotation(rng), force_bias=rng.normal(0, 2, 3),
                              torque_bias=rng.normal(0, 0.1, 3), gravity_base=mass * G_BASE,
                              center_of_mass=rng.normal(0, 0.05, 3))
    flange_p_sensor = rng.normal(0, 0.03, 3)
    flange_p_tcp = flange_p_sensor + rng.normal(0, 0.1, 3)
    return calibration, flange_p_sensor, flange_p_tcp


def sensor_reading(calibration: Calibration, base_R_flange: np.ndarray, flange_p_sensor, contact_point_flange,
                   contact_force_base) -> tuple[np.ndarray, np.ndarray]:
    """What the sensor reads (bias included) with a contact force at a point of the tool, and the true contact
    wrench about the TCP-independent sensor origin in sensor axes."""
    sensor_R_flange = calibration.sensor_rotation
    predicted = calibration.predict(base_R_flange.T)
    f_flange = base_R_flange.T @ contact_force_base
    f_s = sensor_R_flange @ f_flange
    r_s = sensor_R_flange @ (np.asarray(contact_point_flange) - flange_p_sensor)
    contact = np.concatenate([f_s, np.cross(r_s, f_s)])
    return predicted + contact, contact


@pytest.mark.parametrize("feed", ["raw", "compensated"])
def test_controller_reports_the_true_contact_wrench_at_the_tcp(feed):
    """Sensor reading → (bias or full compensation) → fed wrench → documented controller → actual_TCP_force equals
    the contact wrench about the TCP in base axes, whatever the tool, the sensor mounting and the pose."""
    rng = np.random.default_rng(16)
    for _ in range(50):
        calibration, p_s, p_tcp = random_cell(rng)
        body_kg = rng.uniform(0.0, 0.6)
        plan = plan_feed(calibration, feed, p_s, sensor_body_kg=body_kg, flange_p_tcp_m=p_tcp)
        base_R_flange = random_rotation(rng)
        contact_point = p_tcp + rng.normal(0, 0.02, 3)
        contact_force = rng.normal(0, 20, 3)
        reading, _ = sensor_reading(calibration, base_R_flange, p_s, contact_point, contact_force)
        bias = np.concatenate([calibration.force_bias, calibration.torque_bias])
        sensor_wrench = reading - bias if feed == "raw" else calibration.compensate(reading, base_R_flange.T)
        reported = controller_tcp_force(plan.fed_wrench(sensor_wrench), plan, base_R_flange, p_tcp)
        expected_torque = np.cross(base_R_flange @ (contact_point - p_tcp), contact_force)
        np.testing.assert_allclose(reported, np.concatenate([contact_force, expected_torque]), atol=1e-9)
        assert plan.payload_kg == pytest.approx(body_kg + calibration.mass_kg)


def test_raw_feed_leaves_the_tool_weight_to_the_controller_and_compensated_feed_neutralises_it():
    rng = np.random.default_rng(3)
    calibration, p_s, _ = random_cell(rng)
    raw = plan_feed(calibration, "raw", p_s, sensor_body_kg=0.25)
    compensated = plan_feed(calibration, "compensated", p_s, sensor_body_kg=0.25)
    assert raw.sensor_mass_kg == pytest.approx(0.25)
    np.testing.assert_allclose(raw.sensor_cog_m, 0.5 * p_s)
    assert compensated.sensor_mass_kg == pytest.approx(compensated.payload_kg)
    np.testing.assert_allclose(compensated.sensor_cog_m, compensated.payload_cog_m)
    for plan in (raw, compensated):
        assert plan.function == FT_RTDE_INPUT_ENABLE
        np.testing.assert_allclose(plan.sensor_measuring_offset_m, p_s)
    # the payload's centre of gravity is the mass-weighted mean of sensor body and tool
    tool_com = p_s + calibration.sensor_rotation.T @ calibration.center_of_mass
    np.testing.assert_allclose(raw.payload_cog_m, (0.25 * 0.5 * p_s + calibration.mass_kg * tool_com)
                               / (0.25 + calibration.mass_kg))
    # zero fed: the raw plan's controller removes the tool weight, the compensated one removes nothing
    base_R_flange = np.eye(3)
    zero_raw = controller_tcp_force(np.zeros(6), raw, base_R_flange, p_s)
    zero_comp = controller_tcp_force(np.zeros(6), compensated, base_R_flange, p_s)
    np.testing.assert_allclose(zero_raw[:3], -calibration.mass_kg * G_BASE, atol=1e-12)
    np.testing.assert_allclose(zero_comp, np.zeros(6), atol=1e-12)


def test_wrench_map_is_rotation_then_lever():
    rng = np.random.default_rng(5)
    R, p_s, p_ref = random_rotation(rng), rng.normal(size=3), rng.normal(size=3)
    w = rng.normal(size=6)
    fed = wrench_map(R, p_s, p_ref) @ w
    np.testing.assert_allclose(fed[:3], R @ w[:3])
    np.testing.assert_allclose(fed[3:], R @ w[3:] + np.cross(p_s - p_ref, R @ w[:3]))
    np.testing.assert_allclose(skew(p_s) @ w[:3], np.cross(p_s, w[:3]))


def test_deprecated_function_is_fed_about_the_tcp_and_refuses_raw():
    rng = np.random.default_rng(9)
    calibration, p_s, p_tcp = random_cell(rng)
    with pytest.raises(ConfigError, match="opposite sign"):
        plan_feed(calibration, "raw", p_s, function=ENABLE_EXTERNAL_FT_SENSOR, flange_p_tcp_m=p_tcp)
    plan = plan_feed(calibration, "compensated", p_s, function=ENABLE_EXTERNAL_FT_SENSOR, flange_p_tcp_m=p_tcp)
    np.testing.assert_allclose(plan.sensor_measuring_offset_m, p_tcp)
    assert plan.sensor_mass_kg == pytest.approx(plan.payload_kg)
    # the flipped lever sign multiplies zero: the contact wrench still arrives right (same check as above)
    base_R_flange = random_rotation(rng)
    point, force = p_tcp + rng.normal(0, 0.02, 3), rng.normal(0, 20, 3)
    reading, _ = sensor_reading(calibration, base_R_flange, p_s, point, force)
    reported = controller_tcp_force(plan.fed_wrench(calibration.compensate(reading, base_R_flange.T)), plan,
                                    base_R_flange, p_tcp)
    np.testing.assert_allclose(reported[3:], np.cross(base_R_flange @ (point - p_tcp), force), atol=1e-9)


def test_enable_function_by_controller_version():
    assert enable_function_for((5, 11, 1, 0)) == FT_RTDE_INPUT_ENABLE
    assert enable_function_for((5, 9, 0, 0)) == FT_RTDE_INPUT_ENABLE
    assert enable_function_for((5, 8, 2, 0)) == ENABLE_EXTERNAL_FT_SENSOR
    assert enable_function_for((3, 15, 7, 0)) == ENABLE_EXTERNAL_FT_SENSOR
    assert enable_function_for((10, 11, 0, 0)) == FT_RTDE_INPUT_ENABLE


def test_bad_feed_is_a_config_error():
    calibration, p_s, _ = random_cell(np.random.default_rng(1))
    with pytest.raises(ConfigError, match="feed 'filtered'"):
        plan_feed(calibration, "filtered", p_s)
    with pytest.raises(ConfigError, match="sensor body mass"):
        plan_feed(calibration, "raw", p_s, sensor_body_kg=-1.0)


def test_urscript_lines_carry_the_plan():
    calibration, p_s, _ = random_cell(np.random.default_rng(2))
    text = plan_feed(calibration, "raw", p_s, sensor_body_kg=0.3).urscript()
    assert text.splitlines()[0].startswith("set_payload(")
    assert text.splitlines()[1].startswith("ft_rtde_input_enable(True, 0.3, [")
