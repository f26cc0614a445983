"""The live monitor: every sample compensated, published, recorded; a slow, failing or vanished viewer never costs
a sample; Ctrl-C keeps the record. Unit tests feed it from :class:`tests.scripted.ScriptedSensor`; the integration
tests run the real Net F/T driver against the loopback fake and ``ftacq monitor`` itself."""

from __future__ import annotations

import re
import sys
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
    # each sample's time from the sensor's own clock (here exactly its receive time, 995 s off), and that clock
    np.testing.assert_allclose(record["device_time_s"], delivered.device_time_s, atol=1e-9)
    np.testing.assert_allclose(record["sample_time_s"], delivered.time_s, atol=1e-9)
    assert np.all(record["clock_uncertainty_s"] < 1e-6)
    assert summary.clock_uncertainty_s < 1e-6 and summary.clock_rate_error == pytest.approx(0.0, abs=1e-9)



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


def test_ctrl_c_keeps_the_batch_being_read_and_the_viewer_agrees_with_the_record(tmp_path):
    """A real SIGINT while the driver hands out a batch: the run stops between two reads, so that batch is
    published and recorded like the others (a KeyboardInterrupt raised there would lose it) and a second Ctrl-C
    would interrupt at once (Python's handler is back)."""
    import signal

    robot = FixedRobotState(Q_HOME_RAD)
    batches = physics_batches(robot.pose, 10)

    class CtrlCSensor(ScriptedSensor):
        def read(self, timeout_s=1.0):
            batch = super().read(timeout_s)
            if len(self.delivered) == 6:
                signal.raise_signal(signal.SIGINT)  # handled before read() returns, as a Ctrl-C would be
                assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
            return batch

    published: list[events.WrenchSamples] = []
    sensor = CtrlCSensor(batches)
    monitor = LiveMonitor(sensor, robot=robot, compensator=GravityCompensator(CellTruth().calibration()),
                          listeners=[lambda e: published.append(e) if isinstance(e, events.WrenchSamples) else None],
                          record_path=tmp_path / "run.csv", batch_period_s=0.0, strict=True)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal, whatever started pytest
    try:
        summary = monitor.run()
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)
    assert summary.interrupted and summary.samples == 6 * BATCH_SAMPLES
    record = read_record(tmp_path / "run.csv")
    delivered_times = np.concatenate([b.time_s for b in sensor.delivered])
    assert record.size == delivered_times.size
    np.testing.assert_allclose(record["time_s"], delivered_times, atol=1e-6)  # the CSV keeps 9 decimals
    np.testing.assert_array_equal(np.concatenate([e.batch.time_s for e in published]), delivered_times)


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
    assert ftacq_main(["monitor", "--sim", "--seconds", "1", "--save", str(rrd_path), "--save-rate", "0"]) == 0
    assert "samples" in capsys.readouterr().out
    paths = entity_paths(rrd_path)
    assert {layout.RAW_FORCE, layout.COMPENSATED_FORCE, layout.LINK_FRAMES[5], layout.MONITOR_LOG} <= paths
    time_s, _ = read_scalars(rrd_path, layout.RAW_FORCE)
    assert time_s.size > 1000
    run_s, _ = read_scalars(rrd_path, layout.RAW_FORCE, absolute=False)
    assert 0.0 <= run_s[0] < run_s[-1] < 60.0  # seconds since the run started, not the host's uptime
    from tests.rrd_reader import count_chunks

    for entity in (layout.RAW_FORCE, layout.LABELS, layout.GRAVITY):  # a saved file: columns of 5 s, not per read
        assert 1 <= count_chunks(rrd_path, entity) <= 3, entity


def test_ftacq_monitor_with_an_unreachable_robot_leaves_no_rrd_and_never_says_view_it(tmp_path, capsys):
    """The robot refuses the connection before a sample is read: exit 1 with the reason, no .rrd (neither the
    target nor a temporary file), and no "view it with" for a file that holds nothing."""
    from ftacq.app.cli import main as ftacq_main
    from ftacq.calfile import save_calibration
    from tests.fakes.ur_process import random_loopback_address

    host = random_loopback_address()  # nothing listens there: connection refused at once
    config = tmp_path / "cell.toml"
    config.write_text(f'[robot]\nhost = "{host}"\nmodel = "UR5e"\n[sensor]\nurl = "netft://{host}"\n',
                      encoding="utf-8")
    save_calibration(tmp_path / "cal.json", CellTruth().calibration())
    rrd_path = tmp_path / "monitor.rrd"
    status = ftacq_main(["monitor", "--config", str(config), "--calibration", str(tmp_path / "cal.json"),
                         "--save", str(rrd_path)])
    err = capsys.readouterr().err
    assert status == 1 and "cannot connect" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.json", "cell.toml"]
    assert "view it" not in err and f"nothing was recorded; {rrd_path} not written" in err


CLI_WITH_DEFAULT_SIGINT = ("import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
                           "runpy.run_module('ftacq.app.cli', run_name='__main__', alter_sys=True)")
"""``python -c`` this, then the ftacq arguments: the CLI with Python's Ctrl-C handler, as in a terminal, even when
the suite itself was started with SIGINT ignored (a background job of a non-interactive shell), which a child
would otherwise inherit."""
READOUT_LINE = re.compile(r"^\s*\d+ Hz  \|F\|")
"""A line of the live readout: printed once the monitor has streamed at least 0.5 s of samples."""
DROPPED_FOR_THE_VIEWER = re.compile(r"(\d+) dropped for the viewer")


