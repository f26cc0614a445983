"""``ftacq identify POSES.csv -o CALIBRATION.json``: identify a calibration from a pose record."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ftacq.app.helptext import examples
from ftacq.fit_options import DRIFT_MODELS, METHODS
from ftacq.imports.options import WRENCH_FRAMES, ImportOptions
from ftacq.mounts import MOUNT_FORMS


def add_unit_options(parser: argparse.ArgumentParser, what: str) -> argparse._ArgumentGroup:
    """Add ``--force-unit`` and ``--torque-unit`` (the units of ``what``'s wrench columns); return their group."""
    from ftacq.units import FORCE_UNITS, TORQUE_UNITS

    units = parser.add_argument_group(f"units of {what} (docs/formats.md; default N and N·m)")
    units.add_argument("--force-unit", metavar="UNIT",
                       help=f"unit of the force columns when the file does not say: {', '.join(FORCE_UNITS)}")
    units.add_argument("--torque-unit", metavar="UNIT",
                       help=f"unit of the torque columns when the file does not say: {', '.join(TORQUE_UNITS)} "
                            "(an ATI box set to N-mm records N-mm)")
    return units


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
        **examples("ftacq identify runs/20260101-120000/poses.csv -o calibration.json",
                   "ftacq identify poses.csv -o calibration.json --mount tilted:62,-37  # a base tilted 62°",
                   "ftacq identify poses.csv -o calibration.json --gravity-direction 1,0,0  # wall, gravity along +x"),
    )
    parser.add_argument("poses", metavar="POSES.csv", nargs="?",
                        help="pose record CSV (see docs/formats.md); optional with --motion and --calibration")
    parser.add_argument("-o", "--output", metavar="CALIBRATION.json", required=True, help="calibration file to write")
    mounting = parser.add_mutually_exclusive_group()
    mounting.add_argument(
        "--mount", metavar="MOUNT",
        help=f"the robot's mount, to also report the base tilt relative to it: {MOUNT_FORMS}; tilted:ALPHA,BETA "
             "is gravity = -[cos α sin β, -sin α, cos α cos β] in the base frame (degrees; floor 0,0, wall 0,90, "
             "ceiling 0,180)",
    )
    mounting.add_argument(
        "--gravity-direction", metavar="X,Y,Z",
        help="the mount as the direction of gravity in the robot base frame (any length), e.g. 0.539,0.699,-0.470",
    )
    units = add_unit_options(parser, "the pose record")
    units.add_argument("--wrench-frame", choices=WRENCH_FRAMES, default=ImportOptions.wrench_frame,
                       help="frame of the wrench columns: the sensor's (default; the pose record's) or the robot "
                            "base frame (rotated into the flange frame before the fit); the verdict names a wrong one")
    parser.add_argument(
        "--method",
        choices=METHODS,
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
        "--drift",
        choices=DRIFT_MODELS,
        default="auto",
        help="model a linear drift of the sensor's zero over the recording (time from t_start_s/t_end_s, else the "
        "row order): linear, none, or auto (when the residuals trend with time significantly and beyond CELL.toml "
        "sampling.drift_warn_*; default). The calibration keeps the biases of the end of the recording",
    )
    parser.add_argument("--tolerance-force", type=float, metavar="N",
                        help="model mismatch accepted with a WARN, RMS per axis, N (default: CELL.toml "
                             "sampling.mismatch_tolerance_force_n, 0.1)")
    parser.add_argument("--tolerance-torque", type=float, metavar="NM",
                        help="... and for the torques, N·m (default: sampling.mismatch_tolerance_torque_nm, 0.005)")
    parser.add_argument(
        "--use-validation",
        action="store_true",
        help="also fit the poses of sets V and D (by default they are held out and their compensation error is reported)",
    )
    parser.add_argument("--hold-out", type=float, metavar="FRACTION",
                        help="for a record without V poses (an imported recording): hold out this fraction of the "
                             "poses, spread evenly over the record, as set V, to judge the calibration on poses it "
                             "was not fitted to (e.g. 0.2; docs/formats.md, column set)")
    from ftacq.app.commands.calibrate import add_sensor_check_args

    add_sensor_check_args(parser)
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
    import numpy as np

    from ftacq.errors import InputError as _InputError

    if args.poses is None and not (args.motion and args.calibration):
        raise _InputError("give POSES.csv, or --motion MOTION.csv with --calibration CALIBRATION.json")
    if args.poses is not None and args.calibration:
        raise _InputError("give POSES.csv or --calibration, not both (the poses identify the static calibration)")
    if args.poses is None:
        from ftacq.calfile import load_calibration, save_calibration
        from ftacq.validation import check_output_file

        check_output_file(args.output, "-o/--output")
        calibration, report = _dynamic(args, load_calibration(args.calibration))
        save_calibration(args.output, calibration)
        sys.stdout.write(report)
        print(f"wrote {args.output}")
        return 0

    from ftacq.calfile import save_calibration
    from ftacq.errors import IdentificationError, InputError
    from ftacq.identification import identify
    from ftacq.identification.diagnostics import MIN_POSES
    from ftacq.posefile import read_pose_csv
    from ftacq.posesets import is_identified_on
    from ftacq.provenance import input_record, with_provenance
    from ftacq.report import SUMMARY_ROWS, format_identification_report, validation_errors
    from ftacq.verdict import FAIL, format_verdict

    from ftacq.identification.diagnostics import MAX_SPECIAL_TOLERANCE_DEG
    from ftacq.validation import check_number, check_output_file

    # options and the output path first: nothing is computed for a run that cannot be kept
    check_number(args.special_tolerance_deg, "--special-tolerance-deg", low=0.0, high=MAX_SPECIAL_TOLERANCE_DEG,
                 low_exclusive=True, high_exclusive=True)
    from ftacq.settings import SamplingConfig

    tolerance = (
        SamplingConfig.mismatch_tolerance_force_n if args.tolerance_force is None
        else check_number(args.tolerance_force, "--tolerance-force", low=0.0, high=1000.0),
        SamplingConfig.mismatch_tolerance_torque_nm if args.tolerance_torque is None
        else check_number(args.tolerance_torque, "--tolerance-torque", low=0.0, high=100.0),
    )
    if args.drift == "linear" and args.no_refine:
        raise InputError("--drift linear is fitted by the refinement: drop --no-refine")
    if args.hold_out is not None:
        check_number(args.hold_out, "--hold-out", low=0.0, high=0.5, low_exclusive=True)
    check_output_file(args.output, "-o/--output")
    mount = mount_option(args.mount, args.gravity_direction)
    path = Path(args.poses)
    record = read_pose_csv(path, force_unit=args.force_unit, torque_unit=args.torque_unit)
    if args.wrench_frame == "base":
        from ftacq.imports.wrench_frame import sensor_from_base

        record = sensor_from_base(record)
    from ftacq.identification.trend import ROW_INDEX_COLUMN

    if ROW_INDEX_COLUMN not in record.extra:  # the row order survives the split: a drift's time axis without times
        from dataclasses import replace

        record = replace(record, extra={**record.extra, ROW_INDEX_COLUMN: np.arange(len(record), dtype=float)})
    held_out = np.array([not is_identified_on(name) for name in record.sets])  # V and D (ftacq.posesets)
    if args.hold_out is not None:
        from dataclasses import replace

        from ftacq.posesets import VALIDATION_SET, spread_hold_out

        if held_out.any():
            raise InputError(f"{path}: --hold-out {args.hold_out:g}: the record already holds out "
                             f"{int(held_out.sum())} poses (sets V, D): drop --hold-out, or clear their set column")
        held_out = spread_hold_out(len(record), args.hold_out)
        record = replace(record, sets=tuple(VALIDATION_SET if h else name for h, name in zip(held_out, record.sets)))
    validation = None
    fit_record = record
    if held_out.any() and (~held_out).sum() >= MIN_POSES and not args.use_validation:
        fit_record = record.select(~held_out)
    check = _sensor_check(args)
    try:
        result = identify(
            fit_record,
            mount=mount,
            method=args.method,
            refine=not args.no_refine,
            special_tolerance_deg=args.special_tolerance_deg,
            drift="none" if args.no_refine and args.drift == "auto" else args.drift,
            **check,
        )
    except IdentificationError as error:
        from ftacq.imports.wrench_frame import frame_mismatch

        hint = frame_mismatch(fit_record, args.wrench_frame)[0] if len(fit_record) >= MIN_POSES else None
        raise InputError(f"{path}: cannot identify a calibration: {error}" + (f"; {hint}" if hint else "")) \
            from error
    held_out_record = record.select(held_out) if fit_record is not record else None
    if held_out_record is not None:
        validation = validation_errors(result.calibration, held_out_record)
    verdict = _verdict(result, held_out_record, record, tolerance, fit_record, args.wrench_frame)
    calibration = with_provenance(  # a pose file does not say which sensor measured it
        result.calibration, None, None, validation=validation, verdict=verdict.to_dict(),
        input=input_record(path, record.sets, sorted(set(fit_record.sets)), has_std=record.std is not None,
                           has_count=record.count is not None, units=record.units))
    report = format_identification_report(result, validation=validation)
    summary = format_identification_report(result, validation=validation, limit=SUMMARY_ROWS)
    if args.motion:
        calibration, motion_report = _dynamic(args, calibration)
        report += motion_report
        summary += motion_report
    save_calibration(args.output, calibration)  # first: the file must not depend on anyone reading the report
    if summary != report:  # a long record: the console gets the worst poses, the file every one
        from ftacq.fileio import atomic_write

        full = Path(args.output).with_suffix(".report.txt")
        with atomic_write(full) as handle:
            handle.write(report)
        summary += f"(the console shows the worst {SUMMARY_ROWS} poses per list; every pose: {full})\n"
    sys.stdout.write(summary)
    converted = {kind: unit for kind, unit in record.units.items() if unit not in ("N", "N-m")}
    if converted:
        print("units read: " + ", ".join(f"{kind} in {unit}" for kind, unit in converted.items())
              + " (converted to N and N·m)")
    print(f"wrote {args.output}")
    print("")
    print(format_verdict(verdict))
    return 1 if verdict.status == FAIL else 0


