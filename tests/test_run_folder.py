"""The run folder: run.json, poses.csv appended one fsync'd row at a time, reopened for --resume."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ftacq.app.config import CellConfig
from ftacq.errors import InputError
from ftacq.posefile import POSE_CSV_HEADER, read_pose_csv
from procedures import events
from procedures.calibration_procedure import Identify, Measure, Move, Validate, calibration_steps, count_measurements
from procedures.plan import Plan, PlanSettings
from procedures.measured import drift_label
from procedures.run_folder import RUN_JSON, RunFolder, RunFolderWriter

LABELS = ("A01", "E01", "V01", "E02")
SETS = ("A", "E", "V", "E")


def small_plan() -> Plan:
    poses = np.array([[0.3 + 0.01 * i, -0.2, 0.4, np.pi, 0.1 * i, 0.0] for i in range(4)])
    return Plan(poses=poses, joint_targets_rad=np.arange(24.0).reshape(4, 6) * 0.01, labels=LABELS, set_names=SETS,
                rejected=(("E03", "unreachable"),), estimated_duration_s=12.5, joint_travel_rad=3.0,
                listing_travel_rad=5.0, settings=PlanSettings(random_count=2, validation_count=1),
                center_m=(0.3, -0.2, 0.4), branch="shoulder -, elbow +, wrist -", start_q_rad=(0.0,) * 6)


def measured_event(i: int, label: str | None = None, set_name: str | None = None) -> events.PoseMeasured:
    return events.PoseMeasured(
        index=i, label=label or LABELS[i], set_name=set_name or SETS[i], pose=small_plan().poses[i],
        joint_positions_rad=np.full(6, 0.1 * i), mean=np.array([1.0, -2.0, 3.0, 0.1, -0.2, 0.3]) * (i + 1) + 1e-13,
        std=np.array([0.05, 0.05, 0.08, 0.002, 0.002, 0.0015]), count=500 + i, saturated=i, lost=2 * i,
        t_start_s=1.7e9 + i, t_end_s=1.7e9 + i + 0.5)


def test_create_writes_run_json_and_a_header_only_pose_record(tmp_path):
    plan = small_plan()
    folder = RunFolder.create(tmp_path, CellConfig().to_dict(), plan.to_json(), name="run1")
    document = json.loads((tmp_path / "run1" / RUN_JSON).read_text())
    assert document["format"] == "ftacq-run" and document["status"] == "planned"
    assert document["software_version"]
    assert document["labels"] == list(LABELS) and document["set_names"] == list(SETS)
    assert document["config"]["robot"]["model"] == "UR5e"
    assert Plan.from_json(folder.plan_json).labels == LABELS
    assert (tmp_path / "run1" / "poses.csv").read_text() == POSE_CSV_HEADER
    assert folder.measured() == {}
    with pytest.raises(InputError, match="already exists"):
        RunFolder.create(tmp_path, {}, plan.to_json(), name="run1")
    second = RunFolder.create(tmp_path, {}, plan.to_json())  # default names are made unique
    third = RunFolder.create(tmp_path, {}, plan.to_json())
    assert second.path != third.path


def test_rows_are_appended_at_once_and_read_back_exactly(tmp_path):
    folder = RunFolder.create(tmp_path, CellConfig().to_dict(), small_plan().to_json(), name="r")
    writer = RunFolderWriter(folder)
    writer(events.StateChanged("moving", 0))
    writer(measured_event(0))
    # the row is on disk before the next event: another reader sees it now
    record = read_pose_csv(tmp_path / "r" / "poses.csv")
    assert record.labels == ("A01",) and record.sets == ("A",)
    np.testing.assert_array_equal(record.wrench[0], measured_event(0).mean)  # full float64 precision
    writer(measured_event(1))
    writer(measured_event(2))
    measured = RunFolder.open(tmp_path / "r").measured()
    assert list(measured) == ["A01", "E01", "V01"]
    assert measured["V01"].count == 502 and measured["V01"].set_name == "V"
    np.testing.assert_array_equal(measured["E01"].pose, small_plan().poses[1])
    np.testing.assert_array_equal(measured["E01"].std, measured_event(1).std)
    assert measured["E01"].t_end_s == pytest.approx(1.7e9 + 1.5)
    record = folder.read_record()
    np.testing.assert_array_equal(record.extra["q0"], [0.0, 0.1, 0.2])
    np.testing.assert_array_equal(record.extra["lost"], [0, 2, 4])
    assert json.loads((tmp_path / "r" / RUN_JSON).read_text())["status"] == "running"


def test_status_and_results_go_to_run_json(tmp_path):
    folder = RunFolder.create(tmp_path, {}, small_plan().to_json(), name="r")
    writer = RunFolderWriter(folder)
    writer(events.DriftChecked("A01", np.array([0.1, 0, 0, 0, 0, 0.001]), 42.0, "too much"))
    writer(events.Validated(("V01",), np.zeros((1, 6)), np.arange(6.0), np.ones(6)))
    writer(events.StateChanged("failed", 2, "ProtectiveStopError at pose 3/4"))
    document = json.loads((tmp_path / "r" / RUN_JSON).read_text())
    assert document["status"] == "failed" and "ProtectiveStopError" in document["message"]
    assert [h["status"] for h in document["history"]] == ["planned", "failed"]
    assert document["drift_check"]["elapsed_s"] == 42.0 and document["drift_check"]["warning"] == "too much"
    assert document["validation"]["max_abs"] == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    assert RunFolder.open(tmp_path / "r").status == "failed"


def test_a_torn_last_line_is_dropped_on_resume(tmp_path):
    folder = RunFolder.create(tmp_path, {}, small_plan().to_json(), name="r")
    folder.append_pose(measured_event(0))
    folder.append_pose(measured_event(1))
    csv_path = tmp_path / "r" / "poses.csv"
    text = csv_path.read_text()
    csv_path.write_text(text + "V01,V,0.31,-0.2,0.4,3.1")  # the process died in the middle of a row
    reopened = RunFolder.open(tmp_path / "r")
    assert list(reopened.measured()) == ["A01", "E01"]
    assert csv_path.read_text() == text
    reopened.append_pose(measured_event(2))
    assert list(RunFolder.open(tmp_path / "r").measured()) == ["A01", "E01", "V01"]


def test_open_refuses_what_is_not_a_run_folder(tmp_path):
    with pytest.raises(InputError, match="no such folder"):
        RunFolder.open(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="run.json: missing"):
        RunFolder.open(tmp_path / "empty")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / RUN_JSON).write_text("{not json")
    with pytest.raises(InputError, match="cannot read"):
        RunFolder.open(tmp_path / "bad")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / RUN_JSON).write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(InputError, match="not an ftacq run file"):
        RunFolder.open(tmp_path / "other")


def test_steps_skip_measured_poses_and_end_with_the_drift_revisit():
    plan = small_plan()
    steps = list(calibration_steps(plan))
    kinds = [type(s).__name__ for s in steps]
    assert kinds == ["Move", "Measure"] * 5 + ["Identify", "Validate"]
    assert [s.label for s in steps if isinstance(s, Measure)] == [*LABELS, drift_label("A01")]
    assert steps[-4].purpose == "drift" and steps[-3].set_name == "D"
    np.testing.assert_array_equal(steps[-4].joint_target_rad, plan.joint_targets_rad[0])
    resumed = list(calibration_steps(plan, measured={"A01", "E01"}))
    assert [s.label for s in resumed if isinstance(s, Move)] == ["V01", "E02", "A01"]
    assert isinstance(resumed[-2], Identify) and isinstance(resumed[-1], Validate)
    assert count_measurements(plan, {"A01", "E01"}) == 3
    assert count_measurements(plan, {*LABELS, drift_label("A01")}) == 0
    assert count_measurements(plan, (), drift_check=False) == 4


def test_drift_revisit_moves_to_the_plans_checked_revisit_target():
    import dataclasses

    plan = small_plan()
    other = tuple(float(v) for v in np.asarray(plan.joint_targets_rad[0]) + np.array([0, 0, 0, 0, 0, 2 * np.pi]))
    plan = dataclasses.replace(plan, revisit_target_rad=other)
    drift = [s for s in calibration_steps(plan) if isinstance(s, Move) and s.purpose == "drift"]
    assert len(drift) == 1
    np.testing.assert_array_equal(drift[0].joint_target_rad, np.array(other))
    first = next(s for s in calibration_steps(plan) if isinstance(s, Move))
    np.testing.assert_array_equal(first.joint_target_rad, plan.joint_targets_rad[0])


def test_progress_lines_without_a_terminal():
    import io

    from procedures.progress import ProgressListener

    clock = iter([0.0, 10.0, 20.0, 20.0, 20.0, 20.0])
    stream = io.StringIO()
    progress = ProgressListener(total=4, estimated_s=100.0, stream=stream, clock_s=lambda: next(clock),
                                force_terminal=False)
    assert progress.eta_s() == 100.0  # before the first pose: the plan's estimate
    progress(events.StateChanged("moving", 0))
    progress(measured_event(0))
    progress(measured_event(1))
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("pose 1/4 A01 (A) measured: 500 samples, ETA 0:30")  # 10 s per pose, 3 left
    assert lines[1].startswith("pose 2/4 E01 (E) measured: 501 samples, ETA 0:20")
    progress(events.StateChanged("failed", 1, "x"))
    progress.close()  # safe twice


def test_progress_counts_agree_with_the_stop_message_on_a_resumed_run():
    """A resumed run counts the whole plan (bar 2/5 after two of five, not 0/3) and names the pose by its label,
    as the procedure's stop message does ("pose 3/5 (V01)")."""
    import io

    from procedures.progress import ProgressListener

    stream = io.StringIO()
    progress = ProgressListener(total=5, estimated_s=30.0, stream=stream, clock_s=lambda: 0.0,
                                force_terminal=False, done=2)
    progress(events.StateChanged("moving", 2, label="V01", measured=2, total=5))
    assert progress._where() == "moving V01 (pose 3/5)"
    progress(measured_event(2))
    assert stream.getvalue().splitlines()[0].startswith("pose 3/5 V01 (V) measured")
    progress.close()