def test_ctrl_c_stops_ftacq_monitor_cleanly(tmp_path):
    """SIGINT to a live `ftacq monitor --sim`: exit 0, the .rrd and the record are complete and agree.

    SIGINT goes once the live readout printed its first line (samples are flowing through the listeners, so
    thousands were recorded), never after a fixed time; every wait has a generous deadline."""
    import os
    import signal
    import subprocess
    import sys

    rrd_path, record_path = tmp_path / "live.rrd", tmp_path / "live.csv"
    process = subprocess.Popen(
        [sys.executable, "-c", CLI_WITH_DEFAULT_SIGINT, "monitor", "--sim", "--sim-still", "--save", str(rrd_path),
         "--record", str(record_path), "--record-rate", "0", "--save-rate", "0"],  # every sample in both, compared
        cwd=Path(__file__).resolve().parents[1], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines: list[str] = []
    streaming = threading.Event()

    def read_output() -> None:
        for line in process.stdout:
            lines.append(line)
            if READOUT_LINE.match(line):
                streaming.set()
        streaming.set()  # the output ended: the process exited (checked below)

    def rows_recorded() -> int:
        """Data rows in the record being written (the temporary file; 0 before it exists or once renamed)."""
        for partial in tmp_path.glob(f".{record_path.name}.*"):
            try:
                text = partial.read_bytes()
            except FileNotFoundError:  # renamed between the listing and the read
                return 0
            return max(0, text.count(b"\n") - text.count(b"# ") - 1)  # minus the header and the column names
        return 0

    reader = threading.Thread(target=read_output, name="monitor-output", daemon=True)
    reader.start()
    try:
        wait_until(streaming.is_set, "the live readout's first line", timeout_s=120.0)
        assert process.poll() is None, "".join(lines)
        rows_before = wait_until(lambda: (rows := rows_recorded()) > 100 and rows, "rows being recorded",
                                 timeout_s=120.0)
        process.send_signal(signal.SIGINT)
        process.wait(timeout=120.0)
        reader.join(timeout=120.0)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    out = "".join(lines)
    assert process.returncode == 0, out
    assert "stopped by Ctrl-C" in out
    dropped = int(DROPPED_FOR_THE_VIEWER.findall(out)[-1])  # the summary line's figure
    record = read_record(record_path)
    time_s, _ = read_scalars(rrd_path, layout.COMPENSATED_FORCE)
    # a read with no robot state near its samples' time (a stalled state stream) is recorded uncompensated (empty
    # contact columns) and not plotted as compensated: every row is one or the other
    compensated = np.isfinite(record["contact_fx"])
    assert record.size >= rows_before and time_s.size + dropped == compensated.sum(), out
    if dropped == 0:
        np.testing.assert_allclose(time_s, record["time_s"][compensated], atol=1e-6)


def test_an_ignored_sigint_stays_ignored_and_is_said(caplog):
    """A monitor started in the background inherits SIGINT ignored (a shell without job control, nohup): it keeps
    it so, and says how to stop it instead (the benchmark runs that "did not stop on SIGINT", issue 27)."""
    import signal
    import threading

    from procedures.monitor import _stop_on_sigint

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with caplog.at_level("WARNING", logger="procedures.monitor"):
            installed = _stop_on_sigint(threading.Event(), threading.Event())
        assert not installed and signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        assert any("SIGTERM" in record.getMessage() for record in caplog.records)
    finally:
        signal.signal(signal.SIGINT, previous)


def test_the_switch_interval_is_short_while_streaming_and_given_back_after():
    """While streaming, the RTDE state reader gets the interpreter within 1 ms (issue 27: at Python's default 5 ms it
    lagged the sensor reads by 5.6 ms at the median); the caller's interval is given back at the end."""
    robot = FixedRobotState(Q_HOME_RAD)
    seen: list[float] = []

    class SwitchSeeingSensor(ScriptedSensor):
        def read(self, timeout_s=1.0):
            seen.append(sys.getswitchinterval())
            return super().read(timeout_s)

    before = sys.getswitchinterval()
    sys.setswitchinterval(0.005)
    try:
        sensor = SwitchSeeingSensor(physics_batches(robot.pose, 3))
        run_until_exhausted(LiveMonitor(sensor, robot=robot, batch_period_s=0.0), sensor)
        after = sys.getswitchinterval()
    finally:
        sys.setswitchinterval(before)
    assert seen and max(seen) <= 0.0011
    assert after == pytest.approx(0.005)


def test_the_robot_state_of_a_read_is_one_state_of_the_source():
    """A source that gives the joints and the flange pose of one state together (URStateReader) is asked once per
    read: the published joints and pose belong to the same state, never to two consecutive ones."""

    class TwoStates:
        """Its joints move between any two calls; joints_and_flange_pose answers from one."""

        def __init__(self) -> None:
            self.calls = 0

        def joint_positions(self) -> np.ndarray:
            self.calls += 1
            return np.full(6, float(self.calls))

        def flange_pose(self) -> np.ndarray:
            self.calls += 1
            return np.full(6, 10.0 * self.calls)

        def joints_and_flange_pose(self) -> tuple[np.ndarray, np.ndarray]:
            self.calls += 1
            return np.full(6, float(self.calls)), np.full(6, 10.0 * self.calls)

    robot = TwoStates()
    state = LiveMonitor(sensor=None, robot=robot)._robot_state(1.0)  # type: ignore[arg-type]
    assert state is not None and robot.calls == 1
    np.testing.assert_array_equal(state.flange_pose, 10.0 * state.joint_positions_rad)
