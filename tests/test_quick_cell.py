"""The quick calibration on a cell other than our defaults, and its run folder when it crashes.

- The Net F/T may stream at any RDT rate the cell sets (1-7 kHz): the recording's sensor times come from the
  sample counter (``ft_sequence`` counts the internal 7 kHz whatever the output rate) through the device clock, so a
  still hold's samples are where the robot's states say, at every rate.
- A quick run that crashes (an exception no stage handles) leaves run.json "failed" with the error, not "running",
  and the command ends with one line and a non-zero status.
"""

from __future__ import annotations

import contextlib
import json

import numpy as np
import pytest

from procedures.quick_analysis import REST_SPEED_RAD_S, validation_poses
from ftacq.kinematics import forward_kinematics, ur_model
from procedures.plan import home_configuration_rad
from procedures.quick import FIT, VALIDATE, QuickPlan, record_quick
from tests.fakes.cell import SimClocks, SimulatedCell
from tests.fakes.world import CellTruth

pytest.importorskip("rtde_control")


def short_plan(start: np.ndarray) -> QuickPlan:
    """Two wrist moves (a fit hold after the first), then one still validation hold: a few seconds."""
    first, second = start.copy(), start.copy()
    first[4] += 0.5
    second[4] += 0.5
    second[5] -= 0.8
    return QuickPlan(start, np.array([first, second]), np.array([0.3, 1.0]), (FIT, VALIDATE), ("Q1", "V1"), 1.0, 2.0,
                     4.0, 0.0, 1)


@contextlib.contextmanager
def moving_cell(**cell_options):
    """A real-time simulated cell at the floor's home configuration: (cell, robot, started sensor, state stream)."""
    from drivers.robot import MotionLimits
    from drivers.sensor import open_sensor
    from drivers.ur import URRobot
    from drivers.ur_stream import URStateStream

    with SimulatedCell(time_scale=1.0, initial_q=home_configuration_rad("floor"), **cell_options) as cell, \
            URRobot(cell.robot_host, MotionLimits(1.0, 2.0), model="UR5e") as robot, \
            URStateStream(cell.robot_host) as stream:
        sensor = open_sensor(cell.sensor_url)
        sensor.start()
        try:
            yield cell, robot, sensor, stream
        finally:
            sensor.close()


@pytest.mark.parametrize("rate_hz", [7000.0, 1750.0])
def test_a_hold_is_found_in_the_sensor_samples_at_any_rdt_rate(rate_hz):
    truth = CellTruth()
    # the sensor's clock further off the host than the default, in bursts: its times must come from its counter
    clocks = SimClocks(sensor_rate_error=150e-6, sensor_burst_interval_s=0.003)
    with moving_cell(truth=truth, rate_hz=rate_hz, clocks=clocks) as (_, robot, sensor, stream):
        plan = short_plan(robot.joint_positions())
        recording = record_quick(plan, robot, sensor, stream)
    record = recording.record
    assert record.metadata["sensor_clock"] == "device"
    assert recording.completed == 2 and np.all(recording.hold_rows[:, 1] > recording.hold_rows[:, 0])
    # the sensor's rate on the host clock is the cell's RDT rate (not a rate the code assumed)
    steps = np.diff(record.sensor_time_s)
    assert np.all(steps > 0)
    assert abs(np.median(steps) * rate_hz - 1.0) < 0.01
    # the validation hold: at rest, and its sensor samples read the tool's weight at that pose (a window misplaced
    # in time would average the move before it: the wrist turned by 0.8 rad)
    q, mean, standard_error, *_ = validation_poses(recording, plan, lag_s=0.0)
    assert q.shape == (1, 6)
    a, b = recording.hold_rows[1]
    assert np.max(np.abs(record.qd[b - 10:b])) <= REST_SPEED_RAD_S
    flange_R_base = forward_kinematics(ur_model("UR5e"), q[0])[:3, :3].T
    expected = truth.calibration().predict(flange_R_base[None])[0]
    assert np.all(np.abs(mean[0] - expected)[:3] < 0.05), (mean[0], expected)
    assert np.all(np.abs(mean[0] - expected)[3:] < 0.003), (mean[0], expected)
    assert np.all(standard_error[0] < 0.01)


