"""``ftacq robot``: look at a UR controller, and give it the calibration's payload. Never moves the arm.

    ftacq robot info HOST [--model UR5e] [--json]
    ftacq robot set-payload (--config CELL.toml | --sim) --calibration CAL.json [--gravity-from-tilt] [--yes]

Prints model, software version, serial number, joint angles, flange pose (from the joint angles, TCP offset
excluded), the pose the controller reports for its TCP, and the robot, safety and program modes. Uses only the
UR Dashboard Server and an RTDE receive connection: it never uploads a program or moves the arm.

``set-payload`` sends the payload (mass, centre of gravity in the tool-flange frame, inertia) computed from a
calibration (:mod:`ftacq.exports`), and optionally the gravity direction from the identified base tilt, after
confirmation; it reads the payload back over RTDE and prints both (:mod:`drivers.ur_payload`).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from ftacq.app.helptext import examples


READBACK_TOLERANCE = 1e-6
"""The payload read back may differ from the one sent by this much (kg, m): RTDE carries float64."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``robot`` sub-command with its ``info`` and ``set-payload`` actions."""
    parser = subparsers.add_parser("robot", help="inspect a UR controller, or set its payload (never moves it)",
                                   description="Read a UR controller's identity and state over the UR "
                                               "Dashboard Server and RTDE (receive only).",
                                   **examples("ftacq robot info 192.168.1.10"))
    actions = parser.add_subparsers(dest="robot_action", metavar="ACTION", required=True)
    info = actions.add_parser("info", help="model, software, serial number, joints, flange pose, modes",
                              description="Print the controller's model, software version, serial number, joint "
                                          "angles, flange pose and modes. Never moves the arm.",
                              **examples("ftacq robot info 192.168.1.10", "ftacq robot info ur5e.local --json",
                                         "ftacq robot info --sim"))
    info.add_argument("host", nargs="?", help="controller IP address or host name, e.g. 192.168.1.10")
    info.add_argument("--sim", action="store_true", help="look at the simulated cell's UR controller instead")
    info.add_argument("--model", default=None, help="UR model (e.g. UR5e) when the UR Dashboard Server cannot tell")
    info.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    info.set_defaults(func=run_info)
    _register_set_payload(actions)


def collect_info(host: str, model: str | None = None) -> dict:
    """Read everything ``robot info`` prints; raises ftacq.errors.DeviceError types."""
    from drivers.ur import (
        ROBOT_MODE_NAMES,
        RUNTIME_STATE_NAMES,
        SAFETY_MODE_NAMES,
        URControllerInfo,
        URStateReader,
        probe_rtde,
        read_controller_info,
    )
    from ftacq.errors import DeviceError

    probe = probe_rtde(host)  # first: a controller that accepts and never answers fails here within the deadline
    try:
        info = read_controller_info(host)
    except DeviceError:  # no UR Dashboard Server (PolyScope X): RTDE only
        info = URControllerInfo.unknown(probe.version_text)
    reader = URStateReader(host, model=model or info.model)
    reader.start()
    try:
        reader.ensure_connected()
        q = reader.joint_positions()
        status = reader.status()
        flange = reader.flange_pose() if reader.model is not None else None
        tcp = reader.tcp_pose()
        runtime = reader.runtime_state()
        controller_time = reader.controller_time_s()
    finally:
        reader.close()
    return {
        "host": host,
        "model": reader.model.name if reader.model is not None else None,
        "dashboard_server_model": info.model_reply,
        "software_version": info.software_version,
        "serial_number": info.serial_number,
        "joint_positions_rad": q.tolist(),
        "joint_positions_deg": np.degrees(q).tolist(),
        "flange_pose": flange.tolist() if flange is not None else None,
        "tcp_pose_reported": tcp.tolist(),
        "robot_mode": ROBOT_MODE_NAMES.get(status.robot_mode, str(status.robot_mode)),
        "safety_mode": SAFETY_MODE_NAMES.get(status.safety_mode, str(status.safety_mode)),
        "protective_stop": status.protective_stop,
        "emergency_stop": status.emergency_stop,
        "program_state": info.program_state,
        "runtime_state": RUNTIME_STATE_NAMES.get(runtime, str(runtime)),
        "remote_control": info.remote_control,
        "controller_time_s": controller_time,
    }


def _fmt(values, digits: int = 4) -> str:
    return "[" + ", ".join(f"{round(float(v), digits) + 0.0:.{digits}f}" for v in values) + "]" if values is not None else "n/a"


