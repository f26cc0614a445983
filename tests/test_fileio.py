"""Atomic writes: nothing half written, and the file readable by other users (mode 0644 less the umask)."""

from __future__ import annotations

import os
import stat

import pytest

from ftacq.fileio import FILE_MODE, atomic_write


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def test_atomic_write_creates_a_file_readable_by_others(tmp_path):
    previous = os.umask(0o022)
    try:
        target = tmp_path / "calibration.json"
        with atomic_write(target) as handle:
            handle.write("{}\n")
        with atomic_write(tmp_path / "plot.png", mode="wb") as handle:
            handle.write(b"\x89PNG")
    finally:
        os.umask(previous)
    assert target.read_text() == "{}\n"
    assert _mode(target) == 0o644  # mkstemp alone gives 0600
    assert _mode(tmp_path / "plot.png") == 0o644
    assert FILE_MODE == 0o644


def test_atomic_write_respects_a_stricter_umask(tmp_path):
    previous = os.umask(0o077)
    try:
        with atomic_write(tmp_path / "private.json") as handle:
            handle.write("x")
    finally:
        os.umask(previous)
    assert _mode(tmp_path / "private.json") == 0o600


def test_atomic_write_leaves_the_target_as_it_was_on_an_error(tmp_path):
    target = tmp_path / "run.json"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_write(target) as handle:
            handle.write("half")
            raise RuntimeError("crash while writing")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["run.json"]
