"""The live monitor: every sample compensated, published, recorded; a slow, failing or vanished viewer never costs
a sample; Ctrl-C keeps the record. Unit tests feed it from :class:`tests.scripted.ScriptedSensor`; the integration
tests run the real Net F/T driver against the loopback fake and ``ftacq monitor`` itself."""

from __future__ import annotations

import threading
import uuid
from contextlib import closing as contextlib_closing
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from drivers.sensor import WrenchBatch
from ftacq.app.dashboard import layout, sinks
from ftacq.app.dashboard.listener import DashboardListener
from ftacq.app.dashboard.recorder import Dashboard
from ftacq.kinematics import ur_model
from procedures import events
from procedures.monitor import RECORD_COLUMNS, GravityCompensator, LiveMonitor, flange_R_base_from_pose
from tests.conftest import wait_until
from tests.fakes.world import CellTruth
from tests.rrd_reader import entity_paths, mixed_static_and_temporal, read_scalars, read_texts
from tests.scripted import MODEL, Q_HOME_RAD, BATCH_SAMPLES, VALUE_TOLERANCE, FixedRobotState, ScriptedSensor, \
    dashboard_listener, free_port, new_recording, physics_batches, read_record, run_until_exhausted


# ----------------------------------------------------------------------------------------------------------------
# Live monitor (scripted sensor)
# ----------------------------------------------------------------------------------------------------------------


def test_monitor_logs_every_sample_and_compensates_like_the_core(tmp_path):
    robot = FixedRobotState(Q_HOME_RAD)
    sensor = ScriptedSensor(physics_batches(robot.pose, 20, contact_after=10))
    calibration = CellTruth().calibration()
    path = tmp_path / "monitor.rrd"
    recording = new_recording(path)
    monitor = LiveMonitor(sensor, robot=robot, compensator=GravityCompensator(calibration),
                          listeners=[dashboard_listener(recording)], record_path=tmp_path / "run.csv",
                          strict=True, batch_period_s=0.0)
    summary = run_until_exhausted(monitor, sensor)
    sinks.close_recording(recording)

    delivered = WrenchBatch.concatenate(sensor.delivered)
    assert summary.samples == len(delivered) == 20 * BATCH_SAMPLES
    assert summary.dropped_samples == 0 and summary.listener_error is None
    paths = entity_paths(path)
    for entity in layout.WRENCH_PATHS + (layout.LINK_FRAMES[5], layout.FLANGE, layout.HEALTH_RATE, layout.JOINT_ANGLES):
        assert entity in paths, entity
    assert not mixed_static_and_temporal(path)  # what the viewer shows of a file as recorded (see the recorder)
    time_s, raw_force = read_scalars(path, layout.RAW_FORCE)
    np.testing.assert_allclose(time_s, delivered.time_s, atol=1e-9)
    np.testing.assert_allclose(raw_force, delivered.wrench[:, :3], atol=VALUE_TOLERANCE)
    expected = calibration.compensate(delivered.wrench, flange_R_base_from_pose(robot.pose))
    _, force = read_scalars(path, layout.COMPENSATED_FORCE)
    _, torque = read_scalars(path, layout.COMPENSATED_TORQUE)
    np.testing.assert_allclose(np.hstack([force, torque]), expected, atol=VALUE_TOLERANCE)
    # gravity is gone: before contact the compensated force is noise, after it the 5 N push
    before, after = force[: 10 * BATCH_SAMPLES], force[10 * BATCH_SAMPLES:]
    assert np.abs(before.mean(axis=0)).max() < 0.05
    np.testing.assert_allclose(after.mean(axis=0), [0.0, 0.0, 5.0], atol=0.05)

    record = read_record(tmp_path / "run.csv")
    assert record.dtype.names == RECORD_COLUMNS and record.size == summary.samples
    np.testing.assert_allclose(record["contact_fz"], expected[:, 2], atol=1e-6)



