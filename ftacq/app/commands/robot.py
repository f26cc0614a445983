"""``ftacq robot``: look at a UR controller without moving it.

    ftacq robot info HOST [--model UR5e] [--json]

Prints model, software version, serial number, joint angles, flange pose (from the joint angles, TCP offset
excluded), the pose the controller reports for its TCP, and the robot, safety and program modes. Uses only the
UR Dashboard Server and an RTDE receive connection: it never uploads a program or moves the arm.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from ftacq.app.helptext import examples


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``robot`` sub-command with its ``info`` action."""
    parser = subparsers.add_parser("robot", help="inspect a Universal Robots controller (never moves it)",
                                   description="Read a UR controller's identity and state over the UR "
                                               "Dashboard Server and RTDE (receive only).",
                                   **examples("ftacq robot info 192.168.1.10"))
    actions = parser.add_subparsers(dest="robot_action", metavar="ACTION", required=True)
    info = actions.add_parser("info", help="model, software, serial number, joints, flange pose, modes",
                              description="Print the controller's model, software version, serial number, joint "
                                          "angles, flange pose and modes. Never moves the arm.",
                              **examples("ftacq robot info 192.168.1.10", "ftacq robot info ur5e.local --json"))
    info.add_argument("host", help="controller IP address or host name, e.g. 192.168.1.10")
    info.add_argument("--model", default=None, help="UR model (e.g. UR5e) when the UR Dashboard Server cannot tell")
    info.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    info.set_defaults(func=run_info)


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
    return "[" + ", ".join(f"{v:.{digits}f}" for v in values) + "]" if values is not None else "n/a"


def run_info(args: argparse.Namespace) -> int:
    """Print the controller's identity and state."""
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