def run_info(args: argparse.Namespace) -> int:
    """Print the controller's identity and state (``--sim``: the simulated cell's controller)."""
    import contextlib

    from drivers.ur_connection import controller_host
    from ftacq.errors import InputError

    if args.sim and args.host:
        raise InputError(f"give a controller host or --sim, not both (got {args.host!r} and --sim)")
    if not args.sim and not args.host:
        raise InputError("give the controller's IP address or host name (e.g. 192.168.1.10), or --sim")
    with contextlib.ExitStack() as stack:
        if args.sim:
            from ftacq.app.simcell import simulated_cell

            args.host = stack.enter_context(simulated_cell(sensor="netft")).robot_host
        args.host = controller_host(args.host)  # an IP address or host name (a ':30004' dropped), before any socket
        data = collect_info(args.host, args.model)
    if args.json:
        print(json.dumps(data, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    table = Table(title=f"UR controller {args.host}", show_header=False)
    table.add_column("item", style="bold")
    table.add_column("value")
    rows = [
        ("model", f"{data['model'] or 'unknown'} (Dashboard Server: {data['dashboard_server_model']})"),
        ("software version", data["software_version"] or "n/a"),
        ("serial number", data["serial_number"] or "n/a"),
        ("joint angles (deg)", _fmt(data["joint_positions_deg"], 3)),
        ("joint angles (rad)", _fmt(data["joint_positions_rad"], 5)),
        ("flange pose [m, rotvec rad]", _fmt(data["flange_pose"], 5)),
        ("TCP pose reported [m, rad]", _fmt(data["tcp_pose_reported"], 5)),
        ("robot mode", data["robot_mode"]),
        ("safety mode", data["safety_mode"]),
        ("program", f"{data['program_state'] or 'n/a'} (runtime {data['runtime_state']})"),
        ("remote control", {True: "yes", False: "no", None: "n/a"}[data["remote_control"]]),
    ]
    for name, value in rows:
        table.add_row(Text(name), Text(str(value)))  # Text: "[m, rad]" is not markup
    Console(width=120).print(table)
    return 0


def _register_set_payload(actions) -> None:
    from pathlib import Path

    parser = actions.add_parser(
        "set-payload", help="send the calibration's payload (and gravity direction) to the controller",
        description="Compute the payload the UR controller takes from a calibration (mass, centre of gravity in "
                    "the tool-flange frame, inertia when the calibration has one: docs/exports.md), print it, and "
                    "after confirmation send it (setTargetPayload; setPayload before PolyScope 5.10), optionally "
                    "with the gravity direction from the identified base tilt (setGravity). Reads the payload "
                    "back over RTDE and prints both. Moves nothing.",
        **examples("ftacq robot set-payload --config CELL.toml --calibration runs/20260101-120000/calibration.json",
                   "ftacq robot set-payload --config CELL.toml --calibration cal.json --gravity-from-tilt --yes",
                   "ftacq robot set-payload --sim --calibration cal.json --sensor-offset-m 0 0 0.012 --yes"))
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--config", type=Path, metavar="CELL.toml", help="cell configuration (robot.host)")
    source.add_argument("--sim", action="store_true", help="send to the simulated controller and show what it "
                                                           "recorded")
    parser.add_argument("--calibration", type=Path, required=True, metavar="CAL.json",
                        help="calibration from calibrate or identify")
    parser.add_argument("--gravity-from-tilt", action="store_true",
                        help="also set the gravity direction from the identified base tilt (setGravity)")
    parser.add_argument("--sensor-offset-m", type=float, nargs=3, metavar=("X", "Y", "Z"),
                        help="sensor origin in the flange frame, m, when neither the calibration nor CELL.toml has it")
    parser.add_argument("--yes", "-y", action="store_true", help="send without asking")
    parser.add_argument("--force", action="store_true", help="send a calibration whose verdict is FAIL")
    parser.set_defaults(func=run_set_payload)


def run_set_payload(args: argparse.Namespace) -> int:
    """Send the payload (and gravity), read back, print both; return the exit status."""
    import contextlib

    from drivers.robot import MotionLimits
    from drivers.ur import URRobot
    from drivers.ur_payload import gravity_from_weight, read_payload, takes_target_payload
    from ftacq.app.confirm import confirm
    from ftacq.calfile import load_calibration
    from ftacq.errors import InputError
    from ftacq.exports import sensor_offset_m, ur_payload, with_sensor_offset

    calibration = load_calibration(args.calibration)
    config = None
    if args.config is not None:
        from ftacq.app.config import load_config

        config = load_config(args.config)
    if args.sensor_offset_m is not None:
        calibration = with_sensor_offset(calibration, args.sensor_offset_m)
    elif sensor_offset_m(calibration) is None and config is not None \
            and getattr(config.tool, "sensor_offset_m", None) is not None:
        calibration = with_sensor_offset(calibration, config.tool.sensor_offset_m)
    verdict = (calibration.metadata.get("verdict") or {}).get("status")
    if verdict == "FAIL" and not args.force:
        raise InputError(f"{args.calibration}: the calibration's verdict is FAIL: not sending it to the controller "
                         "(--force sends it anyway)")
    payload = ur_payload(calibration)
    gravity = gravity_from_weight(calibration.gravity_base, calibration.mass_kg) if args.gravity_from_tilt else None
    print(f"payload from {args.calibration} (verdict {verdict or 'not recorded'}):")
    print(f"  mass            {payload.mass_kg:.4f} kg")
    print(f"  centre of grav. {_fmt(payload.cog_flange_m, 5)} m (tool-flange frame)")
    print("  inertia         " + ("none in the calibration (the controller uses zeros)"
                                  if payload.inertia_flange_kg_m2 is None
                                  else _fmt(payload.inertia_flange_kg_m2, 6) + " kg·m² [Ixx Iyy Izz Ixy Ixz Iyz] "
                                  "about the centre of gravity, flange axes"))
    if gravity is not None:
        print(f"  gravity         {_fmt(gravity, 4)} m/s² (base frame, away from the earth; from the base tilt)")
    print(f"  URScript: {payload.urscript()}")
    # --config and --sim are mutually exclusive and one is required: no config means the simulated controller
    where = "the simulated controller" if config is None else f"the controller at {config.robot.host}"
    confirm(args, f"Send this payload{' and gravity' if gravity is not None else ''} to {where}?",
            no_terminal="refusing to change the controller's payload: no terminal to confirm on (stdin is not a "
                        "tty); check the values above and pass --yes",
            declined="not confirmed: nothing was sent")
    with contextlib.ExitStack() as stack:
        cell = None
        if config is None:
            from ftacq.app.simcell import simulated_cell

            cell = stack.enter_context(simulated_cell(sensor="netft", time_scale=0.0))
            host, model = cell.robot_host, None
        else:
            host, model = config.robot.host, config.robot.model
        robot = stack.enter_context(URRobot(host, MotionLimits(), model=model))
        method = robot.set_payload(payload.mass_kg, payload.cog_flange_m, payload.inertia_flange_kg_m2)
        if gravity is not None:
            robot.set_gravity(gravity)
        back = read_payload(host)
        recorded = [] if cell is None else [
            e for e in cell.controller.events() if e.get("event") in ("set_payload", "set_target_payload", "set_gravity")]
    version = robot.info.software_version if robot.info else None
    print(f"sent with {method} (controller software {version or 'unknown'}"
          + ("" if takes_target_payload(version) else "; no setTargetPayload before 5.10: inertia not sent") + ")")
    sent_inertia = payload.inertia_flange_kg_m2 if payload.inertia_flange_kg_m2 is not None else np.zeros(6)
    rows = [("mass kg", f"{payload.mass_kg:.4f}", f"{back.mass_kg:.4f}"),
            ("CoG m", _fmt(payload.cog_flange_m, 5), _fmt(back.cog_m, 5)),
            ("inertia kg·m²", _fmt(sent_inertia, 6),
             "not reported before 5.11" if back.inertia_kg_m2 is None else _fmt(back.inertia_kg_m2, 6))]
    if gravity is not None:
        rows.append(("gravity m/s²", _fmt(gravity, 4), "not reported over RTDE: check Installation → Mounting"))
    for name, sent, read in rows:
        print(f"  {name:<14} sent       {sent}")
        print(f"  {'':<14} read back  {read}")
    if cell is not None:
        print("the simulated controller recorded:")
        for event in recorded:
            print("  " + json.dumps(event))
    if abs(back.mass_kg - payload.mass_kg) > READBACK_TOLERANCE or \
            np.max(np.abs(back.cog_m - payload.cog_flange_m)) > READBACK_TOLERANCE:
        from ftacq.errors import RobotError

        raise RobotError(f"robot controller {host}: the payload read back differs from the one sent (see above)")
    return 0


def start_robot(host: str, settings, stack):
    """Connect to the UR controller at ``host`` with the plan's speed and acceleration bounds (``settings``: a
    :class:`procedures.plan_settings.PlanSettings`), close it with ``stack`` (an ExitStack) and start it: the one
    way calibrate, calibrate --quick and tare open the arm they move."""
    from drivers.robot import MotionLimits
    from drivers.ur import URRobot

    limits = MotionLimits(joint_speed_rad_s=settings.joint_speed_rad_s,
                          joint_acceleration_rad_s2=settings.joint_acceleration_rad_s2)
    robot = URRobot(host, limits, model=settings.model)
    stack.callback(robot.close)
    robot.start()
    return robot
