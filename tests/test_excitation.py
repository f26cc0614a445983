"""The excitation stage on the simulated cell: the plan is checked, every command the controller recorded stays
within the CELL.toml limits and the plan, the recorded motion identifies the inertia; the motion file and
``ftacq identify --motion``."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.robot import MotionLimits
from drivers.sensor import open_sensor
from drivers.ur import URRobot
from drivers.ur_stream import URStateStream
from ftacq.app.cli import main as ftacq_main
from ftacq.calfile import load_calibration, save_calibration
from ftacq.dynamics.motionfile import read_motion_csv, write_motion_csv
from ftacq.errors import InputError
from ftacq.kinematics import ur_model
from procedures.excitation import plan_excitation, record_excitation, sensor_host_times
from procedures.plan import PlanSettings, check_path, home_configuration_rad
from tests.fakes.cell import SimulatedCell
from tests.fakes.world import CellTruth

pytest.importorskip("rtde_control")

SETTINGS = PlanSettings(joint_speed_rad_s=1.0, joint_acceleration_rad_s2=2.0)


def test_plan_is_checked_and_returns_to_start():
    start = home_configuration_rad("floor")
    plan = plan_excitation(SETTINGS, start, moves=6, seed=2)
    np.testing.assert_array_equal(plan.targets_rad[-1], start)
    path = np.vstack([start, plan.targets_rad])
    for a, b in zip(path[:-1], path[1:]):
        assert check_path(SETTINGS, a, b) == []
    assert np.ptp(path[:, 3:], axis=0).min() > 1.0  # the wrist turns the tool about every axis
    assert 5.0 < plan.estimated_duration_s < 60.0


def test_recorded_excitation_stays_within_the_limits_and_identifies_the_inertia():
    truth = CellTruth(motion_noise_gain=0.0)
    start = home_configuration_rad("floor")
    with SimulatedCell(truth=truth, time_scale=1.0, rate_hz=1000.0, initial_q=start) as cell, \
            URRobot(cell.robot_host, MotionLimits(1.0, 2.0), model="UR5e") as robot, \
            URStateStream(cell.robot_host) as stream:
        sensor = open_sensor(cell.sensor_url)
        sensor.start()
        try:
            plan = plan_excitation(SETTINGS, robot.joint_positions(), moves=4, seed=5)
            record = record_excitation(plan, robot, sensor, stream)
        finally:
            sensor.close()
        commands = cell.controller.commands()
    moves = [c for c in commands if c["kind"] != "stopj"]
    assert len(moves) == len(plan.targets_rad) and all(c["accepted"] for c in moves)
    for command, target in zip(moves, plan.targets_rad):
        assert command["kind"] == "movej"
        np.testing.assert_allclose(command["target"], target, atol=1e-12)
        assert command["speed"] <= SETTINGS.joint_speed_rad_s and command["acceleration"] <= SETTINGS.joint_acceleration_rad_s2
    assert np.abs(record.qd).max() <= SETTINGS.joint_speed_rad_s + 1e-9
    assert np.abs(record.qdd).max() <= SETTINGS.joint_acceleration_rad_s2 + 1e-9
    assert np.abs(record.qd).max() > 0.9 and len(record.sensor_time_s) > 1000
    from dataclasses import replace

    from ftacq.dynamics import identify_dynamics

    static = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m))
    result = identify_dynamics(static, record, ur_model("UR5e"))
    # loose: a loaded machine ticks the simulated controller unevenly (benchmarks/dynamics.py has the figure)
    assert np.linalg.norm(result.inertia - truth.inertia) < 0.5 * np.linalg.norm(truth.inertia)
    assert np.all(result.held_out_rms_dynamic[3:5] < result.held_out_rms_static[3:5])


def test_sensor_times_follow_the_device_sequence():
    rng = np.random.default_rng(0)
    sequence = np.arange(5000) + 17
    true = 100.0 + sequence / 7000.0
    arrival = true + 0.0004 + rng.exponential(0.0008, sequence.size)  # transport delay ≥ 0.4 ms
    times = sensor_host_times(arrival, sequence)
    assert np.abs(times - (true + 0.0004)).max() < 5e-5


def test_motion_file_round_trip_and_identify_command(tmp_path, capsys):
    from tests.test_dynamics_identify import record_for

    truth = CellTruth()
    record = record_for(truth)
    path = tmp_path / "motion.csv"
    write_motion_csv(path, record, "UR5e")
    loaded, model = read_motion_csv(path)
    assert model == "UR5e"
    np.testing.assert_allclose(loaded.wrench, record.wrench, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(loaded.q, record.q, atol=1e-9)
    static = tmp_path / "static.json"
    from dataclasses import replace

    save_calibration(static, replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m)))
    out = tmp_path / "dynamic.json"
    assert ftacq_main(["identify", "--calibration", str(static), "--motion", str(path), "-o", str(out)]) == 0
    calibration = load_calibration(out)
    assert calibration.has_dynamics
    assert np.linalg.norm(calibration.inertia - truth.inertia) < 1e-3 * np.linalg.norm(truth.inertia)
    assert "tool inertia about its centre of mass" in capsys.readouterr().out
    broken = tmp_path / "broken.csv"
    lines = path.read_text().splitlines()
    lines[5] = lines[5].replace("sensor,", "sensor,x", 1)
    broken.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"broken.csv: line 6: column 'time_s'"):
        read_motion_csv(broken)
