"""``ftacq import RECORDING.csv -o POSES.csv``: convert a recording made by another tool into a pose record.

The flange orientation as quaternions (scalar last or first), rotation matrices, rotation vectors, or joint angles
with a robot model (a UR model, a DH table, a URDF; Pinocchio computes the flange pose); wrenches in the sensor or
the base frame, in any unit of ftacq/units.py. The core is :mod:`ftacq.imports`; formats: docs/formats.md.
"""

from __future__ import annotations

import argparse
import sys

from ftacq.app.helptext import examples
from ftacq.imports.options import ORIENTATIONS, POSITION_COLUMNS, QUATERNION_ORDERS, WRENCH_FRAMES, ImportOptions


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``import`` sub-command."""
    parser = subparsers.add_parser(
        "import",
        help="convert a recording (quaternions, rotation matrices, joint angles; base- or sensor-frame wrenches) "
             "into a pose record for identify",
        description="Read a CSV of still poses recorded by another tool and write a pose record (docs/formats.md): "
                    "the flange pose as a UR rotation vector and the wrench in the sensor frame, in N and N·m. "
                    "The orientation is found from the columns (rx ry rz; qx qy qz qw; r11 … r33; q1 … qn with "
                    "--robot, --dh-table or --urdf) unless --orientation says. Nothing is written if the input is "
                    "bad.",
        **examples("ftacq import log.csv -o poses.csv --orientation quaternion --quaternion-order wxyz "
                   "--orientation-columns w,x,y,z",
                   "ftacq import log.csv -o poses.csv --dh-table arm-dh.csv --torque-unit N-mm",
                   "ftacq import log.csv -o poses.csv --robot UR5e --wrench-frame base"),
    )
    parser.add_argument("recording", metavar="RECORDING.csv", help="one row per still pose, with a header")
    parser.add_argument("-o", "--output", metavar="POSES.csv", required=True, help="pose record to write")
    pose = parser.add_argument_group("flange pose")
    pose.add_argument("--orientation", choices=ORIENTATIONS, default=ImportOptions.orientation,
                      help="how the recording gives the flange orientation in the base frame (default: from the "
                           "column names)")
    pose.add_argument("--quaternion-order", choices=QUATERNION_ORDERS,
                      default=ImportOptions.quaternion_order,
                      help="order of --orientation-columns for quaternions: scalar last (ROS, scipy) or first "
                           "(ABB, MATLAB); default xyzw")
    pose.add_argument("--orientation-columns", metavar="A,B,…",
                      help="the orientation's columns in order (default rx,ry,rz; qx,qy,qz,qw; r11,…,r33 row-major; "
                           "every q<n> column for joints)")
    pose.add_argument("--position-columns", metavar="X,Y,Z", default=",".join(POSITION_COLUMNS),
                      help="the flange position's columns, m (default x,y,z; absent: written as 0)")
    robot = pose.add_mutually_exclusive_group()
    robot.add_argument("--robot", metavar="MODEL", help="joint angles of a UR arm (UR5e, UR10e, …)")
    robot.add_argument("--dh-table", metavar="DH.csv",
                       help="joint angles of any arm with this standard DH table (columns alpha, a, d, offset; rad, "
                            "m; docs/formats.md)")
    robot.add_argument("--urdf", metavar="ROBOT.urdf", help="joint angles of the arm in this URDF")
    pose.add_argument("--urdf-frame", metavar="FRAME", help="the URDF frame that is the flange (default tool0, "
                                                            "flange or ee_link, the first present)")
    wrench = parser.add_argument_group("wrench")
    wrench.add_argument("--wrench-frame", choices=WRENCH_FRAMES, default=ImportOptions.wrench_frame,
                        help="frame of the recorded wrenches: the sensor's (default) or the robot base frame "
                             "(torques about the sensor origin)")
    wrench.add_argument("--force-unit", metavar="UNIT", help="unit of fx fy fz when the file does not say (N, kN, "
                                                             "lbf, kgf, gf, klbf)")
    wrench.add_argument("--torque-unit", metavar="UNIT", help="unit of tx ty tz when the file does not say (N-m, "
                                                              "N-mm, lbf-in, lbf-ft, kgf-cm, kN-m)")
    parser.add_argument("--time-column", metavar="NAME", help="a column of time stamps, s (kept as t_end_s)")
    parser.add_argument("--rename", metavar="OLD=NEW", action="append", default=[],
                        help="read column OLD as NEW (e.g. Fx=fx); repeat for each column")
    parser.set_defaults(func=run)


def _names(text: str | None, option: str) -> tuple[str, ...] | None:
    from ftacq.errors import InputError

    if text is None:
        return None
    names = tuple(part.strip().lower() for part in text.split(","))
    if not all(names):
        raise InputError(f"{option} {text!r}: a comma-separated list of column names")
    return names


def run(args: argparse.Namespace) -> int:
    """Import, write the pose record, print what was done; return the exit status."""
    from pathlib import Path

    from ftacq.errors import InputError
    from ftacq.identification.diagnostics import MIN_POSES
    from ftacq.imports import import_recording
    from ftacq.imports.robot_model import dh_arm_model, read_dh_table, ur_arm_model, urdf_arm_model
    from ftacq.imports.wrench_frame import frame_mismatch
    from ftacq.posefile import write_pose_csv
    from ftacq.validation import check_output_file

    check_output_file(args.output, "-o/--output")
    robot = None
    if args.robot:
        try:
            robot = ur_arm_model(args.robot)
        except ValueError as error:
            raise InputError(f"--robot {args.robot}: {error}") from None
    elif args.dh_table:
        robot = dh_arm_model(read_dh_table(args.dh_table), f"DH table {Path(args.dh_table).name}")
    elif args.urdf:
        robot = urdf_arm_model(args.urdf, args.urdf_frame)
    rename = {}
    for item in args.rename:
        old, sep, new = item.partition("=")
        if not sep or not old.strip() or not new.strip():
            raise InputError(f"--rename {item!r}: give OLD=NEW")
        rename[old] = new
    position = _names(args.position_columns, "--position-columns")
    if position is None or len(position) != 3:
        raise InputError(f"--position-columns {args.position_columns!r}: three column names")
    options = ImportOptions(
        orientation=args.orientation, quaternion_order=args.quaternion_order,
        orientation_columns=_names(args.orientation_columns, "--orientation-columns"),
        position_columns=(position[0], position[1], position[2]), robot=robot, wrench_frame=args.wrench_frame,
        force_unit=args.force_unit, torque_unit=args.torque_unit,
        time_column=args.time_column.strip().lower() if args.time_column else None, rename=rename)
    result = import_recording(args.recording, options)
    write_pose_csv(args.output, result.record)
    for note in result.notes:
        print(note)
    print(f"wrote {len(result.record)} poses to {args.output}")
    if len(result.record) >= MIN_POSES:
        hint, _ = frame_mismatch(result.record, args.wrench_frame)
        if hint is not None:
            print(f"warning: {hint}", file=sys.stderr)
    return 0