def test_monitor_says_when_the_robot_state_stream_is_lost(tmp_path):
    robot = FixedRobotState(Q_HOME_RAD)
    robot.connected = False  # e.g. the network cable to the controller was pulled
    sensor = ScriptedSensor(physics_batches(robot.pose, 5))
    path = tmp_path / "lost.rrd"
    recording = new_recording(path)
    monitor = LiveMonitor(sensor, robot=robot, compensator=GravityCompensator(CellTruth().calibration()),
                          listeners=[dashboard_listener(recording)], strict=True, batch_period_s=0.0)
    summary = run_until_exhausted(monitor, sensor)
    sinks.close_recording(recording)
    assert summary.samples == 5 * BATCH_SAMPLES
    assert any("robot state stream lost" in text for text in read_texts(path, layout.MONITOR_LOG))


class StalledViewer:
    """A listener that hangs on the first wrench samples until released (a viewer behind a dead connection)."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.stalled = threading.Event()

    def __call__(self, event) -> None:
        if isinstance(event, events.WrenchSamples):
            self.stalled.set()
            self.release.wait(30.0)


def test_a_stalled_viewer_drops_batches_for_the_viewer_only(tmp_path):
    robot = FixedRobotState(Q_HOME_RAD)
    viewer = StalledViewer()

    class SensorAfterStall(ScriptedSensor):
        def read(self, timeout_s=1.0):
            if len(self.delivered) == 1:  # the first batch is in the viewer's hands: wait until it hangs
                assert viewer.stalled.wait(10.0)
            return super().read(timeout_s)

    sensor = SensorAfterStall(physics_batches(robot.pose, 30))
    monitor = LiveMonitor(sensor, robot=robot, compensator=GravityCompensator(CellTruth().calibration()),
                          listeners=[viewer], record_path=tmp_path / "run.csv", queue_batches=4, batch_period_s=0.0,
                          listener_period_s=0.0)
    stop = threading.Event()

    def release_when_done() -> None:
        sensor.exhausted.wait(30.0)
        stop.set()
        viewer.release.set()

    helper = threading.Thread(target=release_when_done, name="test-release")
    helper.start()
    try:
        summary = monitor.run(stop=stop)
    finally:
        sensor.exhausted.set()
        helper.join()
    assert summary.samples == 30 * BATCH_SAMPLES
    assert summary.dropped_batches == 30 - 1 - 4  # 1 in the stalled call, 4 in the queue
    assert summary.dropped_samples == summary.dropped_batches * BATCH_SAMPLES
    record = read_record(tmp_path / "run.csv")
    assert record.size == summary.samples  # the record never drops


class BrokenViewer:
    def __call__(self, event) -> None:
        if isinstance(event, events.WrenchSamples):
            raise RuntimeError("viewer exploded")


@pytest.mark.parametrize("strict", [False, True])
def test_a_failing_viewer_never_stops_acquisition(strict):
    robot = FixedRobotState(Q_HOME_RAD)
    sensor = ScriptedSensor(physics_batches(robot.pose, 10))
    monitor = LiveMonitor(sensor, robot=robot, listeners=[BrokenViewer()], strict=strict,
                          batch_period_s=0.0)
    if strict:
        with pytest.raises(RuntimeError, match="viewer exploded"):
            run_until_exhausted(monitor, sensor)
        assert len(WrenchBatch.concatenate(sensor.delivered)) == 10 * BATCH_SAMPLES
    else:
        summary = run_until_exhausted(monitor, sensor)
        assert summary.samples == 10 * BATCH_SAMPLES
        assert summary.listener_error == "RuntimeError: viewer exploded"
        assert summary.dropped_samples == summary.samples


def test_acquisition_continues_when_the_viewer_goes_away():
    viewer = rr.RecordingStream("viewer", recording_id=uuid.uuid4())  # stands in for a viewer's gRPC server
    server = rr.GrpcServerSink(bind_ip="127.0.0.1", port=free_port())
    viewer.set_sinks(server)
    recording = rr.RecordingStream(layout.APP_ID, recording_id=uuid.uuid4())
    recording.connect_grpc(server.uri)
    robot = FixedRobotState(Q_HOME_RAD)

    class ViewerKillingSensor(ScriptedSensor):
        def read(self, timeout_s=1.0):
            if len(self.delivered) == 5:
                viewer.disconnect()  # the viewer window is closed mid-run
            return super().read(timeout_s)

    sensor = ViewerKillingSensor(physics_batches(robot.pose, 10))
    monitor = LiveMonitor(sensor, robot=robot, compensator=GravityCompensator(CellTruth().calibration()),
                          listeners=[DashboardListener(Dashboard(recording), model=MODEL)], batch_period_s=0.0)
    summary = run_until_exhausted(monitor, sensor)
    sinks.close_recording(recording, timeout_s=0.5)
    assert summary.samples == 10 * BATCH_SAMPLES and summary.listener_error is None


def test_ctrl_c_stops_cleanly_and_keeps_the_record(tmp_path):
    robot = FixedRobotState(Q_HOME_RAD)
    batches = physics_batches(robot.pose, 10)

    class InterruptingSensor(ScriptedSensor):
        def read(self, timeout_s=1.0):
            if len(self.delivered) == 5:
                raise KeyboardInterrupt
            return super().read(timeout_s)

    sensor = InterruptingSensor(batches)
    monitor = LiveMonitor(sensor, robot=robot, compensator=GravityCompensator(CellTruth().calibration()),
                          record_path=tmp_path / "run.csv", batch_period_s=0.0)
    summary = monitor.run()
    assert summary.interrupted and summary.samples == 5 * BATCH_SAMPLES
    record = read_record(tmp_path / "run.csv")
    assert record.size == 5 * BATCH_SAMPLES
    assert not list(tmp_path.glob(".run.csv.*"))  # no temporary file left behind


# ----------------------------------------------------------------------------------------------------------------
# Integration: the simulated cell (simulated UR controller + Net F/T fake on loopback), real drivers
# ----------------------------------------------------------------------------------------------------------------

SIM_SECONDS = 1.5
SIM_RATE_HZ = 2000.0


@pytest.fixture
def simulated_cell():
    from tests.fakes import cell as cell_module

    with cell_module.SimulatedCell(sensor="netft", time_scale=1.0, rate_hz=SIM_RATE_HZ) as cell:
        yield cell


def test_monitor_run_against_the_simulated_cell_matches_ftacq_compensate(simulated_cell, tmp_path):
    """Acceptance 1: record a monitor run to an .rrd, read it back with Rerun's reader: the entity paths exist,
    the sample count is what the driver delivered, and the compensated values equal `ftacq compensate`'s."""
    from drivers.sensor import open_sensor
    from drivers.ur import URStateReader
    from ftacq.calfile import save_calibration
    from ftacq.app.cli import main as ftacq_main

    cell = simulated_cell
    calibration = cell.truth.calibration()
    sensor = open_sensor(cell.sensor_url)
    delivered: list[WrenchBatch] = []

    class CountingSensor:  # the real driver, with every batch it delivered kept for the comparison
        def __init__(self, inner) -> None:
            self.inner = inner

        def read(self, timeout_s=1.0):
            batch = self.inner.read(timeout_s)
            delivered.append(batch)
            return batch

        def health(self):
            return self.inner.health()

    rrd_path, record_path = tmp_path / "monitor.rrd", tmp_path / "monitor.csv"
    recording = new_recording(rrd_path)
    cell.set_contact(np.array([0.0, 0.0, 4.0, 0.0, 0.0, 0.0]))  # a 4 N push on the tool all along
    with contextlib_closing(sensor) as sensor, URStateReader(cell.robot_host, model=cell.model_name) as robot:
        sensor.start()
        dashboard = dashboard_listener(recording, model=ur_model(cell.model_name))
        dashboard.set_calibration(calibration)
        summary = LiveMonitor(sensor=CountingSensor(sensor), robot=robot,
                              compensator=GravityCompensator(calibration), listeners=[dashboard],
                              record_path=record_path,
                              strict=True).run(duration_s=SIM_SECONDS)
    sinks.close_recording(recording)

    samples = sum(len(batch) for batch in delivered)
    assert summary.samples == samples > 0.5 * SIM_RATE_HZ * SIM_SECONDS
    paths = entity_paths(rrd_path)
    for entity in layout.WRENCH_PATHS + (layout.LINK_FRAMES[5], layout.FLANGE, layout.CONTACT_FORCE, layout.HEALTH_RATE):
        assert entity in paths, entity
    time_s, force = read_scalars(rrd_path, layout.COMPENSATED_FORCE)
    _, torque = read_scalars(rrd_path, layout.COMPENSATED_TORQUE)
    assert time_s.size == samples
    np.testing.assert_allclose(time_s, WrenchBatch.concatenate(delivered).time_s, atol=1e-9)

    calibration_path = tmp_path / "calibration.json"
    save_calibration(calibration_path, calibration)
    compensated_path = tmp_path / "compensated.csv"
    assert ftacq_main(["compensate", str(calibration_path), str(record_path), "-o", str(compensated_path)]) == 0
    table = read_record(compensated_path)
    assert table.size == samples
    reference = np.column_stack([table[name] for name in
                                 ("contact_fx", "contact_fy", "contact_fz", "contact_tx", "contact_ty", "contact_tz")])
    np.testing.assert_allclose(np.hstack([force, torque]), reference, atol=1e-5)  # CSV keeps 9 digits
    np.testing.assert_allclose(force.mean(axis=0), [0.0, 0.0, 4.0], atol=0.1)  # gravity gone, the push remains


