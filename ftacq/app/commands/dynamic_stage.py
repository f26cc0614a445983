"""The excitation stage of ``ftacq calibrate --dynamic``: plan, check, confirm, move and record, identify the inertia,
rewrite the run's calibration.json, print the result (beside the truth on the simulated cell).

Runs after the static poses, with the robot and sensor the calibration used. On the simulated cell the controller
runs this stage in real time (time scale 1): the recorded motion is then what a real arm produces, and its wall
time is the stage's real duration.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ftacq.errors import InterruptedByUser

if TYPE_CHECKING:
    from procedures.events import Listener

MOTION_CSV = "motion.csv"
"""The recorded excitation in the run folder (ftacq/dynamics/motionfile.py, docs/dynamics.md)."""


def sensor_offset_from(config, cell) -> tuple[np.ndarray, str]:
    """The sensor origin in the flange frame, m, and where it came from (CELL.toml, the simulation, or zero)."""
    if cell is not None:
        return np.array(cell.truth.sensor_offset_m, dtype=float), "the simulated cell's adapter"
    offset = getattr(getattr(config, "tool", None), "sensor_offset_m", None)
    if offset is not None:
        return np.array(offset, dtype=float), "CELL.toml tool.sensor_offset_m"
    return np.zeros(3), ("zero: CELL.toml tool.sensor_offset_m is not set (the sensor origin is taken at the flange; "
                         "measure it on the adapter drawing)")


def run_dynamic_stage(args: argparse.Namespace, stack: contextlib.ExitStack, config, settings, robot, sensor,
                      folder, cell, confirm, listeners: Sequence[Listener] = ()) -> int:
    """Run the stage; return the exit status (0). The motion's events go to a progress display and ``listeners``
    (the run's dashboard). Ctrl-C stops the robot, keeps motion.csv and raises."""
    import time

    from drivers.ur_stream import URStateStream
    from ftacq.calfile import load_calibration, save_calibration
    from ftacq.dynamics import identify_dynamics
    from ftacq.dynamics.motionfile import write_motion_csv
    from ftacq.dynamics.report import format_dynamics
    from ftacq.kinematics import ur_model
    from procedures.excitation import format_excitation, plan_excitation, record_excitation
    from procedures.progress import ProgressListener
    from procedures.run_folder import CALIBRATION_JSON

    calibration = load_calibration(folder.path / CALIBRATION_JSON)
    plan = plan_excitation(settings, robot.joint_positions())
    print("", flush=True)
    print(format_excitation(plan), flush=True)
    confirm(args)
    if cell is not None and cell.time_scale != 1.0:
        cell.controller.set_time_scale(1.0)
        print("  simulation: the excitation runs in real time (time scale 1)", flush=True)
    stream = URStateStream(config.robot.host)
    stack.callback(stream.close)
    stream.start()
    started = time.monotonic()
    motion_path = folder.path / MOTION_CSV
    try:
        progress = ProgressListener(len(plan.targets_rad), plan.estimated_duration_s, motion="excitation")
        stack.callback(progress.close)
        record = record_excitation(plan, robot, sensor, stream, config.robot.move_timeout_s,
                                   listeners=[progress, *listeners])
    except KeyboardInterrupt as interrupt:
        partial = getattr(interrupt, "motion_record", None)
        if partial is not None and len(partial.robot_time_s):
            write_motion_csv(motion_path, partial, settings.model)
        raise InterruptedByUser(f"interrupted: the excitation stopped, the robot was stopped; the static calibration "
                                f"stays in {folder.path / CALIBRATION_JSON}; the motion so far is in {motion_path}") \
            from interrupt
    wall_s = time.monotonic() - started
    write_motion_csv(motion_path, record, settings.model)
    offset, offset_source = sensor_offset_from(config, cell)
    result = identify_dynamics(calibration, record, ur_model(settings.model), sensor_offset_m=offset)
    final = result.calibration
    metadata = dict(final.metadata)
    metadata["dynamics"] = {**metadata.get("dynamics", {}), "excitation": plan.to_json(), "wall_time_s": wall_s,
                            "motion_file": MOTION_CSV, "sensor_offset_source": offset_source}
    from dataclasses import replace

    final = replace(final, metadata=metadata)
    save_calibration(folder.path / CALIBRATION_JSON, final)
    print("", flush=True)
    print(f"excitation recorded in {wall_s:.1f} s: {len(record.sensor_time_s)} sensor samples, "
          f"{len(record.robot_time_s)} robot samples -> {motion_path}", flush=True)
    print("sensor offset from the flange: " + " ".join(f"{1e3 * v:+.1f}" for v in offset) + f" mm ({offset_source})")
    truth = cell.truth if cell is not None else None
    print(format_dynamics(result, truth_inertia=None if truth is None else truth.inertia,
                          truth_mass_kg=None if truth is None else truth.mass_kg,
                          truth_com_m=None if truth is None else truth.center_of_mass_m), end="", flush=True)
    print(f"calibration (with inertia): {folder.path / CALIBRATION_JSON}", flush=True)
    return 0
