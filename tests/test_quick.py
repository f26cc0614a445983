"""The quick calibration's trajectory and verdict (procedures/quick.py, procedures/quick_analysis.py).

The designed trajectory, sampled densely, stays within the CELL.toml speed and acceleration and clear of the
collision model at every sample; the verdict on the still validation poses passes the right tool and fails a
wrong one (a 0.2 kg part left in the gripper during the validation holds, unknown to the fit)."""

import numpy as np
import pytest

from procedures.quick_analysis import quick_verdict
from ftacq.app.commands.quick_stage import refuse_resume
from ftacq.dynamics import MotionRecord
from ftacq.dynamics.joint import identify_joint
from ftacq.errors import InputError
from ftacq.kinematics import planning_limits_rad
from ftacq.mounts import mount_of
from procedures.plan import collision_checker, home_configuration_rad
from procedures.quick import (DEFAULT_BUDGET_S, FIT, VALIDATE, QuickPlan, QuickRecording, design_quick,
                              sample_trajectory)
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose
from tests.test_quick_identify import settings_for

RATE_HZ = 500.0


@pytest.fixture(scope="module")
def designed():
    settings = settings_for()
    return settings, design_quick(settings, home_configuration_rad("floor"))


def test_trajectory_stays_within_limits_and_clear_along_its_whole_path(designed):
    settings, plan = designed
    _, q, qd, qdd, _ = sample_trajectory(plan.start_q_rad, plan.waypoints_rad, plan.hold_s, plan.speed_rad_s,
                                         plan.acceleration_rad_s2, 200.0)
    assert np.max(np.abs(qd)) <= settings.joint_speed_rad_s + 1e-9
    assert np.max(np.abs(qdd)) <= settings.joint_acceleration_rad_s2 + 1e-9
    checker = collision_checker(settings)
    clearance = checker.clearances(q)  # every sample at once: the constraints problems_at checks one by one
    worst = np.unravel_index(np.argmin(clearance), clearance.shape)
    assert clearance[worst] >= 0.0, checker.problems_at(q[worst[0]])
    lower, upper = planning_limits_rad(settings.ur)  # the planning margin from every joint limit
    assert np.all(q >= lower) and np.all(q <= upper)
    assert plan.estimated_duration_s <= DEFAULT_BUDGET_S
    assert plan.purposes.count(VALIDATE) == 3 and plan.purposes.count(FIT) >= 6


def test_plan_round_trips_through_json(designed):
    _, plan = designed
    again = QuickPlan.from_json(plan.to_json())
    np.testing.assert_array_equal(again.waypoints_rad, plan.waypoints_rad)
    assert again.purposes == plan.purposes and again.labels == plan.labels


def recording_for(settings, plan, truth: CellTruth, extra_kg: float, seed: int = 2) -> QuickRecording:
    """A noisy recording of the plan; a part of ``extra_kg`` in the gripper during the validation holds only."""
    t, q, qd, qdd, index = sample_trajectory(plan.start_q_rad, plan.waypoints_rad, plan.hold_s, plan.speed_rad_s,
                                             plan.acceleration_rad_s2, RATE_HZ)
    physics = SensorPhysics(truth, SettablePose(), robot=settings.ur, seed=seed)
    wrench = physics.noiseless_wrench_moving(q, qd, qdd)
    holds = np.full((len(plan.purposes), 2), -1)
    for k, purpose in enumerate(plan.purposes):
        rows = np.flatnonzero(index == k)
        if rows.size:
            holds[k] = (rows[0], rows[-1] + 1)
        if purpose == VALIDATE and rows.size and extra_kg:
            physics.set_tool(truth.mass_kg + extra_kg, truth.center_of_mass_m)
            wrench[rows] = physics.noiseless_wrench_moving(q[rows], qd[rows], qdd[rows])
            physics.set_tool(truth.mass_kg, truth.center_of_mass_m)
    speed = np.max(np.abs(qd), axis=1)[:, None]
    sigma = np.array(truth.force_noise_n + truth.torque_noise_nm) * (1 + truth.motion_noise_gain * speed)
    wrench = wrench + np.random.default_rng(seed).standard_normal(wrench.shape) * sigma
    return QuickRecording(MotionRecord(t.copy(), wrench, t, q, qd, qdd), holds, len(plan.purposes))


@pytest.mark.parametrize("extra_kg, expected", [(0.0, "PASS"), (0.2, "FAIL")])
def test_verdict_catches_a_wrong_tool(designed, extra_kg, expected):
    settings, plan = designed
    truth = CellTruth()
    recording = recording_for(settings, plan, truth, extra_kg)
    rows = np.ones(len(recording.record.robot_time_s), dtype=bool)
    for (a, b), purpose in zip(recording.hold_rows, plan.purposes):
        if purpose == VALIDATE:
            rows[a:b] = False
    result = identify_joint(recording.record, settings.ur, np.array(truth.sensor_offset_m),
                            np.array(mount_of("floor").down_base), rows=rows, lag_s=0.0)
    verdict = quick_verdict(result, recording, plan, settings.ur, completed=True)
    assert verdict.status == expected, verdict.findings
    assert abs(result.calibration.mass_kg - truth.mass_kg) <= 3 * result.sigma["mass_kg"]


def test_a_quick_run_folder_is_restarted_not_resumed(tmp_path):
    class Folder:
        path = tmp_path
        document = {"mode": "quick", "sim": {"sensor": "netft"}}

    with pytest.raises(InputError, match="calibrate --sim --quick"):
        refuse_resume(Folder())


def run_cli(tmp_path, *args: str, timeout_s: float = 300.0):  # a hang guard (the suite's own limit), not a timing assert
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "ftacq.app.cli", "calibrate", *args, "--out", str(tmp_path / "runs")],
                          cwd=root, env=env, capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=timeout_s)


