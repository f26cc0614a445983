"""The pose record: one CSV row per still pose (flange pose + mean sensor wrench), read and written here.

Required columns (any order): ``x, y, z`` flange position in the robot base frame (m); ``rx, ry, rz`` the
rotation vector of ``base_R_flange`` (rad; UR ``actual_TCP_pose`` with a zero TCP offset); ``fx, fy, fz``
(N) and ``tx, ty, tz`` (N·m), the mean sensor reading at that pose in the sensor frame.

Optional columns (read when present; an empty cell means "not given"): see :data:`OPTIONAL_COLUMNS`.
``std_*`` is the sample standard deviation of the samples averaged (same units as the channel) and
``count`` their number, so the standard error of the mean is ``std / sqrt(count)``.

Units: N and N·m unless the file declares others per kind, by a column suffix (``tx_Nmm``), a comment line
before the header (``# torque_unit: N-mm``) or the reader's ``force_unit`` / ``torque_unit`` (the command's
``--torque-unit``); names from the one table in :mod:`ftacq.units`. Two declarations that disagree are refused;
values are converted to SI on reading (``PoseRecord.units`` says what the file was in).

The procedure writes one row at a time (``POSE_CSV_HEADER`` once, then :func:`format_pose_row` per pose)
and fsyncs each row itself; :func:`write_pose_csv` writes a whole record atomically.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from ftacq.channels import WRENCH_COLUMNS
from ftacq.errors import InputError
from ftacq.fileio import atomic_write
from ftacq.so3 import rotation_from_rotvec
from ftacq.unitcolumns import unit_header_map

POSE_COLUMNS = ("x", "y", "z", "rx", "ry", "rz") + WRENCH_COLUMNS
"""Required columns: flange pose [m, rad] in the base frame, mean wrench [N, N·m] in the sensor frame."""

STD_COLUMNS = tuple(f"std_{name}" for name in WRENCH_COLUMNS)
JOINT_COLUMNS = tuple(f"q{i}" for i in range(6))

TEXT_COLUMNS = ("label", "set")
"""Optional text columns: ``label`` names the pose (e.g. ``A07``), ``set`` its pose set (``A``, ``E``, ``V``)."""

NUMERIC_OPTIONAL_COLUMNS = (
    "count",  # samples averaged (excluding saturated ones), integer ≥ 1
    *STD_COLUMNS,  # sample standard deviation per channel, N or N·m, ≥ 0
    "saturated",  # samples excluded as saturated / error status, integer ≥ 0
    "lost",  # samples lost in transit during the window, integer ≥ 0
    "t_start_s",  # start of the averaging window, s (host monotonic clock or UNIX time)
    "t_end_s",  # end of the averaging window, s
    *JOINT_COLUMNS,  # joint positions, rad
)
OPTIONAL_COLUMNS = TEXT_COLUMNS + NUMERIC_OPTIONAL_COLUMNS
"""Optional columns the reader understands; any other column is ignored."""

_INTEGER_COLUMNS = ("count", "saturated", "lost")

CSV_COLUMN_ORDER = ("label", "set", *POSE_COLUMNS, *NUMERIC_OPTIONAL_COLUMNS)
"""Column order :func:`write_pose_csv` and :data:`POSE_CSV_HEADER` use."""

POSE_CSV_HEADER = ",".join(CSV_COLUMN_ORDER) + "\n"
"""The header line (with newline) matching :func:`format_pose_row`."""


@dataclass(frozen=True)
class PoseRecord:
    """Still poses and the mean sensor wrench at each (N poses).

    Attributes:
        pose: (N, 6) flange pose in the base frame [x, y, z (m), rx, ry, rz (rad)], rotation vector of
            ``base_R_flange``.
        wrench: (N, 6) mean reading [Fx, Fy, Fz (N), Tx, Ty, Tz (N·m)] in the sensor frame.
        std: (N, 6) sample standard deviation per channel (same units), or None.
        count: (N,) samples averaged per pose, or None.
        labels: pose names (default ``P1``, ``P2``, … in row order).
        sets: pose-set names ("A", "E", "V", or "" when unknown).
        extra: other optional numeric columns by name, each (N,) (NaN where a cell was empty).
        units: the units the file was in, ``{"force": "N", "torque": "N-mm"}`` (converted to SI on reading);
            empty when the record was not read from a file.
    """

    pose: np.ndarray
    wrench: np.ndarray
    std: np.ndarray | None = None
    count: np.ndarray | None = None
    labels: tuple[str, ...] = ()
    sets: tuple[str, ...] = ()
    extra: dict = field(default_factory=dict)
    units: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        pose = np.array(self.pose, dtype=float).reshape(-1, 6)
        n = pose.shape[0]
        wrench = np.array(self.wrench, dtype=float).reshape(-1, 6)
        if wrench.shape[0] != n:
            raise ValueError(f"PoseRecord: {n} poses but {wrench.shape[0]} wrenches")
        object.__setattr__(self, "pose", pose)
        object.__setattr__(self, "wrench", wrench)
        if self.std is not None:
            std = np.array(self.std, dtype=float).reshape(-1, 6)
            if std.shape[0] != n:
                raise ValueError(f"PoseRecord: std has {std.shape[0]} rows, expected {n}")
            object.__setattr__(self, "std", std)
        if self.count is not None:
            count = np.array(self.count, dtype=float).reshape(-1)
            if count.shape[0] != n:
                raise ValueError(f"PoseRecord: count has {count.shape[0]} rows, expected {n}")
            object.__setattr__(self, "count", count)
        labels = tuple(str(x) for x in self.labels) if self.labels else tuple(f"P{i + 1}" for i in range(n))
        sets = tuple(str(x) for x in self.sets) if self.sets else ("",) * n
        if len(labels) != n or len(sets) != n:
            raise ValueError(f"PoseRecord: {len(labels)} labels / {len(sets)} sets for {n} poses")
        object.__setattr__(self, "labels", labels)
        object.__setattr__(self, "sets", sets)
        extra = {}
        for name, values in dict(self.extra).items():
            values = np.asarray(values, dtype=float).reshape(-1)
            if values.shape[0] != n:
                raise ValueError(f"PoseRecord: extra column {name!r} has {values.shape[0]} rows, expected {n}")
            extra[name] = values
        object.__setattr__(self, "extra", extra)

    def __len__(self) -> int:
        return int(self.pose.shape[0])

    @property
    def flange_R_base(self) -> np.ndarray:
        """(N, 3, 3) rotations mapping base-frame vectors into the flange frame (= base_R_flangeᵀ)."""
        return np.swapaxes(rotation_from_rotvec(self.pose[:, 3:]), -1, -2)

    @property
    def standard_error(self) -> np.ndarray | None:
        """(N, 6) standard error of each mean, ``std / sqrt(count)``, or None when std or count is missing."""
        if self.std is None or self.count is None:
            return None
        return self.std / np.sqrt(np.maximum(self.count, 1.0))[:, None]

    def select(self, mask_or_indices: np.ndarray | Sequence[int] | Sequence[bool]) -> "PoseRecord":
        """Return the record restricted to a boolean mask or an index list (in that order)."""
        index = np.asarray(mask_or_indices)
        if index.dtype == bool:
            if index.shape != (len(self),):
                raise ValueError(f"select: mask of shape {index.shape}, expected ({len(self)},)")
            index = np.flatnonzero(index)
        index = index.astype(int).reshape(-1)
        return PoseRecord(
            pose=self.pose[index],
            wrench=self.wrench[index],
            std=None if self.std is None else self.std[index],
            count=None if self.count is None else self.count[index],
            labels=tuple(self.labels[i] for i in index),
            sets=tuple(self.sets[i] for i in index),
            extra={name: values[index] for name, values in self.extra.items()},
            units=dict(self.units),
        )


# --------------------------------------------------------------------------------------------- reading


def _parse_float(text: str, path: Path, line: int, column: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"{path}: line {line}, column {column!r}: value {text!r} is not a number") from None
    if not math.isfinite(value):
        raise InputError(f"{path}: line {line}, column {column!r}: value {text!r} is not finite")
    return value


def read_csv_table(
    path: str | os.PathLike, required: Iterable[str],
    header_map: Callable[[list[str], int], list[str]] | None = None,
) -> tuple[list[str], list[list[str]], list[int]]:
    """Read a CSV file with a header: return (lower-case header, rows of stripped cells, 1-based line numbers).

    Blank lines and lines starting with ``#`` are skipped. ``header_map(header, line)`` may rename the
    lower-case header's columns (e.g. strip a unit suffix) before the duplicate and required checks.

    Raises InputError (naming the file, line and column) when the file cannot be read, is empty, has a
    duplicated or missing required column, or a row with the wrong number of cells.
    """
    path = Path(path)
    required = list(required)
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            reader = csv.reader(handle)
            rows = [row for row in reader]
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise InputError(f"{path}: cannot read: {error}") from error
    # skip blank lines and '#' comment lines, keep 1-based line numbers
    numbered = [(i + 1, row) for i, row in enumerate(rows) if row and any(c.strip() for c in row)]
    numbered = [(i, row) for i, row in numbered if not row[0].lstrip().startswith("#")]
    if not numbered:
        raise InputError(f"{path}: empty file: expected a header line with columns {','.join(required)}")
    header_line, header = numbered[0]
    header = [c.strip().lower() for c in header]
    if header_map is not None:
        header = header_map(header, header_line)
    seen: dict[str, int] = {}
    for position, name in enumerate(header):
        if not name:
            raise InputError(f"{path}: line {header_line}: column {position + 1} of the header has no name")
        if name in seen:
            raise InputError(
                f"{path}: line {header_line}: column {name!r} appears twice (columns {seen[name] + 1} and {position + 1})"
            )
        seen[name] = position
    missing = [name for name in required if name not in seen]
    if missing:
        raise InputError(
            f"{path}: line {header_line}: missing required column(s) {', '.join(missing)} "
            f"(header is: {','.join(header)})"
        )
    body: list[list[str]] = []
    line_numbers: list[int] = []
    for line, row in numbered[1:]:
        if len(row) > len(header) and not any(c.strip() for c in row[len(header):]):
            row = row[: len(header)]  # trailing empty cells (a trailing comma) are harmless
        if len(row) != len(header):
            raise InputError(f"{path}: line {line}: {len(row)} cells, but the header has {len(header)} columns")
        body.append([c.strip() for c in row])
        line_numbers.append(line)
    return header, body, line_numbers


def numeric_column(
    path: Path, header: list[str], rows: list[list[str]], lines: list[int], name: str, *, optional: bool = False
) -> np.ndarray:
    """Return column ``name`` as floats; empty cells are NaN when ``optional`` (else an InputError)."""
    position = header.index(name)
    out = np.empty(len(rows))
    for k, row in enumerate(rows):
        text = row[position]
        if text == "":
            if not optional:
                raise InputError(f"{path}: line {lines[k]}, column {name!r}: empty cell (a number is required)")
            out[k] = np.nan
        else:
            out[k] = _parse_float(text, path, lines[k], name)
    return out


def unique_labels(labels: tuple[str, ...]) -> tuple[str, ...]:
    """Return the labels with repeats made unique by a suffix (``A01``, ``A01#2``, …) so outliers can be named."""
    seen: dict[str, int] = {}
    out = []
    for label in labels:
        seen[label] = seen.get(label, 0) + 1
        out.append(label if seen[label] == 1 else f"{label}#{seen[label]}")
    return tuple(out)



def read_pose_csv(path: str | os.PathLike, *, force_unit: str | None = None,
                  torque_unit: str | None = None) -> PoseRecord:
    """Read a pose record CSV (see the module docstring). Raises InputError naming file, line, column, value, why.

    Wrench (and std) columns are converted to N and N·m from the unit their suffix (``tx_Nmm``), ``force_unit`` /
    ``torque_unit`` (names of :mod:`ftacq.units`) or a header comment (``# torque_unit: N-mm``) declares; SI when
    none does. The units read are in the record's ``units``.
    """
    path = Path(path)
    strip_units, resolved = unit_header_map(path, force_unit, torque_unit)
    header, rows, lines = read_csv_table(path, POSE_COLUMNS, strip_units)
    if not rows:
        raise InputError(f"{path}: no data rows after the header")
    required = np.column_stack([numeric_column(path, header, rows, lines, name) for name in POSE_COLUMNS])
    factor = np.ones(12)
    factor[6:] = [resolved["factor"][name] for name in WRENCH_COLUMNS]
    required = required * factor
    optional: dict[str, np.ndarray] = {}
    for name in NUMERIC_OPTIONAL_COLUMNS:
        if name in header:
            values = numeric_column(path, header, rows, lines, name, optional=True)
            if not np.all(np.isnan(values)):
                optional[name] = values
    for name in (*STD_COLUMNS, *_INTEGER_COLUMNS):
        present = optional.get(name)
        if present is None:
            continue
        bad = np.flatnonzero(present < 0)
        if bad.size:
            k = int(bad[0])
            raise InputError(f"{path}: line {lines[k]}, column {name!r}: value {rows[k][header.index(name)]!r} is negative")
    if "count" in optional:
        values = optional["count"]
        bad = np.flatnonzero(~np.isnan(values) & ((values < 1) | (values != np.round(values))))
        if bad.size:
            k = int(bad[0])
            raise InputError(
                f"{path}: line {lines[k]}, column 'count': value {rows[k][header.index('count')]!r} "
                "is not a whole number ≥ 1"
            )
    std = None
    present_std = [name for name in STD_COLUMNS if name in optional]
    if present_std:
        if len(present_std) != 6:
            absent = [name for name in STD_COLUMNS if name not in optional]
            raise InputError(f"{path}: std columns must come as a set of six; missing {', '.join(absent)}")
        std = np.column_stack([optional.pop(name) for name in STD_COLUMNS]) * factor[6:]
        incomplete = np.flatnonzero(np.isnan(std).any(axis=1) & ~np.isnan(std).all(axis=1))
        if incomplete.size:
            k = int(incomplete[0])
            raise InputError(f"{path}: line {lines[k]}: some std_* cells are empty and others not")
        if np.isnan(std).any():
            std = None  # some poses without std: weights are estimated from residuals instead
    count = optional.pop("count", None)
    if count is not None and np.isnan(count).any():
        count = None
    labels: tuple[str, ...] = ()
    if "label" in header:
        position = header.index("label")
        labels = tuple(row[position] or f"P{k + 1}" for k, row in enumerate(rows))
        labels = unique_labels(labels)
    sets: tuple[str, ...] = ()
    if "set" in header:
        position = header.index("set")
        sets = tuple(row[position] for row in rows)
    return PoseRecord(
        pose=required[:, :6],
        wrench=required[:, 6:],
        std=std,
        count=count,
        labels=labels,
        sets=sets,
        extra=optional,
        units=resolved["units"],
    )


# --------------------------------------------------------------------------------------------- writing


def _format_number(value: float | None) -> str:
    if value is None:
        return ""
    value = float(value)
    if math.isnan(value):
        return ""
    if value == int(value) and abs(value) < 1e15:
        return str(int(value))
    return repr(value)


def _csv_text(text: str) -> str:
    if any(c in text for c in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text


def format_pose_row(
    pose: Sequence[float],
    wrench: Sequence[float],
    *,
    label: str = "",
    set_name: str = "",
    count: int | None = None,
    std: Sequence[float] | None = None,
    saturated: float | None = None,
    lost: float | None = None,
    t_start_s: float | None = None,
    t_end_s: float | None = None,
    joint_positions_rad: Sequence[float] | None = None,
) -> str:
    """Return one CSV line (with newline) in the :data:`POSE_CSV_HEADER` column order.

    ``pose`` [x, y, z (m), rx, ry, rz (rad)], ``wrench`` [N, N·m], ``std`` per channel (same units),
    ``joint_positions_rad`` (6,). ``saturated`` and ``lost`` are sample counts, given as int or as the float a
    pose CSV was read back into (written as whole numbers when whole). Values are written with full float64 precision (``repr``).
    """
    pose = [float(v) for v in pose]
    wrench = [float(v) for v in wrench]
    if len(pose) != 6 or len(wrench) != 6:
        raise ValueError("format_pose_row: pose and wrench need 6 values each")
    std_cells = [None] * 6 if std is None else [float(v) for v in std]
    joints = [None] * 6 if joint_positions_rad is None else [float(v) for v in joint_positions_rad]
    cells = [_csv_text(str(label)), _csv_text(str(set_name))]
    cells += [_format_number(v) for v in (*pose, *wrench)]
    cells.append(_format_number(count))
    cells += [_format_number(v) for v in std_cells]
    cells += [_format_number(v) for v in (saturated, lost, t_start_s, t_end_s)]
    cells += [_format_number(v) for v in joints]
    return ",".join(cells) + "\n"


def write_pose_csv(path: str | os.PathLike, record: PoseRecord) -> None:
    """Write a whole record atomically (temporary file, fsync, rename) with :data:`POSE_CSV_HEADER`."""
    extra = record.extra

    def column(name: str, i: int) -> float | None:
        values = extra.get(name)
        return None if values is None else float(values[i])

    with atomic_write(path) as handle:
        handle.write(POSE_CSV_HEADER)
        for i in range(len(record)):
            joints = [column(name, i) for name in JOINT_COLUMNS]
            handle.write(
                format_pose_row(
                    record.pose[i],
                    record.wrench[i],
                    label=record.labels[i],
                    set_name=record.sets[i],
                    count=None if record.count is None else record.count[i],
                    std=None if record.std is None else record.std[i],
                    saturated=column("saturated", i),
                    lost=column("lost", i),
                    t_start_s=column("t_start_s", i),
                    t_end_s=column("t_end_s", i),
                    joint_positions_rad=None if all(j is None for j in joints) else [
                        np.nan if j is None else j for j in joints
                    ],
                )
            )
