"""The Rerun dashboard and the live monitor, read back with Rerun's own reader (rerun.chunk.RrdReader).

Unit tests feed the monitor from :class:`ScriptedSensor` (pre-computed batches of the simulated cell's physics,
no transport); the integration tests at the bottom run the real Net F/T driver against the loopback fake.
"""

from __future__ import annotations

import argparse
import socket
from contextlib import closing as contextlib_closing
import threading
import uuid
from pathlib import Path

import numpy as np
import pytest

import rerun as rr

from drivers.sensor import SensorHealth, WrenchBatch
from ftacq.app.hints import command
from ftacq.app.dashboard import arm, layout, sinks
from ftacq.app.dashboard.listener import DashboardListener
from ftacq.app.dashboard.recorder import Dashboard
from ftacq.errors import DeviceTimeoutError
from ftacq.kinematics import flange_pose, forward_kinematics, ur_model
from procedures import events
from procedures.monitor import RECORD_COLUMNS, GravityCompensator, LiveMonitor, flange_R_base_from_pose
from tests.conftest import wait_until
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose
from tests.rrd_reader import entity_paths, mixed_static_and_temporal, read_scalars, read_texts

MODEL = ur_model("UR5e")
Q_HOME_RAD = np.array([0.3, -1.2, 1.4, -1.6, -1.5, 0.4])
RATE_HZ = 7000.0
BATCH_SAMPLES = 70
VALUE_TOLERANCE = 1e-9


def new_recording(path: Path):
    recording = rr.RecordingStream(layout.APP_ID, recording_id=uuid.uuid4())
    recording.save(path)
    return recording


class ScriptedSensor:
    """A ForceTorqueSensor that hands out pre-computed batches (no transport), then times out.

    ``delivered`` keeps every batch it returned, so a test can compare with what reached the recording.
    """

    def __init__(self, batches: list[WrenchBatch]) -> None:
        self._batches = list(batches)
        self.delivered: list[WrenchBatch] = []
        self.exhausted = threading.Event()
        self._health = SensorHealth(rate_hz=RATE_HZ)

    def read(self, timeout_s: float | None = 1.0) -> WrenchBatch:
        if not self._batches:
            self.exhausted.set()
            raise DeviceTimeoutError("scripted sensor: no more batches")
        batch = self._batches.pop(0)
        self.delivered.append(batch)
        self._health.received += len(batch)
        return batch

    def health(self) -> SensorHealth:
        return self._health.snapshot()


class FixedRobotState:
    """The latest robot state of an arm standing still at ``q_rad``."""

    def __init__(self, q_rad: np.ndarray) -> None:
        self.q_rad = np.asarray(q_rad, dtype=float)
        self.pose = flange_pose(MODEL, self.q_rad)

    def joint_positions(self) -> np.ndarray:
        return self.q_rad.copy()

    def flange_pose(self) -> np.ndarray:
        return self.pose.copy()