def test_progress_of_a_recorded_motion_counts_waypoints_with_an_eta():
    """A motion (the excitation, the quick run) has no measured poses: one line per move, the ETA from the time
    per waypoint reached (3 s each here)."""
    import io

    from procedures.progress import ProgressListener

    now = [0.0]
    stream = io.StringIO()
    progress = ProgressListener(total=4, estimated_s=8.0, stream=stream, clock_s=lambda: now[0],
                                force_terminal=False, motion="excitation")
    for k in range(3):
        progress(events.StateChanged("moving", k, label=f"W{k + 1:02d}", measured=k, total=4))
        now[0] += 3.0
    assert stream.getvalue().splitlines() == ["excitation: waypoint 1/4 W01, ETA 0:08",
                                              "excitation: waypoint 2/4 W02, ETA 0:09",
                                              "excitation: waypoint 3/4 W03, ETA 0:06"]
    assert progress._where() == "moving W03 (waypoint 3/4)"
    progress(events.StateChanged("done", None, measured=4, total=4))


def test_stop_message_counts_like_the_progress_display():
    from procedures.calibration_procedure import CalibrationProcedure, ProcedureOptions

    plan = small_plan()  # 4 poses + the drift-check revisit = 5 measurements
    seen = []
    procedure = CalibrationProcedure(plan, robot=None, sensor=None, options=ProcedureOptions(),
                                     listeners=[seen.append], measured={})
    procedure.measured = {label: None for label in plan.labels[:2]}  # two measured (as after a resume)
    procedure._index, procedure._label, procedure.state = 2, plan.labels[2], "moving"
    assert procedure._where() == f"at pose 3/5 ({plan.labels[2]}) while moving"
    procedure._enter("settling", 2)
    assert seen[-1].label == plan.labels[2] and (seen[-1].measured, seen[-1].total) == (2, 5)


