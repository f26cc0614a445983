"""A SIGKILLed run cannot write its last status: run.json's process record lets a later reader say so (issue 15).

A child process creates a run folder, records "running" and a measured pose like the procedure does, then waits
to be killed; the parent SIGKILLs it and reopens the folder.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from ftacq.app.cli import main
from procedures.run_folder import RUN_JSON, RunFolder
from tests.fakes.ur_process import random_loopback_address

REPO_ROOT = Path(__file__).resolve().parents[1]
CHILD_READY_TIMEOUT_S = 30.0

CHILD = textwrap.dedent("""
    import sys, json
    import numpy as np
    from procedures import events
    from procedures.run_folder import RunFolder, RunFolderWriter
    from tests.test_run_folder import small_plan, measured_event
    config = {"robot": {"host": sys.argv[2]}}  # a loopback address nothing listens on
    folder = RunFolder.create(sys.argv[1], config, small_plan().to_json(), name="r")
    writer = RunFolderWriter(folder)
    writer(events.StateChanged("moving", 0, "to A01"))
    writer(measured_event(0))
    print("RUNNING", flush=True)
    sys.stdin.read()  # until killed
""")


@pytest.fixture()
def killed_run(tmp_path) -> Path:
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(tmp_path), random_loopback_address()], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True, cwd=REPO_ROOT,
                             env=dict(os.environ, PYTHONPATH=str(REPO_ROOT)))
    try:
        assert child.stdout.readline().strip() == "RUNNING"  # the child's own "ready" line, not a sleep
        folder = RunFolder.open(tmp_path / "r")
        assert folder.status == "running" and folder.process_alive() is True
        assert "running (process" in folder.status_note
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=CHILD_READY_TIMEOUT_S)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        child.stdin.close()
        child.stdout.close()
    return tmp_path / "r"


def test_a_killed_run_reads_as_interrupted_process_gone(killed_run):
    document = json.loads((killed_run / RUN_JSON).read_text())
    assert document["status"] == "running"  # what the killed process left behind
    assert isinstance(document["process"]["pid"], int) and document["heartbeat_utc"]
    folder = RunFolder.open(killed_run)
    assert folder.status == "interrupted"
    assert folder.status_note.startswith("interrupted (process gone)")
    assert folder.process_alive() is False


def test_resume_of_a_killed_run_says_it_was_interrupted(killed_run, capsys):
    # --resume tells the user what happened to the run, then fails to reach the (absent) robot on loopback
    assert main(["calibrate", "--resume", str(killed_run), "--dry-run"]) == 1
    err = capsys.readouterr().err
    assert "interrupted (process gone)" in err and "cannot connect to port 30004" in err


def test_resume_refuses_a_run_whose_process_is_still_alive(tmp_path, capsys):
    folder = RunFolder.create(tmp_path, {}, json.dumps({"labels": [], "set_names": []}), name="r")
    folder.set_status("running", "measuring")  # this very process: alive
    assert RunFolder.open(tmp_path / "r").process_alive() is True
    assert main(["calibrate", "--resume", str(tmp_path / "r"), "--dry-run"]) == 2
    assert "still running" in capsys.readouterr().err


def test_a_recycled_pid_is_not_taken_for_the_run(tmp_path):
    folder = RunFolder.create(tmp_path, {}, json.dumps({"labels": [], "set_names": []}), name="r")
    folder.set_status("running", "measuring")
    document = json.loads((tmp_path / "r" / RUN_JSON).read_text())
    if document["process"]["start_token"] is None:
        pytest.skip("this platform has no process start time (/proc)")
    document["process"]["start_token"] += "0"  # same pid (ours, alive), another process start
    (tmp_path / "r" / RUN_JSON).write_text(json.dumps(document))
    assert RunFolder.open(tmp_path / "r").status == "interrupted"
