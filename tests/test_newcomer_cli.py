"""What a newcomer trips over in the CLI (issue 38, items 7 and 8): a calibration started with SIGINT ignored
says so at once; a --sim run resumes without --sim (run.json knows)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def _cli(*args: str, ignore_sigint: bool = False) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "ftacq.app.cli", *args], cwd=REPO_ROOT, env=env,
                          capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=300,
                          preexec_fn=(lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if ignore_sigint else None)


def test_calibrate_says_at_once_that_sigint_is_ignored(tmp_path):
    done = _cli("calibrate", "--sim", "--dry-run", "--out", str(tmp_path / "runs"), ignore_sigint=True)
    assert done.returncode == 0, done.stderr
    first = done.stderr.splitlines()[0]
    assert first.startswith("ftacq calibrate: WARNING: Ctrl-C (SIGINT) is ignored in this process"), done.stderr
    assert "kill PID" in first
    plain = _cli("calibrate", "--sim", "--dry-run", "--out", str(tmp_path / "runs"))
    assert "SIGINT" not in plain.stderr


def test_a_sim_run_resumes_without_sim(tmp_path):
    from ftacq.app.config import config_from_dict
    from procedures.plan import home_configuration_rad, make_plan
    from procedures.run_folder import RunFolder

    config = config_from_dict({"robot": {"host": "(simulated)", "model": "UR5e", "mount": "floor"}}, "test")
    plan = make_plan(config.plan_settings(), home_configuration_rad("floor"))
    folder = RunFolder.create(tmp_path / "runs", config.to_dict(), plan.to_json(),
                              extra={"sim": {"sensor": "netft", "time_scale": 0.0, "model": "UR5e", "mount": "floor"}})
    folder.set_status("stopped", "interrupted")
    done = _cli("calibrate", "--resume", str(folder.path), "--dry-run")
    assert done.returncode == 0, done.stderr
    assert "made with --sim (run.json): resuming it on the simulated cell" in done.stderr
    assert "dry run: the robot did not move" in done.stdout
