"""A jog by a separate RTDE client process (tests/fakes/jog.py, as a pendant program or another application) moves
the simulated arm while ``ftacq monitor`` reads it with its own receive interface: the monitor's record shows
the arm at every target of the jog, wrist included."""

from __future__ import annotations

import json
import os
import selectors
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ftacq.calfile import save_calibration
from ftacq.kinematics import flange_pose, ur_model
from tests.fakes.cell import SimulatedCell

pytest.importorskip("rtde_control")

ROOT = Path(__file__).resolve().parents[1]
START_DEADLINE_S = 60.0
"""The monitor's start-up (imports, connections) and the jog, each within this, s."""
REACHED_M = 1e-4
"""The record holds a flange position this close to each target's (the monitor reads every controller cycle)."""


def wait_for_line(process: subprocess.Popen, text: str, deadline_s: float) -> list[str]:
    """Read the process's stderr until a line contains ``text``; return the lines read (fails at the deadline)."""
    selector = selectors.DefaultSelector()
    selector.register(process.stderr, selectors.EVENT_READ)
    lines: list[str] = []
    deadline = time.monotonic() + deadline_s
    try:
        while (remaining := deadline - time.monotonic()) > 0:
            if not selector.select(remaining):
                break
            line = process.stderr.readline()
            if not line:
                break
            lines.append(line)
            if text in line:
                return lines
    finally:
        selector.close()
    pytest.fail(f"{text!r} not printed within {deadline_s} s: {''.join(lines)[-2000:]}")


@pytest.mark.slow(seconds=13)
def test_a_separate_process_jogs_the_arm_while_the_monitor_reads_it(tmp_path):
    with SimulatedCell(time_scale=1.0, sensor_process=True) as cell:
        truth = cell.truth
        calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m),
                              inertia=truth.inertia)
        save_calibration(tmp_path / "calibration.json", calibration)
        (tmp_path / "CELL.toml").write_text(f'[robot]\nhost = "{cell.robot_host}"\nmodel = "UR5e"\n'
                                            f'[sensor]\nurl = "{cell.sensor_url}"\n', encoding="utf-8")
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        monitor = subprocess.Popen([sys.executable, "-m", "ftacq.app.cli", "monitor", "--config",
                                    str(tmp_path / "CELL.toml"), "--calibration", str(tmp_path / "calibration.json"),
                                    "--record", str(tmp_path / "record.csv"), "--seconds", "120"],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
        try:
            wait_for_line(monitor, "dynamic compensation", START_DEADLINE_S)  # reading the arm from here on
            jog = subprocess.run([sys.executable, "-m", "tests.fakes.jog", "--host", cell.robot_host, "--moves", "3",
                                  "--rest-s", "1.0", "--seed", "4"],
                                 capture_output=True, text=True, env=env, cwd=ROOT, timeout=START_DEADLINE_S)
        finally:
            monitor.send_signal(signal.SIGINT)  # Ctrl-C: the monitor stops and closes its record
            out, err = monitor.communicate(timeout=START_DEADLINE_S)
        assert jog.returncode == 0, jog.stderr
        commands = cell.controller.commands()
    assert monitor.returncode == 0, err[-2000:]
    lines = [json.loads(line) for line in jog.stdout.splitlines()]
    moves = [line for line in lines if "move" in line]
    assert lines[-1] == {"done": True} and len(moves) == 3
    targets = np.array([move["target"] for move in moves])
    start = np.array(lines[0]["q"])
    assert np.all(np.abs(targets[0] - start) > 0.05)  # every joint moves, wrist included
    # the controller ran them as moveJ from an RTDE client (not the pendant's back door)
    assert [(c["kind"], c["source"]) for c in commands[-3:]] == [("movej", "rtde")] * 3
    rows = [line for line in (tmp_path / "record.csv").read_text(encoding="utf-8").splitlines()
            if line and not line.startswith("#")]
    columns = rows[0].split(",")
    values = np.genfromtxt(rows[1:], delimiter=",")
    positions = values[:, [columns.index("x"), columns.index("y"), columns.index("z")]]
    positions = positions[np.all(np.isfinite(positions), axis=1)]
    model = ur_model("UR5e")
    for q in targets:
        reached = np.linalg.norm(positions - flange_pose(model, q)[:3], axis=1).min()
        assert reached < REACHED_M
    assert np.ptp(positions, axis=0).max() > 0.05  # the monitor saw the arm travel
