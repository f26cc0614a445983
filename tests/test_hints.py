"""Printed hints name the program so that they run in a fresh shell (absolute path unless PATH finds it)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from ftacq.app.hints import command, ftacq_command, program


def test_program_is_absolute_unless_path_finds_the_same_file(monkeypatch, tmp_path):
    beside = Path(sys.executable).parent / "ftacq"
    monkeypatch.setattr(sys, "argv", ["-m"])
    monkeypatch.setenv("PATH", str(tmp_path))  # nothing there
    assert program("ftacq") == str(beside.absolute())
    monkeypatch.setenv("PATH", str(beside.parent) + os.pathsep + str(tmp_path))
    assert program("ftacq") == "ftacq"
    other = tmp_path / "ftacq"  # another ftacq first on PATH: the hint must not run that one
    other.write_text("#!/bin/sh\n")
    other.chmod(0o755)
    monkeypatch.setenv("PATH", str(tmp_path) + os.pathsep + str(beside.parent))
    assert program("ftacq") == str(beside.absolute())


def test_paths_are_absolute_and_quoted(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(Path(sys.executable).parent))
    monkeypatch.chdir(tmp_path)
    line = ftacq_command("calibrate", "--resume", Path("runs/with space"))
    assert line == f"ftacq calibrate --resume '{tmp_path}/runs/with space'"
    assert command("no-such-program-here", "x") == "no-such-program-here x"
