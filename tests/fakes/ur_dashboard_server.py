"""UR Dashboard Server replies (port 29999) of the simulated controller (docs/protocols-ur.md).

One ASCII line in, exactly one line out (``\\n``-terminated, no ``\\r``). :func:`dashboard_server_reply` is pure logic
over a :class:`~tests.fakes.ur_simulator.URSimulator`; the socket loop lives in ur_controller.py.
"""

from __future__ import annotations

from tests.fakes.ur_simulator import (
    ROBOT_MODE_IDLE,
    ROBOT_MODE_NAMES,
    ROBOT_MODE_POWER_OFF,
    ROBOT_MODE_RUNNING,
    RUNTIME_PLAYING,
    RUNTIME_STOPPED,
    SAFETY_MODE_NAMES,
    SAFETY_NORMAL,
    SAFETY_PROTECTIVE_STOP,
    URSimulator,
)

GREETING = "Connected: Universal Robots Dashboard Server"
RUNTIME_PAUSED = 4


def dashboard_server_model_name(model_name: str) -> str:
    """What ``get robot model`` answers: UR's dashboard drops the e-Series ``e`` (UR5e → ``UR5``)."""
    return model_name[:-1] if model_name.lower().endswith("e") else model_name


def _program_name(sim: URSimulator) -> str:
    if sim.script is not None:
        return "rtde_control"
    return sim.loaded_program or "<unnamed>"


def dashboard_server_reply(sim: URSimulator, line: str) -> str:
    """Return the reply line (without newline) to one dashboard command."""
    command = line.strip()
    lower = command.lower()
    major, minor, bugfix, build = sim.version
    with sim.lock:
        if lower == "polyscopeversion":
            return f"URSoftware {major}.{minor}.{bugfix}.{build} (Dec 06 2021)"
        if lower == "version":
            return f"Version: {major}.{minor}.{bugfix}.{build}"
        if lower == "get serial number" and (major, minor) >= (5, 6):
            return sim.serial_number
        if lower == "get robot model":
            return dashboard_server_model_name(sim.model.name)
        if lower == "is in remote control":
            return "true"
        if lower == "robotmode":
            return f"Robotmode: {ROBOT_MODE_NAMES.get(sim.robot_mode, 'UNKNOWN')}"
        if lower == "safetymode":
            return f"Safetymode: {SAFETY_MODE_NAMES.get(sim.safety_mode, 'UNDEFINED_SAFETY_MODE')}"
        if lower == "safetystatus":
            return f"Safetystatus: {SAFETY_MODE_NAMES.get(sim.safety_mode, 'UNDEFINED_SAFETY_MODE')}"
        if lower == "programstate":
            state = {RUNTIME_PLAYING: "PLAYING", RUNTIME_PAUSED: "PAUSED"}.get(sim.runtime_state, "STOPPED")
            return f"{state} {_program_name(sim)}"
        if lower == "running":
            return f"Program running: {'true' if sim.runtime_state == RUNTIME_PLAYING else 'false'}"
        if lower == "get loaded program":
            return f"Loaded program: {sim.loaded_program}" if sim.loaded_program else "No program loaded"
        if lower.startswith("load "):
            name = command[5:].strip()
            if not name.endswith(".urp"):
                return f"File not found: {name}"
            sim.loaded_program = name
            return f"Loading program: {name}"
        if lower == "play":
            if not sim.loaded_program or not sim.can_move():
                return "Failed to execute: play"
            sim.script = None
            sim.runtime_state = RUNTIME_PLAYING
            return "Starting program"
        if lower == "stop":
            sim.stop_program("dashboard stop")
            return "Stopped"
        if lower == "pause":
            if sim.runtime_state != RUNTIME_PLAYING:
                return "Failed to execute: pause"
            sim.runtime_state = RUNTIME_PAUSED
            return "Pausing program"
        if lower == "unlock protective stop":
            if sim.safety_mode == SAFETY_PROTECTIVE_STOP:
                sim.unlock_protective_stop()
            return "Protective stop releasing"
        if lower == "power on":
            if not sim.estop_pressed and sim.robot_mode == ROBOT_MODE_POWER_OFF:
                sim.robot_mode = ROBOT_MODE_IDLE
            return "Powering on"
        if lower == "power off":
            sim.stop_program("power off")
            sim.robot_mode = ROBOT_MODE_POWER_OFF
            return "Powering off"
        if lower == "brake release":
            if not sim.estop_pressed and sim.safety_mode == SAFETY_NORMAL:
                if sim.robot_mode == ROBOT_MODE_POWER_OFF:
                    sim.robot_mode = ROBOT_MODE_IDLE
                if sim.robot_mode == ROBOT_MODE_IDLE:
                    sim.robot_mode = ROBOT_MODE_RUNNING
            return "Brake releasing"
        if lower == "close popup":
            return "closing popup"
        if lower == "close safety popup":
            sim.popup = None
            return "closing safety popup"
        if lower.startswith("popup "):
            return "showing popup"
        if lower.startswith("addtolog "):
            return "Added log message"
        if lower == "restart safety":
            if not sim.estop_pressed:
                sim.stop_program("restart safety")
                sim.safety_mode = SAFETY_NORMAL
                sim.robot_mode = ROBOT_MODE_POWER_OFF
            return "Restarting safety"
        if lower == "isprogramsaved":
            return f"true {_program_name(sim)}"
        if lower.startswith("setuserrole "):
            return f"Setting user role: {command[12:].strip()}"
        if lower == "get operational mode":
            return "NONE"
        if lower == "quit":
            return "Disconnected"
        if lower == "shutdown":
            return "Shutting down"
        return f"could not understand: '{command}'"


__all__ = ["GREETING", "dashboard_server_reply", "dashboard_server_model_name", "RUNTIME_STOPPED", "ROBOT_MODE_RUNNING"]
