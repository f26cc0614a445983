"""``ftacq compensate CALIBRATION.json POSES.csv [-o OUT.csv]``: the contact wrench of every row.

Reads any CSV with the rotation (``rx, ry, rz``: rotation vector of base_R_flange, rad) and wrench
(``fx .. tz``: N, N·m, sensor frame) columns — a pose record or a sensor record — and writes every input
column followed by ``contact_fx .. contact_tz`` (N, N·m, sensor frame): the reading minus the predicted
gravity wrench and the biases.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REQUIRED_COLUMNS = ("rx", "ry", "rz", "fx", "fy", "fz", "tx", "ty", "tz")
CONTACT_COLUMNS = ("contact_fx", "contact_fy", "contact_fz", "contact_tx", "contact_ty", "contact_tz")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``compensate`` sub-command."""
    parser = subparsers.add_parser(
        "compensate",
        help="subtract the identified gravity wrench and biases from recorded readings",
        description=(
            "For every row of a CSV with columns rx, ry, rz (flange rotation vector, rad) and fx..tz (N, N·m), "
            "write the row followed by contact_fx..contact_tz, the compensated contact wrench."
        ),
    )
    parser.add_argument("calibration", metavar="CALIBRATION.json", help="calibration written by ftacq identify")
    parser.add_argument("poses", metavar="POSES.csv", help="pose record or sensor record CSV")
    parser.add_argument("-o", "--output", metavar="OUT.csv", help="write here (atomically) instead of standard output")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Compensate every row; return the exit status."""
    import numpy as np

    from ftacq.calfile import load_calibration
    from ftacq.fileio import atomic_write
    from ftacq.posefile import numeric_column, read_csv_table
    from ftacq.so3 import rotation_from_rotvec

    calibration = load_calibration(args.calibration)
    path = Path(args.poses)
    header, rows, lines = read_csv_table(path, REQUIRED_COLUMNS)
    values = np.column_stack([numeric_column(path, header, rows, lines, name) for name in REQUIRED_COLUMNS]) if rows else np.zeros((0, 9))
    flange_R_base = np.swapaxes(rotation_from_rotvec(values[:, :3]), -1, -2)
    contact = calibration.compensate(values[:, 3:], flange_R_base) if rows else np.zeros((0, 6))
    # an input that already has contact_* columns (a compensated file) keeps them; ours get a suffix
    out_header = header + [name if name not in header else f"{name}_new" for name in CONTACT_COLUMNS]

    def write(handle) -> None:
        handle.write(",".join(out_header) + "\n")
        for row, wrench in zip(rows, contact):
            cells = [c if not any(x in c for x in ',"\n') else '"' + c.replace('"', '""') + '"' for c in row]
            handle.write(",".join(cells + [repr(float(v)) for v in wrench]) + "\n")

    if args.output:
        with atomic_write(args.output) as handle:
            write(handle)
        print(f"wrote {len(rows)} compensated rows to {args.output}", file=sys.stderr)
    else:
        write(sys.stdout)
    return 0
