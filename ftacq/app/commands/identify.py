"""``ftacq identify POSES.csv -o CALIBRATION.json``: identify a calibration from a pose record."""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

HELD_OUT_SETS = ("V", "D")
"""Poses of these sets (column ``set``: V validation, D the procedure's drift-check revisit) are held out of the
fit, as the calibration procedure does, and used to report the compensation error."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``identify`` sub-command."""
    parser = subparsers.add_parser(
        "identify",
        help="identify sensor rotation, biases, tool mass / centre of mass and base tilt from a pose record",
        description=(
            "Read a pose record CSV (flange poses + mean sensor wrenches), identify the calibration "
            "(Yu, Shi & Lou 2021 closed form, then a robust joint refinement), print a report and write the "
            "calibration JSON. Poses of sets V (validation) and D (drift-check revisit) are held out and their "
            "compensation error is reported. "
            "Nothing is written if the input is bad."
        ),
    )
    parser.add_argument("poses", metavar="POSES.csv", nargs="?",
                        help="pose record CSV (see docs/formats.md); optional with --motion and --calibration")
    parser.add_argument("-o", "--output", metavar="CALIBRATION.json", required=True, help="calibration file to write")
    parser.add_argument(
        "--mount",
        choices=("floor", "wall", "ceiling"),
        help="nominal robot mount: also report the base tilt relative to it",
    )
    parser.add_argument(
        "--method",
        choices=("auto", "srom", "lrom"),
        default="auto",
        help="first estimate of the weight in the base frame: SROM (needs the 24 special orientations), "
        "LROM (any orientations) or auto (SROM when all 24 are present; default)",
    )
    parser.add_argument("--no-refine", action="store_true", help="stop at the paper's closed form (no joint refinement)")
    parser.add_argument(
        "--special-tolerance-deg",
        type=float,
        default=3.0,
        metavar="DEG",
        help="a pose within this angle (degrees) of a cube rotation counts as special (default 3)",
    )
    parser.add_argument(
        "--use-validation",
        action="store_true",
        help="also fit the poses of sets V and D (by default they are held out and their compensation error is reported)",
    )
    dynamics = parser.add_argument_group("motion (docs/dynamics.md)")
    dynamics.add_argument("--motion", metavar="MOTION.csv",
                          help="a recorded motion (ftacq calibrate --dynamic writes RUN_DIR/motion.csv): also "
                               "identify the tool's inertia, so the calibration compensates while the arm moves")
    dynamics.add_argument("--calibration", metavar="CALIBRATION.json",
                          help="with --motion and no POSES.csv: the static calibration to extend")
    dynamics.add_argument("--model", help="UR model of the motion (default: the one named in MOTION.csv)")
    dynamics.add_argument("--sensor-offset", type=float, nargs=3, metavar=("X", "Y", "Z"),
                          help="sensor origin in the flange frame, m (default: the calibration's, else CELL.toml "
                               "tool.sensor_offset_m as recorded there, else 0)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Identify, print the report, write the calibration; return the exit status."""
    from ftacq.calfile import load_calibration, save_calibration
    from ftacq.errors import InputError

    if args.poses is None and not (args.motion and args.calibration):
        raise InputError("give POSES.csv, or --motion MOTION.csv with --calibration CALIBRATION.json")
    if args.poses is not None and args.calibration:
        raise InputError("give POSES.csv or --calibration, not both (the poses identify the static calibration)")
    if args.poses is not None:
        calibration, report = _static(args)
    else:
        calibration, report = load_calibration(args.calibration), ""
    if args.motion:
        calibration, motion_report = _dynamic(args, calibration)
        report += motion_report
    save_calibration(args.output, calibration)  # first: the file must not depend on anyone reading the report
    sys.stdout.write(report)
    print(f"wrote {args.output}")
    return 0


def _dynamic(args: argparse.Namespace, calibration):
    """Identify the inertia from ``args.motion``; return (calibration with inertia, report text)."""
    import numpy as np

    from ftacq.dynamics import identify_dynamics
    from ftacq.dynamics.motionfile import read_motion_csv
    from ftacq.dynamics.report import format_dynamics
    from ftacq.errors import IdentificationError, InputError
    from ftacq.kinematics import ur_model

    record, file_model = read_motion_csv(args.motion)
    model_name = args.model or file_model
    if not model_name:
        raise InputError(f"{args.motion}: the file does not name the robot model; give --model (e.g. UR5e)")
    try:
        model = ur_model(model_name)
    except ValueError as error:
        raise InputError(f"--model {model_name}: {error}") from None
    offset = args.sensor_offset if args.sensor_offset is not None else calibration.sensor_offset
    try:
        result = identify_dynamics(calibration, record, model,
                                   sensor_offset_m=None if offset is None else np.array(offset, dtype=float))
    except (IdentificationError, np.linalg.LinAlgError) as error:
        raise InputError(f"{args.motion}: cannot identify the inertia: {error}") from error
    return result.calibration, "\n" + format_dynamics(result)


def _static(args: argparse.Namespace):
    """Identify the static calibration from ``args.poses``; return (calibration, report text)."""
    import numpy as np

    from ftacq.calibration import Calibration
    from ftacq.errors import IdentificationError, InputError
    from ftacq.identification import identify
    from ftacq.posefile import read_pose_csv
    from ftacq.identification.diagnostics import MIN_POSES
    from ftacq.report import format_identification_report, validation_errors

    from ftacq.identification.diagnostics import MAX_SPECIAL_TOLERANCE_DEG
    from ftacq.validation import check_number, check_output_file

    # options and the output path first: nothing is computed for a run that cannot be kept
    check_number(args.special_tolerance_deg, "--special-tolerance-deg", low=0.0, high=MAX_SPECIAL_TOLERANCE_DEG,
                 low_exclusive=True, high_exclusive=True)
    check_output_file(args.output, "-o/--output")
    path = Path(args.poses)
    record = read_pose_csv(path)
    held_out = np.array([name.strip().upper() in HELD_OUT_SETS for name in record.sets])
    validation = None
    fit_record = record
    if held_out.any() and (~held_out).sum() >= MIN_POSES and not args.use_validation:
        fit_record = record.select(~held_out)
    try:
        result = identify(
            fit_record,
            mount=args.mount,
            method=args.method,
            refine=not args.no_refine,
            special_tolerance_deg=args.special_tolerance_deg,
        )
    except IdentificationError as error:
        raise InputError(f"{path}: cannot identify a calibration: {error}") from error
    if fit_record is not record:
        validation = validation_errors(result.calibration, record.select(held_out))
    metadata = dict(result.calibration.metadata)
    if validation is not None:
        metadata["validation"] = validation
    metadata["input"] = {
        "file": str(path),
        "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "poses": len(record),
        "sets": {name: record.sets.count(name) for name in sorted(set(record.sets))},
        "has_std": record.std is not None,
        "has_count": record.count is not None,
    }
    calibration = Calibration(
        sensor_rotation=result.calibration.sensor_rotation,
        force_bias=result.calibration.force_bias,
        torque_bias=result.calibration.torque_bias,
        gravity_base=result.calibration.gravity_base,
        center_of_mass=result.calibration.center_of_mass,
        uncertainty=result.calibration.uncertainty,
        metadata=metadata,
    )
    from ftacq.provenance import with_provenance

    calibration = with_provenance(calibration, None, None)  # a pose file does not say which sensor measured it
    return calibration, format_identification_report(result, validation=validation)
