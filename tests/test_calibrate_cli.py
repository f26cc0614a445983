"""``ftacq calibrate`` as a process: interrupted by a signal or killed, then ``--resume``: the same plan, poses
already measured are not measured again, and the result is the calibration of exactly those poses."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ftacq.calfile import load_calibration
from ftacq.identification import identify
from ftacq.posefile import read_pose_csv
from tests.fakes.world import CellTruth

REPO_ROOT = Path(__file__).resolve().parents[1]
ROWS_BEFORE_INTERRUPT = 5
WAIT_FOR_ROWS_S = 90.0
EXIT_TIMEOUT_S = 60.0
FAST_TOML = """
[poses]
random_count = 6
validation_count = 4
[sampling]
settle_time_s = 0.0
settle_window_s = 0.02
average_time_s = 0.1
"""


def calibrate_command(tmp_path: Path, *extra: str, sensor: str = "netft") -> list[str]:
    """The command on the simulated cell with ``sensor`` ("netft", or "can": the interrupted runs take the CAN board,
    whose driver polls from the command's own process)."""
    config = tmp_path / "FAST.toml"
    config.write_text(FAST_TOML, encoding="utf-8")
    return [sys.executable, "-m", "ftacq.app.cli", "calibrate", "--sim", "--sensor", sensor, "--time-scale", "0",
            "--yes", "--config", str(config), "--out", str(tmp_path / "runs"), *extra]


def start(command: list[str], new_session: bool = False) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.Popen(command, cwd=REPO_ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, text=True, start_new_session=new_session)


def data_rows(path: Path) -> int:
    try:
        return max(path.read_text(encoding="utf-8").count("\n") - 1, 0)
    except FileNotFoundError:
        return 0


def wait_for_rows(process: subprocess.Popen, runs: Path, rows: int) -> Path:
    """Return the run folder once its poses.csv has ``rows`` complete data rows (deadline WAIT_FOR_ROWS_S)."""
    deadline = time.monotonic() + WAIT_FOR_ROWS_S
    while time.monotonic() < deadline:
        folders = list(runs.glob("*/poses.csv")) if runs.exists() else []
        if folders and data_rows(folders[0]) >= rows:
            return folders[0].parent
        if process.poll() is not None:
            out, err = process.communicate()
            pytest.fail(f"ftacq calibrate ended early ({process.returncode}):\n{out}\n{err}")
        time.sleep(0.02)
    process.kill()
    pytest.fail(f"no {rows} measured poses within {WAIT_FOR_ROWS_S} s")


def run_to_end(command: list[str]) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run(command, cwd=REPO_ROOT, env=env, capture_output=True, text=True, stdin=subprocess.DEVNULL,
                          timeout=300)


def check_resumed(run_dir: Path, rows_before: str) -> None:
    """The resumed run measured every plan pose exactly once and identified on exactly those rows."""
    document = json.loads((run_dir / "run.json").read_text())
    assert document["status"] == "done"
    labels = document["labels"]
    text = (run_dir / "poses.csv").read_text(encoding="utf-8")
    assert text.startswith(rows_before)  # what was measured before the interrupt is kept, not re-measured
    record = read_pose_csv(run_dir / "poses.csv")
    assert sorted(record.labels) == sorted([*labels, f"{labels[0]}-revisit"])  # each exactly once
    calibration = load_calibration(run_dir / "calibration.json")
    truth = CellTruth().calibration()
    assert abs(calibration.mass_kg - CellTruth().mass_kg) < 6 * calibration.uncertainty["mass_kg"] + 1e-4
    assert np.all(np.abs(calibration.force_bias - truth.force_bias)
                  < 6 * np.asarray(calibration.uncertainty["force_bias"]) + 1e-3)
    # same result: identifying the A and E rows of the file gives the saved calibration
    ident = record.select([i for i, s in enumerate(record.sets) if s in ("A", "E")])
    again = identify(ident, mount="floor").calibration
    np.testing.assert_allclose(again.sensor_rotation, calibration.sensor_rotation, atol=1e-12)
    np.testing.assert_allclose(again.gravity_base, calibration.gravity_base, atol=1e-10)
    np.testing.assert_allclose(again.center_of_mass, calibration.center_of_mass, atol=1e-12)


@pytest.mark.slow(seconds=18)
def test_sigint_then_resume(tmp_path, capsys):
    process = start(calibrate_command(tmp_path, sensor="can"))
    run_dir = wait_for_rows(process, tmp_path / "runs", ROWS_BEFORE_INTERRUPT)
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=EXIT_TIMEOUT_S)
    assert process.returncode == 130, err
    assert "interrupted" in err
    resume_line = next(line for line in err.splitlines() if line.startswith("resume with: "))[len("resume with: "):]
    assert resume_line.endswith(f"calibrate --sim --resume {run_dir}")
    assert "the robot was stopped" in err
    document = json.loads((run_dir / "run.json").read_text())
    assert document["status"] == "stopped" and "interrupted" in document["message"]
    before = (run_dir / "poses.csv").read_text(encoding="utf-8")
    measured_before = data_rows(run_dir / "poses.csv")
    assert measured_before >= ROWS_BEFORE_INTERRUPT
    assert not (run_dir / "calibration.json").exists()

    # the printed command runs as printed in a fresh shell: another folder, no PYTHONPATH, the user's PATH
    fresh_env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(tmp_path)}
    resumed = subprocess.run(["bash", "-c", resume_line + " --yes --time-scale 0"], cwd="/", env=fresh_env,
                             capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert f"resuming {run_dir}: {measured_before} poses already measured" in resumed.stdout
    check_resumed(run_dir, before)
    assert len(list((tmp_path / "runs").iterdir())) == 1  # resumed in place, no new run folder

    from ftacq.app.cli import main  # the refusal comes before any device: in this process, not a third one

    capsys.readouterr()
    assert main(calibrate_command(tmp_path, "--resume", str(run_dir))[3:]) == 2
    assert "already done" in capsys.readouterr().err


@pytest.mark.slow(seconds=14)
def test_killed_process_then_resume(tmp_path):
    process = start(calibrate_command(tmp_path, sensor="can"), new_session=True)
    run_dir = wait_for_rows(process, tmp_path / "runs", ROWS_BEFORE_INTERRUPT)
    os.killpg(process.pid, signal.SIGKILL)  # the whole process group: CLI, simulated controller, tracker
    process.communicate(timeout=EXIT_TIMEOUT_S)
    assert process.returncode == -signal.SIGKILL
    for leaked in Path("/dev/shm").glob(f"ftacq-{process.pid}-*"):  # the killed cell's shared pose block
        leaked.unlink(missing_ok=True)
    assert json.loads((run_dir / "run.json").read_text())["status"] == "running"  # no chance to say more
    text = (run_dir / "poses.csv").read_text(encoding="utf-8")
    before = text[: text.rfind("\n") + 1]  # a torn last row, if any, is measured again
    resumed = run_to_end(calibrate_command(tmp_path, "--resume", str(run_dir)))
    assert resumed.returncode == 0, resumed.stderr
    check_resumed(run_dir, before)


def test_sigterm_stops_cleanly_with_exit_130(tmp_path):
    process = start(calibrate_command(tmp_path))
    run_dir = wait_for_rows(process, tmp_path / "runs", 2)
    process.send_signal(signal.SIGTERM)
    out, err = process.communicate(timeout=EXIT_TIMEOUT_S)
    assert process.returncode == 130, err
    assert "resume with:" in err
    assert json.loads((run_dir / "run.json").read_text())["status"] == "stopped"
    assert read_pose_csv(run_dir / "poses.csv").labels  # kept


@pytest.mark.slow(seconds=20)
def test_verdict_is_printed_last_and_stored(tmp_path):
    """A right run ends with its verdict (not FAIL) on stdout, in run.json, calibration.json and report.md; a
    run whose validation poses carry a part left in the gripper ends with FAIL, the reason and exit status 1."""
    good = run_to_end(calibrate_command(tmp_path, "--out", str(tmp_path / "good")))
    assert good.returncode == 0, good.stderr
    tail = good.stdout.rstrip().split("\n\nverdict: ")
    assert len(tail) == 2 and tail[1].split("\n")[0] in ("PASS", "WARN"), good.stdout[-2000:]
    run_dir = next((tmp_path / "good").iterdir())
    stored = json.loads((run_dir / "run.json").read_text())["verdict"]
    assert stored["status"] == tail[1].split("\n")[0]
    assert {f["check"] for f in stored["findings"]} == {"validation", "drift", "conditioning", "outliers", "poses", "trend",
                                                     "fit", "sensor"}
    assert next(f for f in stored["findings"] if f["check"] == "sensor")["status"] == "PASS"
    assert json.loads((run_dir / "calibration.json").read_text())["verdict"]["status"] == stored["status"]
    assert (run_dir / "report.md").read_text().split("\n")[2] == f"## Verdict: **{stored['status']}**"

    bad = run_to_end(calibrate_command(tmp_path, "--out", str(tmp_path / "bad"), "--sim-wrong-tool"))
    assert bad.returncode == 1, bad.stderr
    verdict = bad.stdout.rstrip().split("\n\nverdict: ")[1]
    assert verdict.startswith("FAIL\n  FAIL  validation   the 4 held-out poses disagree with the calibration")
    assert "the tool, its load or the sensor changed" in verdict
    run_dir = next((tmp_path / "bad").iterdir())
    assert json.loads((run_dir / "run.json").read_text())["verdict"]["status"] == "FAIL"
    assert (run_dir / "calibration.json").exists()  # kept, judged unusable


@pytest.mark.slow(seconds=20)
def test_a_sensor_whose_own_calibration_is_off_fails_naming_the_axis(tmp_path):
    """--sim-bad-sensor: the simulated sensor reads Fz 4 % high, Fx 1.5 % low (and some cross-talk); the run's
    verdict is FAIL on its sensor line, naming Fz and the certificate's accuracy; without the check, nothing names it."""
    bad = run_to_end(calibrate_command(tmp_path, "--out", str(tmp_path / "bad"), "--sim-bad-sensor",
                                       "--reference-mass", "1.35±0.002"))
    assert bad.returncode == 1, bad.stderr
    verdict = bad.stdout.rstrip().split("\n\nverdict: ")[1]
    assert verdict.startswith("FAIL\n  FAIL  sensor       the sensor's own calibration is off: Fz gain 4"), verdict
    assert "certificate accuracy 1.25 %" in verdict
    unchecked = run_to_end(calibrate_command(tmp_path, "--out", str(tmp_path / "unchecked"), "--sim-bad-sensor",
                                             "--no-sensor-check"))
    assert unchecked.returncode in (0, 1) and "\n\nverdict: " in unchecked.stdout, unchecked.stderr[-3000:]
    assert "sensor  " not in unchecked.stdout.rstrip().split("\n\nverdict: ")[1]
