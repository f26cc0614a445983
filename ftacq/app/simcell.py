"""The simulated-cell launcher: the one place the application reaches the simulated devices in ``tests.fakes``.

The simulator (a UR controller speaking RTDE / dashboard / script on loopback, a Net F/T box and a NETCANOEM
board whose wrench follows the simulated flange pose) ships with the source checkout, not with the wheel: an
installed ``ftacq`` has no ``tests`` package. From a clone, this module puts the checkout's root on
``sys.path`` so that ``ftacq calibrate --sim`` works from any directory.
"""

from __future__ import annotations

import contextlib
import importlib
import sys
from pathlib import Path
from typing import Any

from ftacq.errors import InputError

CHECKOUT_ROOT = Path(__file__).resolve().parents[2]
"""The source checkout this package was loaded from (holds ``tests/fakes/`` in a clone)."""

NOT_INSTALLED = ("the simulated cell is not installed: it ships with the source checkout. Clone the ftacq "
                 "repository and run './run.sh demo' (or '.venv/bin/ftacq calibrate --sim' from the clone)")


def _fakes_module(name: str) -> Any:
    """Import ``tests.fakes.<name>``, from the checkout beside this package when it is not importable yet."""
    if (CHECKOUT_ROOT / "tests" / "fakes" / "cell.py").is_file() and str(CHECKOUT_ROOT) not in sys.path:
        sys.path.insert(0, str(CHECKOUT_ROOT))
    try:
        return importlib.import_module(f"tests.fakes.{name}")
    except ModuleNotFoundError as error:
        if error.name in ("tests", "tests.fakes", f"tests.fakes.{name}"):
            raise InputError(NOT_INSTALLED) from error
        raise


def simulated_cell(**kwargs: Any) -> Any:
    """Start and return a :class:`tests.fakes.cell.SimulatedCell` (a context manager); see its docstring for the
    arguments. Raises :class:`InputError` with what to do when the simulator is not installed."""
    return _fakes_module("cell").SimulatedCell(**kwargs)


def simulated_truth(**changes: Any) -> Any:
    """Return a :class:`tests.fakes.world.CellTruth` (the simulated cell's ground truth) with some fields changed."""
    return _fakes_module("world").CellTruth(**changes)


def true_calibration(truth: Any) -> Any:
    """The simulated tool's true calibration (:class:`tests.fakes.world.CellTruth`): rotation, biases, weight,
    centre of mass, and the inertia and sensor offset the simulated sensor feels while the arm moves, so that a
    ``--sim`` command without ``--calibration`` compensates as a good dynamic calibration would."""
    from dataclasses import replace

    import numpy as np

    return replace(truth.calibration(), inertia=truth.inertia,
                   sensor_offset=np.asarray(truth.sensor_offset_m, dtype=float))


def enter_calibration_cell(stack: contextlib.ExitStack, config: Any, sim_info: dict, time_scale: float) -> tuple[Any, Any]:
    """Start the simulated cell a ``calibrate --sim`` run moves (``sim_info``: its sensor, robot model and mount),
    say so on stderr, keep it open in ``stack``; return (the cell, ``config`` pointed at its robot and sensor)."""
    pace = "real time" if time_scale == 1.0 else f"time scale {time_scale:g}"
    print(f"starting the simulated cell: {sim_info['model']} controller ({sim_info['mount']} mount, {pace}) and a "
          f"simulated {sim_info['sensor']} sensor on loopback …", file=sys.stderr, flush=True)
    truth = None
    if sim_info.get("bad_sensor"):  # --sim-bad-sensor: the sensor's own calibration is off
        truth = simulated_truth(sensor_gain_error=_fakes_module("world").BAD_SENSOR_GAIN_ERROR)
        print("the simulated sensor's own calibration is off (--sim-bad-sensor)", file=sys.stderr, flush=True)
    cell = stack.enter_context(simulated_cell(truth=truth, sensor=sim_info["sensor"], model=sim_info["model"],
                                              mount=sim_info["mount"], time_scale=time_scale))
    config = config.replace_section("robot", host=cell.robot_host)
    return cell, config.replace_section("sensor", url=cell.sensor_url)
