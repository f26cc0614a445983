"""``ftacq tare``: re-estimate the force and torque biases with the tool on, keeping the rest of the calibration.

    ftacq tare --config CELL.toml --calibration CAL.json -o NEW.json              # at the current pose, moves nothing
    ftacq tare --config CELL.toml --calibration CAL.json -o NEW.json --poses 6    # 6 planned, checked poses (moves)
    ftacq tare --sim [-o NEW.json] [--poses N]                                    # simulated cell, biases shifted

Unlike the box's own bias (``ftacq sensor bias``, RDT command 0x0042), which zeroes the reading under whatever
load hangs on the sensor — the tool's weight included — and so invalidates every calibration made before it, a
tare keeps the sensor rotation, the tool's weight and centre of mass and only re-estimates the biases, so the
calibration stays valid for every orientation. The new file records the change in ``bias_history``.
With ``--poses N`` the robot moves through N poses planned and checked like a calibration's, after the same
confirmation (``--yes`` confirms in advance, ``--dry-run`` prints the plan only). Exit status as calibrate.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

import numpy as np

from ftacq.channels import LABELS
from ftacq.errors import InputError

SIM_BIAS_SHIFT = (0.35, -0.25, 0.6, 0.012, -0.008, 0.005)
"""With --sim, the simulated sensor's biases differ from the calibration's by this much (N, N·m): what the tare
should find."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``tare`` sub-command."""
    parser = subparsers.add_parser(
        "tare", help="re-estimate the biases with the tool on (keeps rotation, mass and centre of mass)",
        description="Re-estimate the force and torque biases of a calibration with the tool on: at the current "
                    "pose (nothing moves) or at N planned and checked poses (--poses N; moves after confirmation). "
                    "Keeps the sensor rotation, the tool's mass and centre of mass; prints the new biases with "
                    "1σ and the change; writes a new calibration file atomically. Unlike `ftacq sensor bias` (the "
                    "box's own zero), the calibration stays valid.",
        epilog="examples:\n  ftacq tare --config CELL.toml --calibration cal.json -o cal-tared.json\n"
               "  ftacq tare --config CELL.toml --calibration cal.json -o cal-tared.json --poses 6\n"
               "  ftacq tare --sim --poses 4 --yes",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", type=Path, metavar="CELL.toml", help="cell configuration (robot, sensor, tool)")
    parser.add_argument("--sim", action="store_true",
                        help="run against the simulated cell, whose sensor biases are shifted from the calibration's "
                             f"by {list(SIM_BIAS_SHIFT)} (N, N·m); prints the true biases beside the estimate")
    parser.add_argument("--calibration", type=Path, metavar="CAL.json",
                        help="the calibration to tare (required with --config; --sim defaults to the simulated "
                             "cell's ground truth before the shift)")
    parser.add_argument("-o", "--output", type=Path, metavar="NEW.json", help="the new calibration file to write")
    parser.add_argument("--poses", type=int, default=0, metavar="N",
                        help="tare at N planned poses (moves the robot; default 0 = at the current pose, no motion)")
    parser.add_argument("--yes", "-y", action="store_true", help="confirm the plan (--poses) without asking")
    parser.add_argument("--dry-run", action="store_true", help="with --poses: print the checked plan, move nothing")
    parser.add_argument("--force", action="store_true",
                        help="tare even when the sensor connected is not the one the calibration was made with")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``ftacq tare``; return the exit status (SIGTERM stops it as Ctrl-C does: :mod:`ftacq.app.signals`)."""
    from dataclasses import replace

    from ftacq.app.commands.robot import start_robot
    from drivers.sensor import open_sensor
    from ftacq.app.commands.calibrate import sim_sampling
    from ftacq.app.confirm import confirm_motion
    from ftacq.app.config import CellConfig, load_config
    from ftacq.bias_estimate import apply_estimate
    from ftacq.calfile import load_calibration, save_calibration
    from ftacq.provenance import require_same_sensor, sensor_record, tool_record
    from procedures.calibration_procedure import ProcedureOptions
    from procedures.settle import SettleSettings
    from procedures.tare import TareProcedure, tare_here, tare_plan_settings

    if not (args.config or args.sim):
        raise InputError("give --config CELL.toml (and --calibration CAL.json), or --sim")
    if args.poses < 0:
        raise InputError(f"--poses {args.poses}: must be ≥ 0 (0 = at the current pose)")
    if args.poses and not args.dry_run:
        from ftacq.app.signals import warn_if_sigint_ignored

        warn_if_sigint_ignored("ftacq tare")
    if not args.sim and args.calibration is None:
        raise InputError("--calibration CAL.json is required (the calibration whose biases are re-estimated)")
    if args.output is None and not (args.sim or args.dry_run):
        raise InputError("-o NEW.json is required (the tared calibration is written there)")
    if args.output is not None and args.output.is_dir():
        raise InputError(f"-o {args.output}: is a folder; give a file name such as {args.output / 'calibration.json'}")
    calibration = load_calibration(args.calibration) if args.calibration is not None else None
    config = load_config(args.config) if args.config else CellConfig(source="--sim")
    time_scale = 0.0
    with contextlib.ExitStack() as stack:
        cell = None
        if args.sim:
            from ftacq.app.commands.calibrate import DEFAULT_SIM_TIME_SCALE
            from ftacq.app.simcell import simulated_cell, simulated_truth, true_calibration

            time_scale = DEFAULT_SIM_TIME_SCALE
            base = simulated_truth()
            if calibration is None:
                calibration = true_calibration(base)
            shifted = simulated_truth(
                force_bias_n=tuple(float(v) for v in calibration.force_bias + np.array(SIM_BIAS_SHIFT[:3])),
                torque_bias_nm=tuple(float(v) for v in calibration.torque_bias + np.array(SIM_BIAS_SHIFT[3:])))
            print(f"starting the simulated cell ({config.robot.model}, time scale {time_scale:g}); its sensor biases "
                  f"are the calibration's shifted by {list(SIM_BIAS_SHIFT)} N, N·m", file=sys.stderr, flush=True)
            cell = stack.enter_context(simulated_cell(truth=shifted, sensor="netft", model=config.robot.model,
                                                     mount=config.robot.mount, time_scale=time_scale))
            config = config.replace_section("robot", host=cell.robot_host)
            config = config.replace_section("sensor", url=cell.sensor_url)
        # checked above: --calibration is required without --sim, and --sim defaults to the simulated cell's
        assert calibration is not None
        sampling = sim_sampling(config.sampling, time_scale) if args.sim else config.sampling
        settings = config.plan_settings()
        robot = start_robot(config.robot.host, settings, stack)
        plan = None
        if args.poses:
            from procedures.calibration_procedure import Move, calibration_steps, check_steps
            from procedures.plan import format_plan, make_plan

            plan = make_plan(tare_plan_settings(settings, args.poses), robot.joint_positions())
            print(format_plan(plan), flush=True)
            problems = check_steps(calibration_steps(plan, (), False), plan.settings, robot.joint_positions())
            if problems:
                from ftacq.errors import PlanError

                raise PlanError("the tare plan's moves from the robot's current configuration are not clear:\n  "
                                + "\n  ".join(problems))
            moves = sum(isinstance(s, Move) for s in calibration_steps(plan, (), False))
            print(f"  path check: {moves} moves checked for collisions and joint limits: clear", flush=True)
            if len(plan) < args.poses:
                print(f"  note: {len(plan)} of the {args.poses} poses asked for are reachable; taring on those",
                      flush=True)
            if args.dry_run:
                print("dry run: the robot did not move", flush=True)
                return 0
            confirm_motion(args)
        elif args.dry_run:
            print("dry run: a tare at the current pose moves nothing; nothing measured", flush=True)
            return 0
        sensor = open_sensor(config.sensor.url)
        stack.callback(sensor.close)
        sensor.start()
        simulated_truth_used = args.sim and args.calibration is None  # the simulated sensor's own: nothing to check
        note = "" if simulated_truth_used else require_same_sensor(calibration, sensor.info, args.force, "ftacq tare")
        if note:
            print(note, file=sys.stderr, flush=True)
        sampled = config.replace_section("sampling", **_as_dict(sampling))
        if plan is None:
            print("taring at the current pose (the robot does not move): keep the arm still and the tool untouched",
                  flush=True)
            result = tare_here(robot, sensor, calibration, SettleSettings.from_config(sampled))
        else:
            options = ProcedureOptions.from_config(sampled)
            procedure = TareProcedure(plan, robot, sensor, calibration, options)
            outcome = procedure.run()
            if outcome.status != "done" or procedure.result is None:
                from ftacq.errors import AbortedError

                raise AbortedError(f"tare {outcome.status}: {outcome.message}; the robot was stopped; "
                                   "the calibration file was not written") from outcome.error
            result = procedure.result
        tared_on = sensor_record(sensor.info)
        previous = (calibration.metadata.get("sensor") or {}).get("serial") or ""
        sensor_keys = {"sensor": tared_on["serial"]} if tared_on["serial"] else {}
        if previous and tared_on["serial"] and previous != tared_on["serial"]:
            sensor_keys["previous_sensor"] = previous  # --force: the biases now belong to another sensor
        tared = apply_estimate(calibration, result.estimate, **sensor_keys)
        metadata = dict(tared.metadata)
        metadata["sensor"] = tared_on  # the biases were measured on this sensor: the file now belongs to it
        tool = tool_record(getattr(config.tool, "name", None))
        if tool is not None:
            metadata.setdefault("tool", tool)
        tared = replace(tared, metadata=metadata)
    print(format_estimate(result.estimate, int(result.count.sum())))
    if cell is not None:
        truth = np.concatenate([cell.truth.force_bias_n, cell.truth.torque_bias_nm])
        error = result.estimate.bias - truth
        print("simulated cell: true biases " + " ".join(f"{v:+.4f}" for v in truth) + "; error/1σ "
              + " ".join(f"{v:+.2f}" for v in error / np.maximum(result.estimate.sigma, 1e-300)))
    if args.output is not None:
        save_calibration(args.output, tared)
        print(f"tared calibration: {args.output}")
    return 0


def _as_dict(sampling) -> dict:
    from dataclasses import asdict

    return asdict(sampling)


def format_estimate(estimate, samples: int) -> str:
    """Return the table printed by ``ftacq tare``: old and new biases, 1σ and change per channel."""
    from ftacq.sigma_text import decimals_for, format_sigma

    lines = [f"{estimate.method} ({samples} samples averaged)"
             + (f", pose scatter χ²/dof {estimate.chi2_per_dof:.2f}" if np.isfinite(estimate.chi2_per_dof) else ""),
             f"  {'':9} {'old':>11} {'new':>11} {'1σ':>9} {'change':>11}"]
    for name, old, new, sigma, change in zip(LABELS, estimate.previous, estimate.bias, estimate.sigma,
                                             estimate.change):
        places = decimals_for(sigma)  # the values to the 1σ's last printed digit
        lines.append(f"  {name:9} {old:11.{places}f} {new:11.{places}f} {format_sigma(sigma):>9} "
                     f"{change:+11.{places}f}")
    return "\n".join(lines)
