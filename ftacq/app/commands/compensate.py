"""``ftacq compensate CALIBRATION.json POSES.csv [-o OUT.csv]``: the contact wrench of every row.

Reads any CSV with the rotation (``rx, ry, rz``: rotation vector of base_R_flange, rad) and wrench
(``fx .. tz``, sensor frame) columns — a pose record or a sensor (monitor) record — and writes every input column
followed by ``contact_fx .. contact_tz`` (N, N·m, sensor frame): the reading minus the predicted
gravity wrench and the biases. Existing ``contact_*`` columns are overwritten; rows whose rotation cells are
all empty (recorded without a robot) keep empty contact cells. The wrench units are read as ``ftacq identify``
reads them (suffix, header comment, ``--force-unit``/``--torque-unit``; docs/formats.md); a file that declares
none while the calibration was identified from other units is read in those units when it is the very file
identified (the calibration's ``input`` record), and refused otherwise.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ftacq.app.helptext import examples
from ftacq.channels import CONTACT_COLUMNS, WRENCH_COLUMNS

REQUIRED_COLUMNS = ("rx", "ry", "rz") + WRENCH_COLUMNS


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``compensate`` sub-command."""
    parser = subparsers.add_parser(
        "compensate",
        help="subtract the identified gravity wrench and biases from recorded readings",
        description=(
            "For every row of a CSV with columns rx, ry, rz (flange rotation vector, rad) and fx..tz (N, N·m unless "
            "declared otherwise), write the row followed by contact_fx..contact_tz (N, N·m), the compensated contact "
            "wrench."
        ),
        **examples("ftacq compensate calibration.json poses.csv -o contact.csv",
                   "ftacq compensate calibration.json monitor.csv | head"),
    )
    parser.add_argument("calibration", metavar="CALIBRATION.json", help="calibration written by ftacq identify")
    parser.add_argument("poses", metavar="POSES.csv", help="pose record or sensor record CSV")
    parser.add_argument("-o", "--output", metavar="OUT.csv", help="write here (atomically) instead of standard output")
    from ftacq.app.commands.identify import add_unit_options

    add_unit_options(parser, "POSES.csv")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Compensate every row; return the exit status."""
    import numpy as np

    from ftacq.calfile import load_calibration
    from ftacq.fileio import atomic_write
    from ftacq.posefile import numeric_column, read_csv_table
    from ftacq.so3 import rotation_from_rotvec
    from ftacq.unitcolumns import adopt_identified_units, unit_header_map

    from ftacq.errors import InputError
    from ftacq.validation import MAX_FORCE_N, MAX_ROTATION_VECTOR_RAD, MAX_TORQUE_NM, check_output_file

    if args.output:
        check_output_file(args.output, "-o/--output")
    calibration = load_calibration(args.calibration)
    path = Path(args.poses)
    strip_units, units = unit_header_map(path, args.force_unit, args.torque_unit)
    as_written: list[str] = []  # the header with its unit suffixes, for the output

    def keep_suffixes(names: list[str], line: int) -> list[str]:
        as_written[:] = names
        return strip_units(names, line)

    header, rows, lines = read_csv_table(path, REQUIRED_COLUMNS, keep_suffixes)
    note = adopt_identified_units(path, units, calibration.metadata.get("input"))
    if note:
        print(f"ftacq compensate: {note}", file=sys.stderr)
    rotation_positions = [header.index(name) for name in REQUIRED_COLUMNS[:3]]
    # rows recorded without a robot pose (all of rx, ry, rz empty, as in a monitor record) stay uncompensated
    known = np.array([any(row[k] != "" for k in rotation_positions) for row in rows], dtype=bool)
    known_rows = [row for row, flag in zip(rows, known) if flag]
    known_lines = [line for line, flag in zip(lines, known) if flag]
    values = np.zeros((len(known_rows), 9))
    for k, name in enumerate(REQUIRED_COLUMNS):
        values[:, k] = numeric_column(path, header, known_rows, known_lines, name)
    values[:, 3:] *= np.array([units["factor"][name] for name in REQUIRED_COLUMNS[3:]])  # to N and N·m
    # beyond a robot's orientations or a sensor's range: refused with the line, never written as empty cells
    limits = np.array([MAX_ROTATION_VECTOR_RAD] * 3 + [MAX_FORCE_N] * 3 + [MAX_TORQUE_NM] * 3)
    bad = np.abs(values) > limits
    with np.errstate(over="ignore"):  # a norm of 1e300 is inf, and refused
        bad[:, :3] |= (np.linalg.norm(values[:, :3], axis=1) > MAX_ROTATION_VECTOR_RAD)[:, None]
    if bad.any():
        row, column = (int(v) for v in np.argwhere(bad)[0])
        name = REQUIRED_COLUMNS[column]
        why = ("the rotation vector is longer than two turns" if column < 3
               else f"|value| > {limits[column]:g} {'N' if column < 6 else 'N·m'} once read in "
                    f"{units['units']['force' if column < 6 else 'torque']}, beyond any F/T sensor's range (wrong units?)")
        raise InputError(f"{path}: line {known_lines[row]}, column {name!r}: value "
                         f"{known_rows[row][header.index(name)]!r}: {why}")
    flange_R_base = np.swapaxes(rotation_from_rotvec(values[:, :3]), -1, -2)
    contact = np.full((len(rows), 6), np.nan)
    if len(known_rows):
        contact[known] = calibration.compensate(values[:, 3:], flange_R_base)
    # contact_* columns already in the input (a monitor record) are overwritten; otherwise appended
    out_header = as_written + [name for name in CONTACT_COLUMNS if name not in header]
    contact_positions = [out_header.index(name) for name in CONTACT_COLUMNS]

    def write(handle) -> None:
        handle.write(",".join(out_header) + "\n")
        width = len(out_header)
        for row, wrench in zip(rows, contact):
            cells = [c if not any(x in c for x in ',"\n') else '"' + c.replace('"', '""') + '"' for c in row]
            cells += [""] * (width - len(cells))
            for position, value in zip(contact_positions, wrench):
                cells[position] = "" if np.isnan(value) else repr(float(value))
            handle.write(",".join(cells) + "\n")

    if args.output:
        with atomic_write(args.output) as handle:
            write(handle)
        print(f"wrote {int(known.sum())} compensated rows to {args.output}", file=sys.stderr)
    else:
        try:
            write(sys.stdout)
            sys.stdout.flush()
        except BrokenPipeError:  # e.g. piped into `head`: not an error
            pass
    if not known.all():
        print(f"ftacq: {int((~known).sum())} rows without a flange pose were left uncompensated", file=sys.stderr)
    return 0
