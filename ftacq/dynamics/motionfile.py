"""The motion record file (``motion.csv``): a recorded excitation, sensor and robot samples in one CSV.

Layout (docs/dynamics.md): an optional first line ``# ftacq motion record, servo lag 4.012 ms, model UR5e`` (the
arm's lag behind its target as measured at recording, and its model; either may be left out), then a header and one
row per sample, oldest first within each source::

    source,time_s,fx_n,fy_n,fz_n,tx_nm,ty_nm,tz_nm,q1_rad,…,q6_rad,qd1_rad_s,…,qd6_rad_s,qdd1_rad_s2,…,qdd6_rad_s2

- ``source`` ``sensor``: a raw sensor sample, sensor frame, N and N·m; the joint columns are empty.
- ``source`` ``robot``: a robot state: joint positions (rad), speeds (rad/s), accelerations (rad/s²) (RTDE
  ``actual_q``, ``actual_qd``, and the physical arm's q̈: ``target_qdd`` of the servo lag earlier,
  :mod:`ftacq.dynamics.acceleration`); the wrench columns are empty.
- ``time_s``: seconds on one clock for both sources (ftacq writes the host's monotonic clock, after aligning each
  device's clock: :mod:`ftacq.dynamics.timing`); only differences matter.
"""

from __future__ import annotations

import csv
import os
import re
from pathlib import Path

import numpy as np

from ftacq.dynamics.identify import MotionRecord
from ftacq.errors import InputError
from ftacq.fileio import atomic_write

WRENCH_COLUMNS = ("fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm")
JOINT_COLUMNS = (tuple(f"q{i}_rad" for i in range(1, 7)) + tuple(f"qd{i}_rad_s" for i in range(1, 7))
                 + tuple(f"qdd{i}_rad_s2" for i in range(1, 7)))
COLUMNS = ("source", "time_s") + WRENCH_COLUMNS + JOINT_COLUMNS
_MODEL_LINE = re.compile(r"^#.*\bmodel\s+(\S+)")
_SERVO_LAG = re.compile(r"\bservo lag\s+([-+0-9.eE]+)\s*ms")
_HEADER_LINE = re.compile(r"^#")


def write_motion_csv(path: str | os.PathLike, record: MotionRecord, model: str | None = None) -> None:
    """Write ``record`` (atomically) as a motion record CSV."""
    empty_joints = "," * len(JOINT_COLUMNS)
    empty_wrench = "," * len(WRENCH_COLUMNS)
    servo_lag_s = record.metadata.get("servo_lag_s")
    notes = ([f"servo lag {1e3 * float(servo_lag_s):.4f} ms"] if servo_lag_s is not None else []) + (
        [f"model {model}"] if model else [])
    with atomic_write(path) as handle:
        if notes:
            handle.write("# ftacq motion record, " + ", ".join(notes) + "\n")
        handle.write(",".join(COLUMNS) + "\n")
        # each source's rows formatted by one %-operation over all of them (in C; a row's line is what
        # f"{t:.7f}", f"{v:.7g}" and f"{v:.10g}" write)
        sensor = np.column_stack([np.asarray(record.sensor_time_s, dtype=float).reshape(-1),
                                  np.asarray(record.wrench, dtype=float).reshape(-1, 6)])
        line = "sensor,%.7f," + ",".join(["%.7g"] * 6) + empty_joints + "\n"
        handle.write((line * len(sensor)) % tuple(sensor.ravel().tolist()))
        robot = np.column_stack([np.asarray(record.robot_time_s, dtype=float).reshape(-1),
                                 *(np.asarray(x, dtype=float).reshape(-1, 6) for x in (record.q, record.qd, record.qdd))])
        line = "robot,%.7f" + empty_wrench + "," + ",".join(["%.10g"] * 18) + "\n"
        handle.write((line * len(robot)) % tuple(robot.ravel().tolist()))


def read_motion_csv(path: str | os.PathLike) -> tuple[MotionRecord, str | None]:
    """Read a motion record CSV; return (record, the model named on its first line or None).

    Raises InputError naming the file, line and column on a bad value."""
    path = Path(path)
    try:
        handle = path.open(newline="", encoding="utf-8")
    except OSError as error:
        raise InputError(f"{path}: cannot read: {error}") from error
    model, servo_lag_s = None, None
    sensor_rows: list[list[float]] = []
    robot_rows: list[list[float]] = []
    with handle:
        lines = iter(handle)
        first = next(lines, "")
        comment = bool(_HEADER_LINE.match(first))
        if comment:
            match, lag = _MODEL_LINE.match(first), _SERVO_LAG.search(first)
            model = match.group(1) if match else None
            servo_lag_s = 1e-3 * float(lag.group(1)) if lag else None
            first = next(lines, "")
        reader = csv.reader([first])
        header = [h.strip() for h in next(reader, [])]
        if tuple(header) != COLUMNS:
            raise InputError(f"{path}: header must be {','.join(COLUMNS)} (see docs/dynamics.md), got {','.join(header)}")
        wrench_cols = slice(2, 8)
        joint_cols = slice(8, 8 + len(JOINT_COLUMNS))
        for line_number, row in enumerate(csv.reader(lines), start=3 if comment else 2):
            if not row:
                continue
            if len(row) != len(COLUMNS):
                raise InputError(f"{path}: line {line_number}: {len(row)} fields, expected {len(COLUMNS)}")
            source = row[0].strip()
            columns = wrench_cols if source == "sensor" else joint_cols if source == "robot" else None
            if columns is None:
                raise InputError(f"{path}: line {line_number}: column 'source': {source!r} is not sensor or robot")
            try:
                values = [float(row[1])] + [float(v) for v in row[columns]]
            except ValueError:
                bad = next(i for i, v in enumerate(row) if i == 1 or columns.start <= i < columns.stop
                           if not _is_float(v))
                raise InputError(f"{path}: line {line_number}: column {COLUMNS[bad]!r}: {row[bad]!r} is not a "
                                 "number") from None
            if not np.all(np.isfinite(values)):
                raise InputError(f"{path}: line {line_number}: a value is not finite")
            (sensor_rows if source == "sensor" else robot_rows).append(values)
    sensor = np.array(sensor_rows).reshape(-1, 7)
    robot = np.array(robot_rows).reshape(-1, 19)
    if len(sensor) == 0 or len(robot) == 0:
        raise InputError(f"{path}: needs both sensor and robot rows ({len(sensor)} sensor, {len(robot)} robot)")
    sensor = sensor[np.argsort(sensor[:, 0], kind="stable")]
    robot = robot[np.argsort(robot[:, 0], kind="stable")]
    record = MotionRecord(sensor[:, 0], sensor[:, 1:7], robot[:, 0], robot[:, 1:7], robot[:, 7:13], robot[:, 13:19],
                          metadata={"file": str(path)} | ({"servo_lag_s": servo_lag_s} if servo_lag_s is not None else {}))
    return record, model


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
