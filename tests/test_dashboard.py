"""The Rerun dashboard: the recorder, the arm and label geometry, the listener and the viewer sinks, read back with
Rerun's own reader (tests/rrd_reader.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from ftacq.app.dashboard import arm, layout, sinks
from ftacq.app.dashboard.listener import DashboardListener
from ftacq.app.dashboard.recorder import Dashboard
from ftacq.app.hints import command
from ftacq.kinematics import flange_pose, forward_kinematics
from procedures import events
from tests.conftest import wait_until
from tests.fakes.world import CellTruth
from tests.rrd_reader import entity_paths, read_scalars
from tests.scripted import MODEL, Q_HOME_RAD, RATE_HZ, BATCH_SAMPLES, VALUE_TOLERANCE, dashboard_listener, free_port, \
    new_recording


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


def test_headless_default_saves_an_rrd_and_says_where(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sinks.sys, "platform", "linux")
    choice = sinks._choose_sink(sink_args([]), layout.APP_ID)
    assert choice.kind == "save"
    assert choice.target.endswith(".rrd") and Path(choice.target).parent == Path("runs")
    assert f"recording to {choice.target}" in choice.message
    assert "view it" not in choice.message  # said when the file exists (close_recording)


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
    assert not path.exists()  # written to a temporary file, renamed when closed
    sinks.close_recording(recording)
    assert path.is_file() and layout.MONITOR_LOG in entity_paths(path)
    assert sorted(p.name for p in path.parent.iterdir()) == ["run.rrd"]
    assert lines == [f"rerun: recording to {path} (written when the run ends)",
                     f"rerun: saved {path}; view it with: {command('rerun', path)}"]
    viewer = command("rerun", path).split(" ")[0]  # runs as printed: the viewer beside this Python, or on PATH
    assert viewer == "rerun" or Path(viewer).is_file()


def test_a_saved_recording_that_recorded_nothing_leaves_no_file_and_says_so(tmp_path):
    """A run that fails before its first sample (the robot unreachable) writes no empty .rrd and never says
    "view it with"."""
    path = tmp_path / "run.rrd"
    lines = []
    recording = sinks.open_recording(sink_args(["--save", str(path)]), announce=lines.append)
    Dashboard(recording, strict=True).set_calibration(CellTruth().calibration())  # layout and static data only
    sinks.close_recording(recording)
    assert list(tmp_path.iterdir()) == []
    assert lines[-1] == f"rerun: nothing was recorded; {path} not written"
    assert not any("view it" in line for line in lines)


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


# ----------------------------------------------------------------------------------------------------------------
# Time axis, chunks, the bridge's layout
# ----------------------------------------------------------------------------------------------------------------


def test_the_time_axis_reads_seconds_since_the_run_started(tmp_path):
    """The timeline holds seconds since the dashboard's origin (not the host's uptime: the viewer printed
    "+1h 19m 40s" under every plot); the origin is kept in the recording, so the host times come back."""
    from tests.rrd_reader import time_origin_s

    path = tmp_path / "time.rrd"
    recording = new_recording(path)
    dashboard = Dashboard(recording, strict=True, origin_s=86_400.0)  # a day of uptime
    times = 86_400.5 + np.arange(3 * BATCH_SAMPLES) / RATE_HZ
    dashboard.log_wrench_batch(times, np.ones((times.size, 6)), None)
    dashboard.log_text("hello", time_s=86_401.0)
    sinks.close_recording(recording)

    run_s, _ = read_scalars(path, layout.RAW_FORCE, absolute=False)
    np.testing.assert_allclose(run_s, times - 86_400.0, atol=1e-9)
    assert time_origin_s(path) == 86_400.0
    np.testing.assert_allclose(read_scalars(path, layout.RAW_FORCE)[0], times, atol=1e-9)


def test_streams_are_sent_as_columns_of_the_send_period_not_one_chunk_per_read(tmp_path):
    """3 s of 7 kHz samples in 150 reads: a chunk per plot per second, not per read (a file of one chunk per
    read loaded so slowly that the viewer showed the arrows and labels seconds late); nothing is lost at close."""
    from tests.rrd_reader import count_chunks

    path = tmp_path / "chunks.rrd"
    recording = new_recording(path)
    listener = DashboardListener(Dashboard(recording, strict=True, send_period_s=1.0), model=MODEL)
    listener.set_calibration(CellTruth().calibration())
    times = 10.0 + np.arange(21_000) / 7000.0
    wrench = np.random.default_rng(7).normal(size=(times.size, 6))
    for rows in np.array_split(np.arange(times.size), 150):
        listener.dashboard.log_wrench_batch(times[rows], wrench[rows], wrench[rows] * 0.1)
        t = float(times[rows][-1])
        listener(events.RobotState(t, Q_HOME_RAD, flange_pose(MODEL, Q_HOME_RAD)))
    sinks.close_recording(recording)  # sends what the dashboard still holds

    stored_s, stored = read_scalars(path, layout.RAW_FORCE)
    np.testing.assert_allclose(stored_s, times, atol=1e-9)
    np.testing.assert_allclose(stored, wrench[:, :3], atol=VALUE_TOLERANCE)
    for entity in (layout.RAW_FORCE, layout.COMPENSATED_TORQUE, layout.LABELS, layout.GRAVITY, layout.CONTACT_FORCE,
                   layout.LINK_FRAMES[5]):
        assert 1 <= count_chunks(path, entity) <= 5, entity  # (a static style chunk, then one per second)


def test_the_bridge_recording_shows_the_fed_wrench_and_a_posed_arm(tmp_path):
    """ftacq bridge's layout: every plot is one the bridge fills (the fed force and torque, the joints; no empty
    raw/compensated plots), and the arm is posed from the joint angles of the cycles it fed."""
    from tests.rrd_reader import blueprint_views, read_column

    path = tmp_path / "bridge.rrd"
    recording = new_recording(path)
    listener = DashboardListener(Dashboard(recording, strict=True, view="bridge"), model=MODEL)
    times = 20.0 + np.arange(1000) / 500.0  # 2 s of controller cycles at 500 Hz
    qs = Q_HOME_RAD + 0.3 * np.sin(np.linspace(0.0, 2.0, times.size))[:, None]
    fed = np.column_stack([np.sin(times), np.cos(times), times - 20.0, 0.1 * np.sin(times), 0.0 * times,
                           0.0 * times])
    for rows in np.array_split(np.arange(times.size), 20):  # ten events a second, as Bridge publishes
        listener(events.FedWrenches(time_s=times[rows], fed=fed[rows], cycles=rows.size, written=rows.size,
                                    joint_positions_rad=qs[rows]))
    sinks.close_recording(recording)

    views = blueprint_views(path)
    plots = {origin for kind, origin in views.values() if kind == "TimeSeries"}
    assert plots == {layout.FED_FORCE, layout.FED_TORQUE, layout.JOINT_ANGLES}
    assert any(name.startswith("fed to the controller: force") for name in views)
    assert plots <= entity_paths(path)  # no empty plot
    stored_s, stored = read_scalars(path, layout.FED_FORCE)
    np.testing.assert_allclose(stored_s, times, atol=1e-9)
    np.testing.assert_allclose(stored, fed[:, :3], atol=VALUE_TOLERANCE)
    arm_s, translations = read_column(path, layout.LINK_FRAMES[5], "Transform3D:translation")
    assert 50 <= arm_s.size <= 61  # thinned to 30 Hz
    kept = np.searchsorted(times, arm_s - 1e-6)  # the cycle each state was drawn from
    np.testing.assert_allclose(times[kept], arm_s, atol=1e-9)
    expected = arm.link_frames(MODEL, qs[kept])[:, 5, :3, 3]
    np.testing.assert_allclose(np.array(translations).reshape(-1, 3), expected, atol=1e-6)