def test_a_crash_ends_the_run_failed_with_the_error(tmp_path, monkeypatch, capsys):
    import procedures.quick
    from ftacq.app.cli import main

    def crash(*args, **kwargs):
        raise RuntimeError("simulated crash in the recorder")

    monkeypatch.setattr(procedures.quick, "record_quick", crash)
    status = main(["calibrate", "--sim", "--quick", "--yes", "--out", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert status != 0
    last = err.strip().splitlines()[-1]
    assert last.startswith("ftacq:") and "simulated crash in the recorder" in last and "calibrate --sim --quick" in last
    (folder,) = (tmp_path / "runs").iterdir()
    run = json.loads((folder / "run.json").read_text())
    assert run["status"] == "failed"
    assert "RuntimeError: simulated crash in the recorder" in run["message"]
    assert not (folder / "calibration.json").exists()


def test_a_controller_of_another_model_than_the_cell_file_is_a_one_line_error(tmp_path, capsys):
    from ftacq.app.cli import main

    with SimulatedCell(model="UR5e") as cell:
        config = tmp_path / "CELL.toml"
        config.write_text(f'[robot]\nhost = "{cell.robot_host}"\nmodel = "UR10e"\n\n[sensor]\nurl = "{cell.sensor_url}"\n',
                          encoding="utf-8")
        status = main(["calibrate", "--config", str(config), "--quick", "--dry-run", "--out", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert status == 2, err
    assert "says it is a UR5e" in err and "robot.model = UR10e" in err and "Traceback" not in err


def test_the_motion_publishes_its_plan_states_and_samples_and_a_stop():
    """The motion runner tells its listeners what the full run tells them (procedures/events.py): the plan, a state
    per move and hold, the end; every sensor batch with the arm's newest state. Ctrl-C from a listener stops the
    robot and ends the events with "stopped"."""
    from procedures import events

    model = ur_model("UR5e")
    published: list = []

    def interrupt_at_the_first_hold(event) -> None:
        if isinstance(event, events.StateChanged) and event.state == "holding":
            raise KeyboardInterrupt

    with moving_cell() as (cell, robot, sensor, stream):
        plan = short_plan(robot.joint_positions())
        recording = record_quick(plan, robot, sensor, stream, listeners=[published.append])
        stopped: list = []
        with pytest.raises(KeyboardInterrupt) as raised:
            record_quick(plan, robot, sensor, stream, listeners=[stopped.append, interrupt_at_the_first_hold])
        commands = cell.controller.commands()
    ready = published[0]
    assert isinstance(ready, events.PlanReady) and ready.labels == ("Q1", "V1") and ready.set_names == ("Q", "V")
    np.testing.assert_allclose(ready.joint_targets_rad, plan.waypoints_rad)
    np.testing.assert_allclose(ready.poses[1, :3], forward_kinematics(model, plan.waypoints_rad[1])[:3, 3], atol=1e-9)
    states = [(e.state, e.index, e.label, e.measured, e.total) for e in published if isinstance(e, events.StateChanged)]
    assert states == [("moving", 0, "Q1", 0, 2), ("holding", 0, "Q1", 0, 2), ("moving", 1, "V1", 1, 2),
                      ("holding", 1, "V1", 1, 2), ("done", None, "", 2, 2)]
    samples = [e for e in published if isinstance(e, events.WrenchSamples)]
    assert sum(len(e) for e in samples) == len(recording.record.sensor_time_s)
    placed = [e for e in samples if e.joint_positions_rad is not None]
    assert len(placed) > 0.9 * len(samples)
    last = placed[-1]  # at rest at the last waypoint: its pose by the model's forward kinematics
    np.testing.assert_allclose(last.joint_positions_rad, plan.waypoints_rad[-1], atol=1e-3)
    np.testing.assert_allclose(last.flange_pose[:3], forward_kinematics(model, plan.waypoints_rad[-1])[:3, 3],
                               atol=1e-3)
    # the interrupted run: stopped in its first hold, the robot told to stop, the partial run kept
    assert [(e.state, e.index) for e in stopped if isinstance(e, events.StateChanged)] == [
        ("moving", 0), ("holding", 0), ("stopped", None)]
    assert commands[-1]["kind"] == "stopj"
    assert raised.value.quick_recording.completed == 0 and len(raised.value.quick_recording.record.robot_time_s)
