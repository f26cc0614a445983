"""Exports (ftacq export) and sending the payload to the controller (ftacq robot set-payload)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ftacq.app.cli import main
from ftacq.calfile import save_calibration
from ftacq.errors import InputError
from ftacq.exports import ros2_parameters_text, ur_payload, with_sensor_offset
from ftacq.so3 import rotation_from_rotvec
from tests.fakes.world import CellTruth

OFFSET_M = (0.001, -0.002, 0.012)


def calibration(**metadata):
    from dataclasses import replace

    cal = with_sensor_offset(CellTruth().calibration(), OFFSET_M)
    return replace(cal, metadata={**cal.metadata, **metadata})


def test_ur_payload_is_the_centre_of_gravity_in_the_flange_frame():
    """The CoG in the flange frame is where the sensor-frame CoG lands: a point check through the pose chain."""
    cal = calibration()
    payload = ur_payload(cal)
    flange_R_sensor = cal.sensor_rotation.T
    np.testing.assert_allclose(payload.cog_flange_m, np.array(OFFSET_M) + flange_R_sensor @ cal.center_of_mass,
                               atol=1e-15)
    # the same point seen from the base: flange pose ∘ (offset, rotation) ∘ CoG
    base_R_flange = rotation_from_rotvec(np.array([0.3, -1.2, 2.0]))
    base_p_flange = np.array([0.4, -0.1, 0.3])
    via_sensor = base_p_flange + base_R_flange @ (np.array(OFFSET_M) + flange_R_sensor @ cal.center_of_mass)
    np.testing.assert_allclose(base_p_flange + base_R_flange @ payload.cog_flange_m, via_sensor, atol=1e-15)
    assert payload.mass_kg == pytest.approx(CellTruth().mass_kg)
    assert payload.inertia_flange_kg_m2 is None
    assert payload.urscript() == "set_target_payload(1.3500, [{}])".format(
        ", ".join(f"{v:.5f}" for v in payload.cog_flange_m))


def test_ur_inertia_turns_into_the_flange_axes():
    from dataclasses import fields, replace

    cal = calibration()
    inertia_sensor = np.diag([0.002, 0.003, 0.004])
    inertia_sensor[0, 1] = inertia_sensor[1, 0] = 0.0005
    if any(f.name == "inertia" for f in fields(cal)):
        cal = replace(cal, inertia=inertia_sensor)
    else:
        cal = replace(cal, metadata={**cal.metadata, "inertia_kg_m2": inertia_sensor.tolist()})
    payload = ur_payload(cal)
    r = cal.sensor_rotation.T
    expected = r @ inertia_sensor @ r.T
    np.testing.assert_allclose(payload.inertia_flange_kg_m2, [expected[0, 0], expected[1, 1], expected[2, 2],
                                                              expected[0, 1], expected[0, 2], expected[1, 2]])
    assert np.trace(expected) == pytest.approx(np.trace(inertia_sensor))  # a rotation keeps the trace
    assert payload.urscript().count("[") == 2  # mass, [cog], [inertia]


def test_ur_needs_the_sensor_offset():
    with pytest.raises(InputError, match="sensor_offset_m"):
        ur_payload(CellTruth().calibration())


def test_ros2_parameters_compensate_like_ftacq():
    """offset (added) = −bias; filter subtracts mass·gravity_field turned into the sensor frame and CoG × it:
    applied to a simulated reading, the YAML's numbers give ftacq's compensated wrench."""
    cal = calibration()
    text = ros2_parameters_text(cal)
    values = {}
    for line in text.splitlines():
        key, _, rest = line.strip().partition(":")
        values.setdefault(key, rest.split("#")[0].strip())
    assert "type: control_filters/GravityCompensationWrench" in text and "sensor_filter_chain:" in text
    force_offset = [float(v.split(":")[1]) for v in values["force"].strip("{}").split(",")]
    torque_offset = [float(v.split(":")[1]) for v in values["torque"].strip("{}").split(",")]
    cog = np.array(json.loads(values["CoG"]))
    mass = float(values["mass"])
    gravity_field = np.array(json.loads(values["gravity_field"]))
    flange_R_base = rotation_from_rotvec(np.array([2.0, -0.4, 0.7])).T
    raw = cal.predict(flange_R_base) + np.array([1.0, -2.0, 0.5, 0.01, 0.02, -0.03])  # a contact on top
    force_in_sensor = cal.sensor_rotation @ flange_R_base @ (mass * gravity_field)  # what TF does
    filtered_force = raw[:3] + force_offset - force_in_sensor
    filtered_torque = raw[3:] + torque_offset - np.cross(cog, force_in_sensor)
    np.testing.assert_allclose(np.concatenate([filtered_force, filtered_torque]),
                               cal.compensate(raw, flange_R_base), atol=1e-5)


def test_export_command_writes_each_format(tmp_path, capsys):
    path = tmp_path / "cal.json"
    save_calibration(path, CellTruth().calibration())
    assert main(["export", str(path), "--format", "ur"]) == 2  # no sensor offset: refused, one line
    assert "sensor_offset_m" in capsys.readouterr().err
    out = tmp_path / "payload.json"
    assert main(["export", str(path), "--format", "ur", "--sensor-offset-m", *map(str, OFFSET_M), "-o", str(out)]) == 0
    document = json.loads(out.read_text())
    assert document["urscript"].startswith("set_target_payload(1.3500, [")
    assert (out.stat().st_mode & 0o777) == 0o644 or (out.stat().st_mode & 0o044)
    assert main(["export", str(path), "--format", "ros2"]) == 0
    assert "force_torque_sensor_broadcaster:" in capsys.readouterr().out
    copy = tmp_path / "copy.json"
    assert main(["export", str(path), "--format", "json", "-o", str(copy)]) == 0
    assert json.loads(copy.read_text())["mass_kg"] == pytest.approx(CellTruth().mass_kg)


def test_set_payload_on_the_simulated_controller(tmp_path, capsys):
    """The payload (setTargetPayload) and the gravity (setGravity) reach the controller: it records the calls with
    the values sent and reports the payload in its RTDE outputs, which the command reads back and prints."""
    path = tmp_path / "cal.json"
    save_calibration(path, calibration())
    code = main(["robot", "set-payload", "--sim", "--calibration", str(path), "--gravity-from-tilt", "--yes"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "sent with setTargetPayload" in out
    recorded = [json.loads(line) for line in out.split("the simulated controller recorded:\n")[1].splitlines()]
    payload = ur_payload(calibration())
    target = next(e for e in recorded if e["event"] == "set_target_payload")
    assert target["mass_kg"] == pytest.approx(payload.mass_kg) and target["applied"]
    np.testing.assert_allclose(target["cog_m"], payload.cog_flange_m, atol=1e-12)
    gravity = next(e for e in recorded if e["event"] == "set_gravity")["gravity_m_s2"]
    np.testing.assert_allclose(gravity, -CellTruth().gravity_base / CellTruth().mass_kg, atol=1e-12)
    lines = out.splitlines()
    mass_row = lines.index(next(line for line in lines if line.strip().startswith("mass kg")))
    assert lines[mass_row + 1].split()[-1] == f"{payload.mass_kg:.4f}"  # read back over RTDE


def test_set_payload_refuses_a_failed_calibration_and_an_unconfirmed_send(tmp_path, capsys):
    path = tmp_path / "cal.json"
    save_calibration(path, calibration(verdict={"status": "FAIL"}))
    assert main(["robot", "set-payload", "--sim", "--calibration", str(path), "--yes"]) == 2
    assert "verdict is FAIL" in capsys.readouterr().err
    save_calibration(path, calibration())
    assert main(["robot", "set-payload", "--sim", "--calibration", str(path)]) == 2  # no tty, no --yes
    assert "no terminal to confirm on" in capsys.readouterr().err


def test_older_controllers_get_set_payload_and_keep_the_cog_on_zeros():
    """Before 5.10 ur-rtde's script has no set_target_payload: the driver sends setPayload (mass and CoG). Either
    command keeps the current CoG when all three coordinates are 0, as the control script does."""
    from drivers.robot import MotionLimits
    from drivers.ur import URRobot
    from drivers.ur_payload import read_payload, takes_target_payload
    from tests.fakes.ur_process import URControllerProcess

    assert takes_target_payload("5.10.0.0") and takes_target_payload("10.7.0") and not takes_target_payload("5.9.4")
    assert not takes_target_payload("3.15.7.0") and not takes_target_payload(None)
    with URControllerProcess(time_scale=0.0, version="5.9.4.0") as fake:
        with URRobot(fake.host, MotionLimits(), model="UR5e") as robot:
            assert robot.set_payload(1.25, [0.01, 0.02, 0.05], [0.1] * 6) == "setPayload"
            assert robot.set_payload(1.5, [0.0, 0.0, 0.0]) == "setPayload"
        back = read_payload(fake.host)
        calls = [e for e in fake.events() if e["event"].startswith("set_")]
    assert [c["event"] for c in calls] == ["set_payload", "set_payload"]
    assert back.mass_kg == pytest.approx(1.5)
    np.testing.assert_allclose(back.cog_m, [0.01, 0.02, 0.05])  # the zero CoG kept the previous one


def test_the_writer_table_has_every_export_and_refuses_an_unknown_one(tmp_path, capsys):
    from ftacq import calfile

    assert {"json", "ur", "ros2"} <= set(calfile.WRITERS)
    path = tmp_path / "cal.json"
    save_calibration(path, calibration())
    assert main(["export", str(path), "--format", "urdf"]) == 2
    assert "known: json, ur, ros2" in capsys.readouterr().err


def test_cell_toml_declares_the_sensor_offset(tmp_path):
    from ftacq.app.config import example_config_text, load_config
    from ftacq.errors import ConfigError

    path = tmp_path / "CELL.toml"
    path.write_text("[tool]\nsensor_offset_m = [0.0, 0.0, 0.012]\n")
    assert load_config(path).tool.sensor_offset_m == pytest.approx((0.0, 0.0, 0.012))
    path.write_text("[tool]\nsensor_offset_m = [0.0, 0.0, 2.0]\n")
    with pytest.raises(ConfigError, match="sensor_offset_m"):
        load_config(path)
    assert "sensor_offset_m" in example_config_text()