def test_calibrate_needs_a_source(capsys):
    from ftacq.app.cli import main

    assert main(["calibrate"]) == 2
    assert "--config CELL.toml, --sim, or --resume RUN_DIR" in capsys.readouterr().err


def test_report_of_a_failed_run_lists_what_was_measured(tmp_path):
    from procedures.calibration_procedure import ProcedureResult
    from procedures.run_report import write_report

    folder = RunFolder.create(tmp_path, CellConfig().to_dict(), small_plan().to_json(), name="r")
    folder.append_pose(measured_event(0))
    folder.append_pose(measured_event(1))
    result = ProcedureResult(status="failed", message="ProtectiveStopError at pose 3/4 (V01) while moving: stop",
                             measured=folder.measured(), warnings=["something to know"])
    path = write_report(folder.path, result, small_plan(), CellConfig().to_dict())
    text = path.read_text(encoding="utf-8")
    assert "status: **failed** — ProtectiveStopError at pose 3/4" in text
    assert "poses measured: 2 of 4 planned" in text
    assert "- something to know" in text
    assert "| A01 | A | 500 |" in text and "| E01 | E | 501 |" in text
    assert "## Identified parameters" not in text
    assert [p.name for p in folder.path.glob("*.png")] == ["wrench_per_pose.png"]  # raw wrenches, kept
    assert "![raw wrench](wrench_per_pose.png)" in text
    assert (folder.path / "wrench_per_pose.png").read_bytes().startswith(b"\x89PNG")
