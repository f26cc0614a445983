"""Faults during the procedure: the robot is stopped, everything measured is kept, the run is marked and the
controller's record shows that nothing left the plan or exceeded the limits."""

from __future__ import annotations

import json

import numpy as np
import pytest

from drivers.robot import MotionLimits
from ftacq.errors import DeviceError, ProtectiveStopError
from procedures import events
from procedures.run_folder import RunFolder, RunFolderWriter
from tests.fakes.cell import SimulatedCell, fast_config, motion_problems, plan_for, run_calibration

FAULT_MOVE = 4
"""The fault happens during this motion command (1-based): three poses are measured before it."""


def limits_of(config) -> MotionLimits:
    return MotionLimits(joint_speed_rad_s=config.robot.joint_speed_rad_s,
                        joint_acceleration_rad_s2=config.robot.joint_acceleration_rad_s2)


def check_kept_and_stopped(folder, plan, result, commands, config, measured_count: int) -> None:
    assert result.status == "failed"
    assert len(result.measured) == measured_count
    assert list(result.measured) == list(plan.labels[:measured_count])
    record = folder.read_record()
    assert record.labels == tuple(plan.labels[:measured_count])  # every pose measured is on disk
    document = json.loads((folder.path / "run.json").read_text())
    assert document["status"] == "failed"
    total = len(plan) + (1 if config.sampling.drift_check else 0)  # counted as the progress display counts
    assert f"at pose {measured_count + 1}/{total} ({plan.labels[measured_count]})" in document["message"]
    assert motion_problems(commands, plan, limits_of(config)) == []
    moves = [c for c in commands if c["kind"] == "movej"]
    assert len(moves) == measured_count + 1  # nothing was commanded after the fault
    assert any(c["kind"] == "stopj" for c in commands)  # the robot was told to stop


def test_protective_stop_mid_move(tmp_path):
    with SimulatedCell(sensor="can", time_scale=4.0) as cell:
        config = fast_config(cell)
        plan = plan_for(cell, config)
        folder = RunFolder.create(tmp_path, config.to_dict(), plan.to_json())
        cell.controller.inject("protective_stop", "move_fraction", 0.5, move=FAULT_MOVE)
        _, result = run_calibration(cell, config, [RunFolderWriter(folder)], plan=plan)
        commands = cell.controller.commands()
        state = cell.controller.state()
    assert isinstance(result.error, ProtectiveStopError), result.message
    assert "ProtectiveStopError" in result.message
    assert state["moving"] is False
    target = plan.joint_targets_rad[FAULT_MOVE - 1]
    assert np.max(np.abs(np.asarray(state["q"]) - target)) > 1e-3  # it stopped on the way, not at the target
    moves = [c for c in commands if c["kind"] == "movej"]
    assert len(moves) == FAULT_MOVE
    assert motion_problems(commands, plan, limits_of(config)) == []
    assert result.status == "failed" and len(result.measured) == FAULT_MOVE - 1
    assert folder.read_record().labels == tuple(plan.labels[:FAULT_MOVE - 1])
    assert json.loads((folder.path / "run.json").read_text())["status"] == "failed"


def _silence_sensor_during(cell, plan_index: int):
    def listener(event):
        if isinstance(event, events.StateChanged) and event.state == "moving" and event.index == plan_index:
            if cell.can_board is not None:
                cell.can_board.silent = True
            else:
                cell.netft.go_silent()
    return listener


@pytest.mark.parametrize("sensor", ["can", "netft"])
@pytest.mark.slow(seconds=7)
def test_sensor_going_silent_mid_move(tmp_path, sensor):
    with SimulatedCell(sensor=sensor, time_scale=4.0) as cell:
        config = fast_config(cell, sensor_timeout_s=0.3)
        plan = plan_for(cell, config)
        folder = RunFolder.create(tmp_path, config.to_dict(), plan.to_json())
        _, result = run_calibration(cell, config, [RunFolderWriter(folder), _silence_sensor_during(cell, 2)],
                                    plan=plan)
        commands = cell.controller.commands()
        state = cell.controller.state()
    assert isinstance(result.error, DeviceError), result.message
    assert "silent" in result.message or "no sample" in result.message
    assert state["moving"] is False
    check_kept_and_stopped(folder, plan, result, commands, config, measured_count=2)


@pytest.mark.slow(seconds=9)
def test_requested_stop_keeps_the_data_and_a_critical_listener_error_fails_the_run(tmp_path):
    with SimulatedCell(sensor="can", time_scale=0.0) as cell:
        config = fast_config(cell)
        plan = plan_for(cell, config)
        holder: dict = {}

        def stop_after_two(event):
            if isinstance(event, events.PoseMeasured) and event.index == 1:
                holder["procedure_stop"]()

        folder = RunFolder.create(tmp_path, config.to_dict(), plan.to_json(), name="stopped")
        _, stopped = run_calibration(cell, config, [RunFolderWriter(folder), stop_after_two], plan=plan,
                                     on_procedure=lambda p: holder.update(procedure_stop=p.request_stop))

        class Broken:
            critical = True

            def __call__(self, event):
                if isinstance(event, events.PoseMeasured):
                    raise OSError("disk full")

        def flaky_viewer(event):
            raise RuntimeError("viewer went away")  # not critical: ignored

        _, failed = run_calibration(cell, config, [flaky_viewer, Broken()], plan=plan)

        def abort_after_one(event):
            if isinstance(event, events.PoseMeasured):
                holder["procedure"].request_abort("watchdog: cell door opened")

        _, aborted = run_calibration(cell, config, [abort_after_one], plan=plan,
                                     on_procedure=lambda p: holder.update(procedure=p))
    assert stopped.status == "stopped" and not stopped.interrupted
    assert list(stopped.measured) == list(plan.labels[:2])
    assert folder.read_record().labels == tuple(plan.labels[:2])
    assert json.loads((folder.path / "run.json").read_text())["status"] == "stopped"
    assert failed.status == "failed" and "disk full" in failed.message
    assert aborted.status == "failed" and "cell door opened" in aborted.message
    assert list(aborted.measured) == list(plan.labels[:1])


def test_a_pose_that_never_settles_fails_naming_the_channel(tmp_path):
    from dataclasses import replace

    from procedures.settle import PoseNotSettledError
    from tests.fakes.world import CellTruth

    shaky = replace(CellTruth(), force_noise_n=(0.05, 0.05, 3.0))  # Fz far above the 0.5 N stillness threshold
    with SimulatedCell(truth=shaky, sensor="can", time_scale=0.0) as cell:
        config = fast_config(cell, settle_timeout_s=0.3)
        _, result = run_calibration(cell, config)
        commands = cell.controller.commands()
    assert isinstance(result.error, PoseNotSettledError)
    assert "did not settle within 0.3 s" in result.message and "Fz std" in result.message
    assert result.status == "failed" and result.measured == {}
    assert len([c for c in commands if c["kind"] == "movej"]) == 1
