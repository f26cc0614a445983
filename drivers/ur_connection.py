"""Reaching a UR controller with a deadline: port probes, an RTDE handshake probe, guarded ur-rtde calls.

ur-rtde's constructors hold the GIL and read their RTDE setup replies with no timeout (docs/protocols-ur.md,
"What the code relies on"): a controller that accepts the TCP connection on port 30004 and never answers would
freeze the whole Python process, Ctrl-C included. So before any ur-rtde object is built, :func:`probe_rtde`
walks the same handshake itself (protocol version, controller version, a one-field output recipe, start, first
data package) on a plain socket with one overall deadline, and fails with a message naming the host and the
port. Only a controller that streams within the deadline is handed to ur-rtde.

:func:`call_with_deadline` runs a ur-rtde method (those release the GIL) on a worker thread and gives up after
a deadline, leaving the worker behind.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from drivers.hosts import check_host
from ftacq.errors import DeviceConnectionError, DeviceTimeoutError, InputError

RTDE_PORT, DASHBOARD_SERVER_PORT, SCRIPT_PORT = 30004, 29999, 30003
"""The controller's fixed TCP ports: RTDE, UR Dashboard Server, the script ("realtime") port ur-rtde uploads to."""
E_SERIES_RATE_HZ, CB3_RATE_HZ = 500.0, 125.0
"""The controller's state rate (its RTDE cycle), Hz: 500 on e-Series and later (software 5+), 125 on a CB3 (every
generation offers 125). Declared here only; the RTDE clients ask :func:`state_rate_hz` of the controller's version,
and the rest of ftacq reads the rate their stream reports."""
PROBE_TIMEOUT_S = 2.0
"""Default deadline of one probe (TCP connect plus, for RTDE, the whole handshake up to the first data package)."""
WATCHDOG_INTERVAL_S = 0.05

RTDE_PROTOCOL_VERSION = 2
RTDE_REQUEST_PROTOCOL_VERSION, RTDE_GET_URCONTROL_VERSION = ord("V"), ord("v")
RTDE_SETUP_OUTPUTS, RTDE_START, RTDE_DATA_PACKAGE, RTDE_TEXT_MESSAGE = ord("O"), ord("S"), ord("U"), ord("M")
RTDE_HEADER = struct.Struct(">HB")
"""Every RTDE package: uint16 total size (header included), uint8 type; big-endian."""
PROBE_FREQUENCY_HZ = CB3_RATE_HZ
"""Output rate asked for by the probe (every controller generation supports 125 Hz)."""
PROBE_VARIABLES = b"timestamp"


def state_rate_hz(version: Sequence[int]) -> float:
    """The fastest RTDE output rate of a controller running software ``version`` (major, minor, …), Hz: 500 from
    software 5 (e-Series, PolyScope X), 125 before (a CB3, software 3); ur-rtde chooses its default alike."""
    return E_SERIES_RATE_HZ if int(version[0]) >= 5 else CB3_RATE_HZ


@dataclass(frozen=True)
class RTDEProbe:
    """What the handshake probe learned: the controller's software version (major, minor, bugfix, build)."""

    version: tuple[int, int, int, int]
    elapsed_s: float

    @property
    def version_text(self) -> str:
        return ".".join(str(v) for v in self.version)


def controller_host(text: str) -> str:
    """The controller's address from what a user typed: an IP address or host name, optionally followed by the
    RTDE port (``192.168.1.10:30004``, dropped: the controller's ports are fixed). Raises InputError (one line)."""
    host, _, port = text.rpartition(":") if text.count(":") == 1 else ("", "", "")
    if host and port.isdigit():
        if int(port) != RTDE_PORT:
            raise InputError(f"robot controller {text!r}: a UR controller's ports are fixed (RTDE {RTDE_PORT}, UR "
                             f"Dashboard Server {DASHBOARD_SERVER_PORT}, script {SCRIPT_PORT}): give the address alone")
        text = host
    return check_host(text, "robot controller")


def _unreachable(host: str, port: int, what: str, error: OSError, timeout_s: float) -> DeviceConnectionError:
    if isinstance(error, ConnectionRefusedError):
        return DeviceConnectionError(
            f"robot controller {host}: cannot connect to port {port} ({what}): nothing listens there; check the IP "
            "address and that the robot is switched on and booted")
    if isinstance(error, socket.timeout):
        return DeviceConnectionError(
            f"robot controller {host} port {port} ({what}): no answer within {timeout_s:g} s; check the IP address, "
            "the network cable and that the robot is switched on")
    return DeviceConnectionError(
        f"robot controller {host}: cannot connect to port {port} ({what}: {error.strerror or error}); check the IP "
        "address and that the robot is switched on and booted")


def connect(host: str, port: int, what: str, timeout_s: float = PROBE_TIMEOUT_S) -> socket.socket:
    """Open a TCP connection within ``timeout_s``; raise DeviceConnectionError naming host and port."""
    try:
        sock = socket.create_connection((host, port), timeout=timeout_s)
    except OSError as error:
        raise _unreachable(host, port, what, error, timeout_s) from error
    except UnicodeError:  # the resolver's IDNA codec refused the name (drivers/hosts.py)
        check_host(host, "robot controller")
        raise
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def probe_port(host: str, port: int, timeout_s: float = PROBE_TIMEOUT_S, what: str = "TCP") -> None:
    """Open and close a TCP connection to ``host:port``; raise DeviceConnectionError naming the port if it fails."""
    connect(host, port, what, timeout_s).close()