def test_dry_run_prints_the_checked_quick_plan_and_moves_nothing(tmp_path):
    done = run_cli(tmp_path, "--sim", "--quick", "--dry-run")
    assert done.returncode == 0, done.stderr
    assert "Quick calibration plan" in done.stdout and "Fisher information" in done.stdout
    assert "dry run: the robot did not move" in done.stdout
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_quick_with_dynamic_is_a_one_line_input_error(tmp_path):
    done = run_cli(tmp_path, "--sim", "--quick", "--dynamic", "--dry-run")
    assert done.returncode == 2
    assert "--quick runs alone" in done.stderr and "Traceback" not in done.stderr


@pytest.mark.slow(seconds=90)
def test_sim_quick_with_a_wrong_tool_fails_is_not_saved_and_is_replayed(tmp_path):
    """The whole command at real time (about a minute): a 0.2 kg part in the gripper during the validation holds
    is caught (FAIL, exit 1, nothing saved); motion.csv and report.md are kept; the replay holds raw and
    compensated wrenches over the run."""
    import json

    from ftacq.app.dashboard.layout import COMPENSATED_FORCE, RAW_FORCE
    from tests.rrd_reader import read_scalars

    rrd = tmp_path / "quick.rrd"
    done = run_cli(tmp_path, "--sim", "--quick", "--yes", "--sim-wrong-tool", "--save", str(rrd))
    assert done.returncode == 1, done.stdout + done.stderr
    assert "verdict: FAIL" in done.stdout and "not saved" in done.stdout
    (folder,) = (tmp_path / "runs").iterdir()
    assert (folder / "motion.csv").is_file() and (folder / "report.md").is_file()
    assert not (folder / "calibration.json").exists()
    run = json.loads((folder / "run.json").read_text())
    assert run["mode"] == "quick" and run["status"] == "failed" and run["verdict"]["status"] == "FAIL"
    raw_t, raw = read_scalars(rrd, RAW_FORCE)
    comp_t, compensated = read_scalars(rrd, COMPENSATED_FORCE)
    assert raw_t[-1] - raw_t[0] > 30.0 and len(comp_t) == len(raw_t)
    # the tool's weight is in the raw force and compensated out (but for the part during the validation holds)
    assert np.median(np.linalg.norm(raw, axis=1)) > 5.0
    assert np.median(np.linalg.norm(compensated, axis=1)) < 0.5


@pytest.mark.slow(seconds=90)
def test_sim_quick_passes_and_saves_the_calibration_with_its_drift_model(tmp_path):
    """The whole command at real time on the default simulated cell (its tool rings after every stop): PASS, exit
    0, calibration.json saved with its inertia, the drift model's decision and each hold's settling."""
    import json

    done = run_cli(tmp_path, "--sim", "--quick", "--yes", timeout_s=1200.0)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "verdict: PASS" in done.stdout
    (folder,) = (tmp_path / "runs").iterdir()
    saved = json.loads((folder / "calibration.json").read_text())
    metadata = saved  # the metadata keys follow the model keys (ftacq/calfile.py)
    assert metadata["drift_model"]["model"] in ("linear", "none") and metadata["drift_model"]["chosen"]
    delays = metadata["quick"]["settle_delay_s"]
    assert len(delays) == len(json.loads(metadata["quick"]["plan"])["hold_s"])
    assert max(delays) > 0.1  # the ring-down after each stop was seen and left out
    assert json.loads((folder / "run.json").read_text())["status"] == "done"


@pytest.mark.slow(seconds=9)
def test_ctrl_c_stops_keeps_the_motion_and_says_how_to_restart(tmp_path):
    import json
    import os
    import signal
    import subprocess
    import sys
    from pathlib import Path

    from tests.conftest import wait_until

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    log = tmp_path / "stderr.txt"
    with open(log, "w", encoding="utf-8") as stderr:
        process = subprocess.Popen([sys.executable, "-m", "ftacq.app.cli", "calibrate", "--sim", "--quick", "--yes",
                                    "--out", str(tmp_path / "runs")], cwd=root, env=env, stdout=subprocess.PIPE,
                                   stderr=stderr, stdin=subprocess.DEVNULL, text=True)
        try:
            wait_until(lambda: "waypoint 2/" in log.read_text(encoding="utf-8") or process.poll() is not None,
                       timeout_s=90.0)
            process.send_signal(signal.SIGINT)
            process.communicate(timeout=60)
        finally:
            if process.poll() is None:
                process.kill()
    err = log.read_text(encoding="utf-8")
    assert process.returncode == 130, err
    assert "the robot was stopped" in err and "restart with:" in err and "calibrate --sim --quick" in err
    (folder,) = (tmp_path / "runs").iterdir()
    assert json.loads((folder / "run.json").read_text())["status"] == "stopped"
    assert (folder / "motion.csv").is_file() and not (folder / "calibration.json").exists()
    done = run_cli(tmp_path, "--sim", "--resume", str(folder))
    assert done.returncode == 2 and "restart it with" in done.stderr


def test_slow_cell_speeds_give_the_shortest_clear_trajectory_not_a_refusal():
    from ftacq.app.config import config_from_dict
    from procedures.quick import DEFAULT_BUDGET_S, check_quick

    settings = config_from_dict({"robot": {"host": "x", "model": "UR5e", "mount": "floor",
                                           "joint_speed_rad_s": 0.2}}, "test").plan_settings()
    plan = design_quick(settings, home_configuration_rad("floor"))
    assert plan.estimated_duration_s > DEFAULT_BUDGET_S
    assert plan.speed_rad_s == 0.2 and check_quick(settings, plan.start_q_rad, plan.waypoints_rad) == []