def physics_batches(pose: np.ndarray, count: int, seed: int = 1, contact_after: int | None = None) -> list[WrenchBatch]:
    """Return ``count`` batches of the simulated cell's sensor at ``pose``; a 5 N push from batch ``contact_after``."""
    truth = CellTruth()
    physics = SensorPhysics(truth, SettablePose(pose), seed=seed)
    batches = []
    for k in range(count):
        if contact_after is not None and k == contact_after:
            physics.contact_wrench = np.array([0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
        wrench = physics.sample(BATCH_SAMPLES)
        start = k * BATCH_SAMPLES
        batches.append(WrenchBatch(
            time_s=1000.0 + (start + np.arange(BATCH_SAMPLES)) / RATE_HZ,
            wrench=wrench,
            counts=np.round(wrench * 1e6).astype(np.int64),
            status=np.zeros(BATCH_SAMPLES, dtype=np.uint32),
            sequence=start + np.arange(BATCH_SAMPLES, dtype=np.int64),
            saturated=np.zeros(BATCH_SAMPLES, dtype=bool),
        ))
    return batches


def dashboard_listener(recording, model=MODEL) -> DashboardListener:
    """The dashboard as the monitor's listener, strict (a Rerun misuse fails the test)."""
    return DashboardListener(Dashboard(recording, strict=True), model=model)


def read_record(path: Path) -> np.ndarray:
    """Read a monitor record CSV (``#`` comment lines, then a header) as a structured array."""
    lines = [line for line in Path(path).read_text().splitlines() if not line.startswith("#")]
    return np.genfromtxt(lines, delimiter=",", names=True)


# ----------------------------------------------------------------------------------------------------------------
# Dashboard
# ----------------------------------------------------------------------------------------------------------------


def test_wrench_batches_round_trip_through_an_rrd_file(tmp_path):
    path = tmp_path / "wrench.rrd"
    recording = new_recording(path)
    dashboard = Dashboard(recording, strict=True)
    rng = np.random.default_rng(3)
    times = 50.0 + np.arange(3 * BATCH_SAMPLES) / RATE_HZ
    raw = rng.normal(size=(times.size, 6)) * [10, 20, 30, 0.1, 0.2, 0.3]
    compensated = raw - [1, 2, 3, 0.01, 0.02, 0.03]
    for k in range(3):
        rows = slice(k * BATCH_SAMPLES, (k + 1) * BATCH_SAMPLES)
        dashboard.log_wrench_batch(times[rows], raw[rows], compensated[rows])
    sinks.close_recording(recording)

    for entity, expected in ((layout.RAW_FORCE, raw[:, :3]), (layout.RAW_TORQUE, raw[:, 3:]),
                             (layout.COMPENSATED_FORCE, compensated[:, :3]),
                             (layout.COMPENSATED_TORQUE, compensated[:, 3:])):
        time_s, values = read_scalars(path, entity)
        assert values.shape == expected.shape, entity
        np.testing.assert_allclose(time_s, times, atol=1e-9)
        np.testing.assert_allclose(values, expected, atol=VALUE_TOLERANCE)
    assert layout.CONTACT_FORCE in entity_paths(path)


def test_recording_carries_the_blueprint_and_fixed_axis_styles(tmp_path):
    from rerun.chunk import RrdReader

    path = tmp_path / "layout.rrd"
    recording = new_recording(path)
    Dashboard(recording, strict=True)
    sinks.close_recording(recording)

    reader = RrdReader(path)
    assert len(reader.blueprints()) == 1
    styles = {}
    for chunk in reader.stream().to_chunks():
        batch = chunk.to_record_batch()
        if chunk.is_static and "SeriesLines:names" in batch.schema.names:
            styles[chunk.entity_path.lstrip("/")] = batch.column("SeriesLines:names").to_pylist()[0]
    assert styles[layout.RAW_FORCE] == list(layout.FORCE_AXES)
    assert styles[layout.COMPENSATED_TORQUE] == list(layout.TORQUE_AXES)


def test_strict_dashboard_raises_on_misuse(tmp_path):
    recording = new_recording(tmp_path / "strict.rrd")
    dashboard = Dashboard(recording, strict=True)
    with pytest.raises(ValueError):  # a time column and value columns of different lengths
        dashboard.log_wrench_batch(np.arange(3.0), np.zeros((4, 6)), None)
    sinks.close_recording(recording)


def test_arm_polyline_ends_at_the_flange():
    skeleton = arm.arm_polyline(MODEL, Q_HOME_RAD)
    assert skeleton.shape == (13, 3)
    np.testing.assert_allclose(skeleton[0], 0.0)
    np.testing.assert_allclose(skeleton[-1], forward_kinematics(MODEL, Q_HOME_RAD)[:3, 3], atol=1e-9)
    np.testing.assert_allclose(skeleton[1], [0.0, 0.0, MODEL.d[0]], atol=1e-12)  # shoulder height


def test_static_link_shapes_placed_by_the_frames_follow_the_chain():
    """Each link's shape is fixed in its own DH frame: placed by base_T_i it joins frame i-1 to frame i."""
    rng = np.random.default_rng(11)
    shapes = arm.link_shapes(MODEL)
    for q in rng.uniform(-np.pi, np.pi, size=(5, 6)):
        frames = arm.link_frames(MODEL, q)[0]
        previous_origin = np.zeros(3)
        for i in range(6):
            placed = shapes[i] @ frames[i][:3, :3].T + frames[i][:3, 3]
            np.testing.assert_allclose(placed[0], previous_origin, atol=1e-12)  # starts at frame i-1
            np.testing.assert_allclose(placed[2], frames[i][:3, 3], atol=1e-12)  # ends at frame i
            previous_origin = frames[i][:3, 3]
        np.testing.assert_allclose(frames[5], forward_kinematics(MODEL, q), atol=1e-12)


@pytest.mark.parametrize("contact_n", [
    (0.0, 0.0, 0.0),  # no contact: its label must not sit on the weight's shaft
    (0.0, 0.0, -14.7),  # a push exactly like the weight
    (0.0, 0.0, -30.0),  # a longer one along the weight: it runs through the weight's tip
    (0.0, 0.0, 15.0), (6.0, 0.0, -15.0), (0.5, 0.2, 0.1),
])
def test_force_labels_never_overlap_each_other_or_sit_on_an_arrow(contact_n):
    scale = layout.FORCE_ARROW_SCALE_M_PER_N
    origin = np.array([0.4, -0.2, 0.5])
    weight = np.array([0.0, 0.0, -14.7]) * scale
    contact = np.array(contact_n) * scale
    anchors = arm.label_anchors(origin, weight, contact)

    def distance_to_segment(point, vector):
        t = np.clip((point - origin) @ vector / max(vector @ vector, 1e-12), 0.0, 1.0)
        return np.linalg.norm(point - (origin + t * vector))

    assert np.linalg.norm(anchors[0] - anchors[1]) >= layout.LABEL_MIN_SEPARATION_M - 1e-12
    for anchor in anchors:
        for vector in (weight, contact):
            assert distance_to_segment(anchor, vector) >= layout.LABEL_CLEARANCE_M - 1e-12


def test_the_arm_is_recorded_as_static_shapes_and_per_time_frames(tmp_path):
    """A recording shows the arm as recorded: link shapes static (whatever the time cursor), the six frames as
    transforms in time columns; the arrows carry no label of their own (the labels are placed apart)."""
    from tests.rrd_reader import count_chunks, read_column, static_paths

    path = tmp_path / "arm.rrd"
    recording = new_recording(path)
    listener = dashboard_listener(recording)
    listener.set_calibration(CellTruth().calibration())
    qs = Q_HOME_RAD + 0.2 * np.sin(np.linspace(0, 3, 60))[:, None]
    times = 500.0 + np.arange(60) / 30.0
    for t, q in zip(times, qs):  # 2 s of robot states at 30 Hz, as the monitor publishes them
        listener(events.RobotState(float(t), q, flange_pose(MODEL, q)))
    listener.flush()
    sinks.close_recording(recording)

    assert set(layout.LINK_SHAPES) <= static_paths(path, "LineStrips3D:strips")
    for i, frame in enumerate(layout.LINK_FRAMES):
        time_s, translations = read_column(path, frame, "Transform3D:translation")
        np.testing.assert_allclose(time_s, times, atol=1e-9)
        expected = np.array([arm.link_frames(MODEL, q)[0][i][:3, 3] for q in qs])
        np.testing.assert_allclose(np.array(translations).reshape(-1, 3), expected, atol=1e-6)  # float32
        assert count_chunks(path, frame) <= 60 * 0.25  # columns of several states, not one chunk per state
    _, labels = read_column(path, layout.LABELS, "Points3D:labels")
    assert len(labels) == 60 and all(len(row) == 2 and row[0].startswith("tool weight") for row in labels)
    assert not static_paths(path, "Arrows3D:labels") and not read_column(path, layout.GRAVITY, "Arrows3D:labels")[1]


def test_listener_draws_plan_measurements_and_residuals(tmp_path):
    path = tmp_path / "procedure.rrd"
    recording = new_recording(path)
    dashboard = Dashboard(recording, strict=True)
    clock = iter(np.arange(100.0, 200.0, 0.5))
    listener = DashboardListener(dashboard, model=MODEL, clock_s=lambda: float(next(clock)))
    rng = np.random.default_rng(5)
    qs = Q_HOME_RAD + 0.3 * rng.normal(size=(6, 6))
    poses = np.array([flange_pose(MODEL, q) for q in qs])
    labels = ("A01", "A02", "E01", "E02", "V01", "V02")
    sets = ("A", "A", "E", "E", "V", "V")
    truth = CellTruth()
    listener(events.PlanReady(poses, qs, labels, sets, estimated_duration_s=60.0, joint_travel_rad=4.0))
    means = rng.normal(size=(4, 6))
    for index in range(4):
        listener(events.StateChanged("moving", index))
        listener(events.PoseMeasured(index, labels[index], sets[index], poses[index], qs[index], means[index],
                                     np.full(6, 0.01), count=700, saturated=0, lost=0))
    residuals = rng.normal(size=(4, 6)) * 0.01
    listener(events.Identified(truth.calibration(), labels[:4], residuals))
    listener(events.Validated(labels[4:], rng.normal(size=(2, 6)) * 0.01))
    listener(events.StateChanged("done"))
    sinks.close_recording(recording)

    paths = entity_paths(path)
    for expected in (f"{layout.PLAN}/A", f"{layout.PLAN}/E", f"{layout.PLAN}/V", layout.CURRENT_POSE,
                     layout.RESIDUAL_FORCE_NORM, layout.VALIDATION_FORCE_NORM, layout.CALIBRATION_LOG, layout.SENSOR,
                     layout.LINK_FRAMES[5], layout.FLANGE):
        assert expected in paths, expected
    _, measured_force = read_scalars(path, layout.MEASURED_FORCE)
    np.testing.assert_allclose(measured_force, means[:, :3], atol=VALUE_TOLERANCE)
    _, residual_torque = read_scalars(path, layout.RESIDUAL_TORQUE)
    np.testing.assert_allclose(residual_torque, residuals[:, 3:], atol=VALUE_TOLERANCE)


def test_listener_swallows_errors_unless_strict(tmp_path):
    recording = new_recording(tmp_path / "errors.rrd")
    bad_event = events.Identified(CellTruth().calibration(), ("A01",), residuals=np.zeros(5))  # not (N, 6)
    DashboardListener(Dashboard(recording, strict=False))(bad_event)  # logged, not raised
    with pytest.raises(ValueError):
        DashboardListener(Dashboard(recording, strict=True))(bad_event)
    sinks.close_recording(recording)


# ----------------------------------------------------------------------------------------------------------------
# Sink selection
# ----------------------------------------------------------------------------------------------------------------


def sink_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    sinks.add_sink_args(parser)
    return parser.parse_args(argv)


def test_headless_default_saves_an_rrd_and_says_how_to_view_it(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sinks.sys, "platform", "linux")
    choice = sinks._choose_sink(sink_args([]), layout.APP_ID)
    assert choice.kind == "save"
    assert choice.target.endswith(".rrd") and Path(choice.target).parent == Path("runs")
    assert command("rerun", Path(choice.target)) in choice.message  # absolute, runs as printed


def test_sink_flags_pick_the_sink_and_exclude_each_other(tmp_path):
    assert sinks._choose_sink(sink_args(["--save", str(tmp_path / "x.rrd")]), layout.APP_ID).kind == "save"
    connect = sinks._choose_sink(sink_args(["--connect"]), layout.APP_ID)
    assert (connect.kind, connect.target) == ("connect", "rerun+http://127.0.0.1:9876/proxy")
    serve = sinks._choose_sink(sink_args(["--serve", "--web-port", "9123"]), layout.APP_ID)
    assert serve.kind == "serve" and "http://127.0.0.1:9123/" in serve.message
    with pytest.raises(SystemExit):
        sink_args(["--serve", "--save", "x.rrd"])


def test_open_recording_with_save_writes_the_file(tmp_path):
    path = tmp_path / "sub" / "run.rrd"
    lines = []
    recording = sinks.open_recording(sink_args(["--save", str(path)]), announce=lines.append)
    Dashboard(recording, strict=True).log_text("hello")
    sinks.close_recording(recording)
    assert path.is_file() and layout.MONITOR_LOG in entity_paths(path)
    assert lines == [f"rerun: saving to {path}; view it with: {command('rerun', path)}"]
    viewer = command("rerun", path).split(" ")[0]  # runs as printed: the viewer beside this Python, or on PATH
    assert viewer == "rerun" or Path(viewer).is_file()


# ----------------------------------------------------------------------------------------------------------------
# Live monitor (scripted sensor)
# ----------------------------------------------------------------------------------------------------------------


def run_until_exhausted(monitor: LiveMonitor, sensor: ScriptedSensor):
    stop = threading.Event()
    watcher = threading.Thread(target=lambda: (sensor.exhausted.wait(30.0), stop.set()), name="test-watcher")
    watcher.start()
    try:
        return monitor.run(stop=stop)
    finally:
        stop.set()
        sensor.exhausted.set()
        watcher.join()


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


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


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


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="reads the listening sockets from Linux /proc")
def test_serve_hosts_the_web_viewer_on_localhost_only_and_stops_it():
    grpc_port, web_port = free_port(), free_port()
    lines = []
    recording = sinks.open_recording(
        sink_args(["--serve", "--no-browser", "--viewer-port", str(grpc_port), "--web-port", str(web_port)]),
        announce=lines.append)
    process, web_url = sinks._WEB_SERVERS[id(recording)]
    Dashboard(recording, strict=True).log_text("hello")
    ports = (f":{grpc_port:04X}", f":{web_port:04X}")

    def listening() -> set[str]:
        rows = (line.split() for line in Path("/proc/net/tcp").read_text().splitlines()[1:])
        return {fields[1] for fields in rows if fields[3] == "0A" and fields[1].endswith(ports)}  # 0A = LISTEN

    assert listening() == {f"0100007F{port}" for port in ports}  # 127.0.0.1 only, not 0.0.0.0
    native = command("rerun", f"rerun+http://127.0.0.1:{grpc_port}/proxy")
    assert lines == [f"rerun: web viewer at {web_url} (native: {native})"]
    sinks.close_recording(recording, wait_while_serving=False)
    assert process.poll() is not None and id(recording) not in sinks._WEB_SERVERS
    wait_until(lambda: not listening(), "the server binary (the wrapper's child) to close its ports")


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
