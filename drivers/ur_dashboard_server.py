"""The UR Dashboard Server (TCP 29999) client: identity, modes and recovery commands, every reply with a deadline.

Not to be confused with ftacq's Rerun dashboard (:mod:`ftacq.app.dashboard`). The protocol is one ASCII line per
command and one line per reply, after a greeting line on connect (docs/protocols-ur.md, "Dashboard Server").
This client is plain Python on a socket with a timeout, so a server that accepts and never answers costs at most
the deadline; ur-rtde's own ``DashboardClient`` is not used.
"""

from __future__ import annotations

import re
import socket
import time
from dataclasses import dataclass

from drivers.ur_connection import DASHBOARD_SERVER_PORT, PROBE_TIMEOUT_S, connect
from ftacq.errors import DeviceConnectionError, DeviceTimeoutError, RobotError
from ftacq.kinematics import URModel, ur_model

REPLY_TIMEOUT_S = 2.5
"""Deadline of one reply line (what ur-rtde uses too)."""
MAX_LINE_BYTES = 4096
"""A reply longer than this is not a Dashboard Server line."""
UNLOCK_REPLY = "Protective stop releasing"
_E_SERIES_DASHBOARD_NAMES = ("UR3", "UR5", "UR10", "UR16")
_VERSION = re.compile(r"(\d+)\.(\d+)\.(\d+)\.(\d+)")


def model_from_dashboard_server(reply: str, major_version: int | None) -> URModel | None:
    """Map a Dashboard Server ``get robot model`` reply to a :class:`URModel` (None for an unknown reply).

    The server answers ``UR3``/``UR5``/``UR10``/``UR16`` for both the CB3 and the e-Series arm; software major
    version 5 (PolyScope 5) and 10 (PolyScope X) only run on e-Series (and UR20/UR30) arms, 3 on CB3.
    """
    name = reply.strip().upper()
    if name.endswith("E") and name[:-1] in _E_SERIES_DASHBOARD_NAMES:
        return ur_model(name[:-1] + "e")
    if name in _E_SERIES_DASHBOARD_NAMES:
        e_series = major_version is None or major_version >= 5 or name == "UR16"
        return ur_model(name + "e" if e_series else name)
    try:
        return ur_model(name)
    except ValueError:
        return None


def parse_version(reply: str | None) -> tuple[int, int, int, int] | None:
    """The first ``a.b.c.d`` in a ``PolyscopeVersion`` reply (``URSoftware 5.11.1.108318 (Dec 06 2021)``)."""
    match = _VERSION.search(reply or "")
    return tuple(int(g) for g in match.groups()) if match else None  # type: ignore[return-value]


