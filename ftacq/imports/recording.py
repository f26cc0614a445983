"""Read a recording made by another tool into a pose record: :func:`import_recording` (the package docstring says
what it reads; the options are :mod:`ftacq.imports.options`)."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ftacq.errors import InputError
from ftacq.imports.options import (
    DEFAULT_COLUMNS,
    ORIENTATIONS,
    QUATERNION_ORDERS,
    WRENCH_FRAMES,
    ImportOptions,
)
from ftacq.imports.orientation import (
    from_matrices,
    from_quaternions,
    from_rotation_vectors,
    to_rotation_vectors,
)
from ftacq.imports.wrench_frame import sensor_from_base
from ftacq.posefile import (
    JOINT_COLUMNS,
    STD_COLUMNS,
    WRENCH_COLUMNS,
    PoseRecord,
    numeric_column,
    read_csv_table,
    unique_labels,
)
from ftacq.unitcolumns import unit_header_map

_JOINT = re.compile(r"^q(\d+)$")


@dataclass(frozen=True)
class ImportResult:
    """The pose record and one line per thing the import did (units converted, frame rotated, positions filled)."""

    record: PoseRecord
    notes: tuple[str, ...]


def _check(options: ImportOptions) -> None:
    if options.orientation not in ORIENTATIONS:
        raise InputError(f"orientation {options.orientation!r}: must be one of {', '.join(ORIENTATIONS)}")
    if options.quaternion_order not in QUATERNION_ORDERS:
        raise InputError(f"quaternion order {options.quaternion_order!r}: must be one of "
                         f"{', '.join(QUATERNION_ORDERS)}")
    if options.wrench_frame not in WRENCH_FRAMES:
        raise InputError(f"wrench frame {options.wrench_frame!r}: must be one of {', '.join(WRENCH_FRAMES)}")
    if options.orientation == "joints" and options.robot is None:
        raise InputError("joint angles need a robot model: a UR model, a DH table or a URDF")
    expected = {"quaternion": 4, "matrix": 9, "rotvec": 3}.get(options.orientation)
    if options.orientation_columns is not None and expected and len(options.orientation_columns) != expected:
        raise InputError(f"{options.orientation} needs {expected} orientation columns, got "
                         f"{len(options.orientation_columns)} ({','.join(options.orientation_columns)})")


def import_recording(path: str | os.PathLike, options: ImportOptions) -> ImportResult:
    """Read the recording at ``path`` as ``options`` say; return the pose record (SI, sensor frame) and notes."""
    _check(options)
    path = Path(path)
    rename = {k.strip().lower(): v.strip().lower() for k, v in options.rename.items()}

    def renamed(header: list[str]) -> list[str]:
        missing = [name for name in rename if name not in header]
        if missing:
            raise InputError(f"{path}: cannot rename column(s) {', '.join(missing)}: not in the header "
                             f"({','.join(header)})")
        return [rename.get(name, name) for name in header]

    header_map, resolved = unit_header_map(path, options.force_unit, options.torque_unit, renamed)
    header, rows, lines = read_csv_table(path, WRENCH_COLUMNS, header_map)
    if not rows:
        raise InputError(f"{path}: no data rows after the header")

    def columns(names: tuple[str, ...], what: str) -> np.ndarray:
        absent = [name for name in names if name.lower() not in header]
        if absent:
            raise InputError(f"{path}: {what}: missing column(s) {', '.join(absent)} (header is: {','.join(header)})")
        return np.column_stack([numeric_column(path, header, rows, lines, name.lower()) for name in names])

    orientation = options.orientation
    if orientation == "auto":
        found = [kind for kind, names in DEFAULT_COLUMNS.items() if all(name in header for name in names)]
        if options.robot is not None:
            orientation = "joints"
        elif len(found) == 1:
            orientation = found[0]
        else:
            raise InputError(f"{path}: cannot tell the orientation from the header ({','.join(header)}): give "
                             "--orientation (and --robot, --dh-table or --urdf for joint angles)")
    notes: list[str] = []
    wrench = columns(WRENCH_COLUMNS, "wrench") * np.array([resolved["factor"][c] for c in WRENCH_COLUMNS])
    converted = {kind: unit for kind, unit in resolved["units"].items() if unit not in ("N", "N-m")}
    if converted:
        notes.append("units: " + ", ".join(f"{kind} in {unit}" for kind, unit in converted.items())
                     + " converted to N and N·m")
    joints = None
    if orientation == "joints":
        assert options.robot is not None
        names = options.orientation_columns or tuple(
            sorted((n for n in header if _JOINT.match(n)), key=lambda n: int(_JOINT.match(n).group(1))))  # type: ignore[union-attr]
        if len(names) != options.robot.joints:
            raise InputError(f"{path}: the robot model {options.robot.name} has {options.robot.joints} joints but "
                             f"the recording gives {len(names)} joint column(s) ({','.join(names) or 'none'})")
        joints = columns(tuple(names), "joint angles")
        base_T_flange = options.robot.flange_transforms(joints)
        rotations, position = base_T_flange[:, :3, :3], base_T_flange[:, :3, 3]
        notes.append(f"flange poses from {len(names)} joint angles through the {options.robot.name} model")
    else:
        names = options.orientation_columns or DEFAULT_COLUMNS[orientation]
        values = columns(tuple(names), orientation)
        if orientation == "quaternion":
            order = options.quaternion_order
            if options.orientation_columns is None:
                order = "xyzw"  # the default names say which is which
            rotations = from_quaternions(values, order, str(path), lines)
        elif orientation == "matrix":
            rotations = from_matrices(values, str(path), lines)
        else:
            rotations = from_rotation_vectors(values)
        if all(name.lower() in header for name in options.position_columns):
            position = columns(tuple(options.position_columns), "position")
        else:
            position = np.zeros((len(rows), 3))
            notes.append(f"no position columns ({','.join(options.position_columns)}): flange positions written as 0 "
                         "(the identification does not use them)")
    std = None
    if all(name in header for name in STD_COLUMNS):  # kept only when every row gives all six
        std = np.column_stack([numeric_column(path, header, rows, lines, name, optional=True)
                               for name in STD_COLUMNS]) * np.array([resolved["factor"][c] for c in WRENCH_COLUMNS])
        if np.isnan(std).any() or (std < 0).any():
            std = None
    count = None
    if "count" in header:
        count = numeric_column(path, header, rows, lines, "count", optional=True)
        bad = np.flatnonzero(~np.isnan(count) & ((count < 1) | (count != np.round(count))))
        if bad.size:
            raise InputError(f"{path}: line {lines[int(bad[0])]}, column 'count': value {count[bad[0]]:g} is not a "
                             "whole number ≥ 1")
    extra: dict[str, np.ndarray] = {}
    if joints is not None and joints.shape[1] == len(JOINT_COLUMNS):
        extra.update({name: joints[:, i] for i, name in enumerate(JOINT_COLUMNS)})
    if options.time_column:
        time_s = columns((options.time_column,), "time")[:, 0]
        extra["t_start_s"] = extra["t_end_s"] = time_s
    labels = unique_labels(tuple(row[header.index("label")] or f"P{k + 1}" for k, row in enumerate(rows))) \
        if "label" in header else ()
    sets = tuple(row[header.index("set")] for row in rows) if "set" in header else ()
    pose = np.hstack([position, to_rotation_vectors(rotations)])
    record = PoseRecord(pose=pose, wrench=wrench, std=std, count=count, labels=labels, sets=sets, extra=extra,
                        units={"force": "N", "torque": "N-m"})
    if options.wrench_frame == "base":
        record = sensor_from_base(record)
        notes.append("wrenches rotated from the base frame into the flange frame (flange_R_base · w)")
    if count is not None and np.isnan(count).any():
        record = replace(record, count=None)
    return ImportResult(record, tuple(notes))


__all__ = ["ImportResult", "import_recording"]