def test_ftacq_monitor_sim_saves_a_recording(tmp_path, capsys):
    from ftacq.app.cli import main as ftacq_main

    rrd_path = tmp_path / "sim.rrd"
    assert ftacq_main(["monitor", "--sim", "--seconds", "1", "--save", str(rrd_path)]) == 0
    assert "samples" in capsys.readouterr().out
    paths = entity_paths(rrd_path)
    assert {layout.RAW_FORCE, layout.COMPENSATED_FORCE, layout.LINK_FRAMES[5], layout.MONITOR_LOG} <= paths
    time_s, _ = read_scalars(rrd_path, layout.RAW_FORCE)
    assert time_s.size > 1000


def test_ctrl_c_stops_ftacq_monitor_cleanly(tmp_path):
    """SIGINT to a live `ftacq monitor --sim`: exit 0, the .rrd and the record are complete and agree."""
    import os
    import signal
    import subprocess
    import sys

    rrd_path, record_path = tmp_path / "live.rrd", tmp_path / "live.csv"
    process = subprocess.Popen(
        [sys.executable, "-m", "ftacq.app.cli", "monitor", "--sim", "--sim-still", "--save", str(rrd_path),
         "--record", str(record_path)],
        cwd=Path(__file__).resolve().parents[1], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        def recording_or_exited() -> bool:
            try:
                return process.poll() is not None or any(
                    partial.stat().st_size > 10_000 for partial in tmp_path.glob(f".{record_path.name}.*"))
            except FileNotFoundError:  # renamed between the listing and the stat
                return False

        wait_until(recording_or_exited, "samples being recorded", timeout_s=60.0)
        assert process.poll() is None, process.communicate()
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=60.0)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, err
    assert "stopped by Ctrl-C" in out
    record = read_record(record_path)
    time_s, _ = read_scalars(rrd_path, layout.COMPENSATED_FORCE)
    assert record.size > 100 and time_s.size == record.size
    np.testing.assert_allclose(time_s, record["time_s"], atol=1e-6)
