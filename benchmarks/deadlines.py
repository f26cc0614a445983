"""Benchmark: how long each network call to the robot takes to give up on a controller that never answers.

    .venv/bin/python benchmarks/deadlines.py

Issue 15's acceptance: `ftacq robot info` against a controller that accepts TCP and never answers exits within
5 s. The tests (tests/test_ur_deadlines.py) check what the deadlines do (the call ends, its message names the
deadline it waited); the times are here. Prints one line per call: seconds from start to the error, and the
deadline it was given. The two commands run in a subprocess (interpreter and imports included); `ftacq robot info`
against a refused port gives their start-up cost without a deadline to wait.
"""

from __future__ import annotations

import socket
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.ur import URRobot  # noqa: E402
from drivers.robot import MotionLimits  # noqa: E402
from drivers.ur_connection import DASHBOARD_SERVER_PORT, PROBE_TIMEOUT_S, RTDE_PORT, probe_rtde  # noqa: E402
from drivers.ur_dashboard_server import DashboardServerClient, read_controller_info  # noqa: E402
from ftacq.errors import DeviceError  # noqa: E402
from tests.fakes.ur_process import random_loopback_address  # noqa: E402
from tests.test_ur_deadlines import run_ftacq, silent_controller  # noqa: E402


def timed(call) -> float:
    """Seconds ``call()`` took to raise a DeviceError."""
    started = time.monotonic()
    try:
        call()
    except DeviceError:
        return time.monotonic() - started
    raise SystemExit("the call did not fail")


def silent_dashboard_reply_s(reply_timeout_s: float) -> float:
    """A Dashboard Server that greets, then answers nothing: seconds until ``ask`` gives up."""
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    held: list[socket.socket] = []

    def greet() -> None:
        client, _ = listener.accept()
        client.sendall(b"Connected: Universal Robots Dashboard Server\n")
        held.append(client)

    server = threading.Thread(target=greet, daemon=True)
    server.start()
    try:
        client = DashboardServerClient("127.0.0.1", port=listener.getsockname()[1],
                                       reply_timeout_s=reply_timeout_s).connect()
        return timed(lambda: client.ask("PolyscopeVersion"))
    finally:
        server.join(5.0)
        for sock in held:
            sock.close()
        listener.close()


def main() -> None:
    rows = []
    started = time.monotonic()
    run_ftacq("robot", "info", random_loopback_address())
    rows.append(("ftacq robot info, refused port (start-up only)", time.monotonic() - started, 0.0))
    with silent_controller() as host:
        started = time.monotonic()
        run_ftacq("robot", "info", host)
        rows.append(("ftacq robot info, silent controller", time.monotonic() - started, PROBE_TIMEOUT_S))
    with silent_controller(ports=(RTDE_PORT,)) as host:
        rows.append(("probe_rtde, silent RTDE port", timed(lambda: probe_rtde(host, timeout_s=0.5)), 0.5))
    with silent_controller(ports=(DASHBOARD_SERVER_PORT,)) as host:
        rows.append(("read_controller_info, silent Dashboard Server",
                     timed(lambda: read_controller_info(host, timeout_s=0.5)), 0.5))
    rows.append(("Dashboard Server silent after its greeting", silent_dashboard_reply_s(0.3), 0.3))
    rows.append(("URRobot.start, refused port", timed(
        lambda: URRobot(random_loopback_address(), MotionLimits(1.0, 1.0)).start()), 0.0))
    for what, elapsed_s, deadline_s in rows:
        print(f"{what:48s} {elapsed_s:6.2f} s  (deadline {deadline_s:g} s)")


if __name__ == "__main__":
    main()