def _receive_exactly(sock: socket.socket, size: int, deadline: float) -> bytes:
    data = b""
    while len(data) < size:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise socket.timeout("deadline")
        sock.settimeout(remaining)
        chunk = sock.recv(size - len(data))
        if not chunk:
            raise ConnectionResetError("the controller closed the connection")
        data += chunk
    return data


def _receive_package(sock: socket.socket, deadline: float) -> tuple[int, bytes]:
    size, kind = RTDE_HEADER.unpack(_receive_exactly(sock, RTDE_HEADER.size, deadline))
    if size < RTDE_HEADER.size:
        raise ValueError(f"RTDE package size {size} is below the header size")
    return kind, _receive_exactly(sock, size - RTDE_HEADER.size, deadline)


def _send_package(sock: socket.socket, kind: int, payload: bytes, deadline: float) -> None:
    sock.settimeout(max(deadline - time.monotonic(), 1e-3))
    sock.sendall(RTDE_HEADER.pack(RTDE_HEADER.size + len(payload), kind) + payload)


def _reply(sock: socket.socket, kind: int, deadline: float) -> bytes:
    """The reply to a setup request: the next package that is not a text message, which must be of ``kind``."""
    while True:
        got, payload = _receive_package(sock, deadline)
        if got == RTDE_TEXT_MESSAGE:
            continue
        if got != kind:
            raise ValueError(f"expected an RTDE {chr(kind)!r} reply, got package type {got}")
        return payload


def probe_rtde(host: str, timeout_s: float = PROBE_TIMEOUT_S) -> RTDEProbe:
    """Walk the RTDE handshake ur-rtde will do (V, v, O, S, first U) within ``timeout_s`` in total, then close.

    Raises DeviceConnectionError naming host, port 30004 and the step that got no answer.
    """
    started = time.monotonic()
    deadline = started + timeout_s
    sock = connect(host, RTDE_PORT, "RTDE", timeout_s)
    step = "the protocol-version request"
    try:
        _send_package(sock, RTDE_REQUEST_PROTOCOL_VERSION, struct.pack(">H", RTDE_PROTOCOL_VERSION), deadline)
        _reply(sock, RTDE_REQUEST_PROTOCOL_VERSION, deadline)
        step = "the controller-version request"
        _send_package(sock, RTDE_GET_URCONTROL_VERSION, b"", deadline)
        payload = _reply(sock, RTDE_GET_URCONTROL_VERSION, deadline)
        if len(payload) < 16:
            raise ValueError(f"a controller-version reply of {len(payload)} bytes (16 expected)")
        version = struct.unpack(">IIII", payload[:16])
        step = "the output-recipe setup"
        _send_package(sock, RTDE_SETUP_OUTPUTS, struct.pack(">d", PROBE_FREQUENCY_HZ) + PROBE_VARIABLES, deadline)
        _reply(sock, RTDE_SETUP_OUTPUTS, deadline)
        step = "the start request"
        _send_package(sock, RTDE_START, b"", deadline)
        if _reply(sock, RTDE_START, deadline)[:1] != b"\x01":
            raise ValueError("the controller refused to start the RTDE data stream")
        step = "the first data package"
        while _receive_package(sock, deadline)[0] != RTDE_DATA_PACKAGE:
            pass
    except socket.timeout as error:
        raise DeviceConnectionError(
            f"robot controller {host} port {RTDE_PORT} (RTDE): the connection was accepted but {step} got no answer "
            f"within {timeout_s:g} s; is this a UR controller, booted, with RTDE enabled?") from error
    except (OSError, ValueError, struct.error) as error:
        raise DeviceConnectionError(
            f"robot controller {host} port {RTDE_PORT} (RTDE): {step} failed ({error}); is this a UR controller, "
            "booted, with RTDE enabled?") from error
    finally:
        sock.close()
    return RTDEProbe(version=tuple(int(v) for v in version), elapsed_s=time.monotonic() - started)  # type: ignore[arg-type]


def call_with_deadline(fn: Callable[..., Any], *args: Any, timeout_s: float, what: str,
                       watchdog: Callable[[], None] | None = None) -> Any:
    """Run ``fn(*args)`` on a named worker thread; return its result, re-raise its error, or raise
    DeviceTimeoutError after ``timeout_s`` (the worker is left to finish on its own; ur-rtde methods release the
    GIL, its constructors do not: never pass a constructor here).

    ``watchdog()`` is called every :data:`WATCHDOG_INTERVAL_S` while waiting; it raises to abandon the call early
    (e.g. when the connection is lost: ur-rtde would keep waiting for a reply that never comes)."""
    box: dict = {}

    def run() -> None:
        try:
            box["result"] = fn(*args)
        except BaseException as error:  # noqa: BLE001 - re-raised in the caller's thread
            box["error"] = error

    worker = threading.Thread(target=run, name=f"ur-rtde-{what}", daemon=True)
    worker.start()
    deadline = time.monotonic() + timeout_s
    while worker.is_alive() and time.monotonic() < deadline:
        worker.join(min(WATCHDOG_INTERVAL_S, max(deadline - time.monotonic(), 0.0)))
        if worker.is_alive() and watchdog is not None:
            watchdog()
    if worker.is_alive():
        raise DeviceTimeoutError(f"robot controller did not complete {what} within {timeout_s:g} s")
    if "error" in box:
        raise box["error"]
    return box.get("result")


__all__ = ["RTDE_PORT", "DASHBOARD_SERVER_PORT", "SCRIPT_PORT", "PROBE_TIMEOUT_S", "RTDEProbe", "state_rate_hz",
           "connect", "probe_port", "probe_rtde", "call_with_deadline"]