class DashboardServerClient:
    """One connection to the UR Dashboard Server. ``with DashboardServerClient(host) as server: server.ask(...)``.

    Raises DeviceConnectionError (unreachable, no greeting, connection closed) and DeviceTimeoutError (no reply
    within :data:`REPLY_TIMEOUT_S`), both naming the host and port 29999.
    """

    def __init__(self, host: str, port: int = DASHBOARD_SERVER_PORT, connect_timeout_s: float = PROBE_TIMEOUT_S,
                 reply_timeout_s: float = REPLY_TIMEOUT_S) -> None:
        self.host, self.port = host, port
        self.connect_timeout_s, self.reply_timeout_s = connect_timeout_s, reply_timeout_s
        self._sock: socket.socket | None = None
        self._buffer = b""

    def connect(self) -> "DashboardServerClient":
        self._sock = connect(self.host, self.port, "Dashboard Server", self.connect_timeout_s)
        try:
            self._line(self.connect_timeout_s, "the greeting")
        except DeviceTimeoutError as error:
            self.close()
            raise DeviceConnectionError(str(error)) from error
        except BaseException:
            self.close()
            raise
        return self

    def __enter__(self) -> "DashboardServerClient":
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()

    def _where(self) -> str:
        return f"robot controller {self.host} port {self.port} (Dashboard Server)"

    def _line(self, timeout_s: float, what: str) -> str:
        if self._sock is None:
            raise DeviceConnectionError(f"{self._where()}: not connected")
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buffer:
            remaining = deadline - time.monotonic()
            try:
                if remaining <= 0:
                    raise socket.timeout
                self._sock.settimeout(remaining)
                chunk = self._sock.recv(MAX_LINE_BYTES)
            except socket.timeout:
                self.close()
                raise DeviceTimeoutError(f"{self._where()}: no answer to {what} within {timeout_s:g} s") from None
            except OSError as error:
                self.close()
                raise DeviceConnectionError(f"{self._where()}: {what}: {error}") from error
            if not chunk:
                self.close()
                raise DeviceConnectionError(f"{self._where()}: the server closed the connection ({what})")
            self._buffer += chunk
            if len(self._buffer) > MAX_LINE_BYTES and b"\n" not in self._buffer:
                self.close()
                raise DeviceConnectionError(f"{self._where()}: a reply line longer than {MAX_LINE_BYTES} bytes")
        line, self._buffer = self._buffer.split(b"\n", 1)
        return line.decode("utf-8", "replace").strip()

    def ask(self, command: str) -> str:
        """Send one command line and return the reply line (stripped)."""
        if self._sock is None:
            raise DeviceConnectionError(f"{self._where()}: not connected")
        try:
            self._sock.settimeout(self.reply_timeout_s)
            self._sock.sendall(command.encode("ascii") + b"\n")
        except OSError as error:
            self.close()
            raise DeviceConnectionError(f"{self._where()}: cannot send {command!r}: {error}") from error
        return self._line(self.reply_timeout_s, repr(command))

    # ------------------------------------------------------------------ recovery commands
    def close_safety_popup(self) -> None:
        self.ask("close safety popup")

    def power_on(self) -> None:
        self.ask("power on")

    def brake_release(self) -> None:
        self.ask("brake release")

    def unlock_protective_stop(self) -> None:
        """Unlock a protective stop (the pendant's Unlock button); RobotError when the server refuses."""
        reply = self.ask("unlock protective stop")
        if reply != UNLOCK_REPLY:
            raise RobotError(f"{self._where()}: unlock protective stop refused: {reply}")


@dataclass(frozen=True)
class URControllerInfo:
    """What the Dashboard Server (and the RTDE handshake, for the version) say about the controller."""

    model_reply: str | None
    model: URModel | None
    software_version: str | None
    serial_number: str | None
    robot_mode: str | None
    safety_status: str | None
    program_state: str | None
    remote_control: bool | None

    @classmethod
    def unknown(cls, software_version: str | None = None) -> "URControllerInfo":
        return cls(None, None, software_version, None, None, None, None, None)


def read_controller_info(host: str, timeout_s: float = PROBE_TIMEOUT_S) -> URControllerInfo:
    """Ask the Dashboard Server for model, software version, serial number and modes.

    A reply the server refuses leaves that item None; an unreachable or silent server raises
    DeviceConnectionError / DeviceTimeoutError (PolyScope X has no Dashboard Server: callers fall back).
    """
    with DashboardServerClient(host, connect_timeout_s=timeout_s) as server:
        version = parse_version(server.ask("PolyscopeVersion"))
        major, minor = (version[0], version[1]) if version else (None, None)
        model_reply = server.ask("get robot model") or None
        newer = major == 5 and (minor or 0) >= 6  # the serial number and remote control exist from 5.6
        serial = server.ask("get serial number") if newer else None
        remote = "true" in server.ask("is in remote control").lower() if newer else None
        safety = server.ask("safetystatus")
        if not safety or safety.lower().startswith("could not understand"):
            safety = server.ask("safetymode")
        return URControllerInfo(
            model_reply=model_reply,
            model=model_from_dashboard_server(model_reply, major) if model_reply else None,
            software_version=".".join(map(str, version)) if version else None,
            serial_number=serial if serial and serial.isdigit() else None,
            robot_mode=server.ask("robotmode"), safety_status=safety, program_state=server.ask("programState"),
            remote_control=remote)


__all__ = ["DashboardServerClient", "URControllerInfo", "read_controller_info", "model_from_dashboard_server",
           "parse_version", "REPLY_TIMEOUT_S"]