def _sensor_check(args: argparse.Namespace) -> dict:
    """The sensor check's keyword arguments of ``identify`` from the command line (defaults: CELL.toml's)."""
    from ftacq.app.commands.calibrate import sensor_check_options
    from ftacq.identification.sensor_gain import ReferenceWeight
    from ftacq.settings import SensorConfig

    given = sensor_check_options(args, None)
    reference = given.get("reference_mass_kg")
    return {"sensor_check": given.get("sensor_check", SensorConfig.check),
            "reference": None if reference is None else ReferenceWeight(reference, given["reference_sigma_kg"]),
            "sensor_accuracy_percent": given.get("sensor_accuracy_percent", SensorConfig.accuracy_percent)}


def mount_option(mount: str | None, gravity_direction: str | None) -> str | None:
    """The mount spec of ``--mount`` or ``--gravity-direction`` (InputError naming the option when malformed)."""
    from ftacq.errors import InputError
    from ftacq.mounts import check_mount, gravity_spec

    try:
        if gravity_direction is not None:
            return gravity_spec(gravity_direction)
        return None if mount is None else check_mount(mount)
    except ValueError as error:
        option = "--gravity-direction" if gravity_direction is not None else "--mount"
        raise InputError(f"{option}: {error}") from None


def _verdict(result, held_out_record, record, tolerance, fit_record=None, wrench_frame="sensor"):
    """Judge the identification: held-out poses (V, D), the drift seen by each D row against the pose it
    revisits (label ``<first>-revisit``), conditioning, outliers (ftacq.verdict) and the wrenches' frame
    (ftacq.imports.wrench_frame)."""
    import numpy as np

    from ftacq.app.config import SamplingConfig
    from ftacq.imports.wrench_frame import wrench_frame_finding
    from ftacq.posesets import DRIFT_SET
    from ftacq.verdict import drift_finding, identification_findings, judge
    from procedures.measured import DRIFT_SUFFIX

    findings = identification_findings(result, held_out_record, tolerance)
    findings.append(wrench_frame_finding(record if fit_record is None else fit_record, result, wrench_frame))
    labels = list(record.labels)
    for i, (label, set_name) in enumerate(zip(labels, record.sets)):
        first = label[: -len(DRIFT_SUFFIX)] if label.endswith(DRIFT_SUFFIX) else None
        if set_name.strip().upper() != DRIFT_SET or first not in labels:
            continue
        j = labels.index(first)
        t_end = record.extra.get("t_end_s")
        elapsed = float(t_end[i] - t_end[j]) if t_end is not None else float("nan")
        drift = np.asarray(record.wrench[i]) - np.asarray(record.wrench[j])
        findings.insert(1, drift_finding(drift, elapsed, SamplingConfig.drift_warn_force_n,
                                         SamplingConfig.drift_warn_torque_nm, first))
    return judge(findings)


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
