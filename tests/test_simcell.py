"""The simulated-cell launcher: from a checkout it finds tests/fakes; from an install without them it says what to do."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_installed_without_the_simulator_says_what_to_do(tmp_path):
    for package in ("ftacq", "drivers", "procedures"):  # an install: the product packages, no tests/
        shutil.copytree(ROOT / package, tmp_path / package, ignore=shutil.ignore_patterns("__pycache__"))
    result = subprocess.run(
        [sys.executable, "-c", "import sys; from ftacq.app.cli import main; sys.exit(main(sys.argv[1:]))",
         "calibrate", "--sim", "--yes", "--dry-run", "--out", str(tmp_path / "runs")],
        cwd=tmp_path, capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert result.returncode == 2, result.stderr
    assert "simulated cell is not installed" in result.stderr and "./run.sh demo" in result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "runs").exists()


def test_from_the_checkout_the_simulator_is_found():
    from ftacq.app import simcell

    assert simcell.CHECKOUT_ROOT == ROOT
    assert simcell._fakes_module("world").CellTruth is not None
