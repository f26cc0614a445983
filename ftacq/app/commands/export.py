"""``ftacq export CAL.json --format ur|ros2|json [-o FILE]``: the calibration in a form the next system takes.

    ur    JSON with the URScript line set_target_payload(m, [cx, cy, cz], [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]) and the
          payload's mass, centre of gravity (tool-flange frame) and inertia (about the centre of gravity, flange
          axes), from the calibration's sensor_offset_m (or --sensor-offset-m) and sensor rotation;
    ros2  a parameters YAML for force_torque_sensor_broadcaster with control_toolbox's gravity-compensation filter;
    json  the calibration file itself (ftacq's format, rewritten).

Without ``-o`` the text goes to standard output. Formats and frames: docs/exports.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ftacq.app.helptext import examples

def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``export`` sub-command."""
    parser = subparsers.add_parser(
        "export", help="write a calibration for the UR controller (payload) or ROS 2 (parameters YAML)",
        description="Turn a calibration into what the next system takes: 'ur' gives the UR payload (mass, centre "
                    "of gravity in the tool-flange frame, inertia when the calibration has one) as a URScript "
                    "set_target_payload line and as JSON; 'ros2' gives parameters for a force_torque_sensor_"
                    "broadcaster with control_toolbox's gravity-compensation filter; 'json' rewrites ftacq's own "
                    "format. Frames and the versions followed: docs/exports.md.",
        **examples("ftacq export runs/20260101-120000/calibration.json --format ur",
                   "ftacq export calibration.json --format ros2 -o ft_params.yaml",
                   "ftacq export calibration.json --format ur --sensor-offset-m 0 0 0.012 -o payload.json"))
    parser.add_argument("calibration", type=Path, metavar="CAL.json", help="calibration from calibrate or identify")
    parser.add_argument("--format", "-f", required=True, metavar="FORMAT",
                        help="ur (the UR payload), ros2 (ROS 2 parameters YAML) or json (a calibration file); "
                             "docs/exports.md")
    parser.add_argument("-o", "--output", type=Path, metavar="FILE", help="write here (atomically, mode 0644) "
                        "instead of standard output")
    parser.add_argument("--sensor-offset-m", type=float, nargs=3, metavar=("X", "Y", "Z"),
                        help="sensor origin in the flange frame, m (from the adapter drawing), when the calibration "
                             "does not have it (CELL.toml tool.sensor_offset_m)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the export; return the exit status."""
    from ftacq.calfile import WRITERS, load_calibration, write_calibration
    from ftacq.errors import InputError
    from ftacq.exports import with_sensor_offset

    if args.format not in WRITERS:
        raise InputError(f"--format {args.format!r}: unknown (known: {', '.join(WRITERS)})")
    calibration = load_calibration(args.calibration)
    if args.sensor_offset_m is not None:
        calibration = with_sensor_offset(calibration, args.sensor_offset_m)
    if args.output is None:
        sys.stdout.write(WRITERS[args.format](calibration))
        return 0
    write_calibration(args.output, calibration, args.format)
    print(f"wrote {args.output} ({args.format})", file=sys.stderr)
    return 0
