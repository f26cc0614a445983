"""Every network call to the robot has a deadline (issue 15): a controller that accepts TCP on 30004/29999/30003
and never answers fails at the connect timeout, with a message naming the host, the port and the deadline it waited.

The silent controller is three listening sockets on a distinct 127.x.y.z that never call accept(): the kernel
completes every TCP handshake, nothing ever answers. The ftacq commands run in a subprocess, because on a build
without the deadline ur-rtde's constructor blocks holding the GIL and nothing in-process could stop it.
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from drivers.ur_connection import DASHBOARD_SERVER_PORT, PROBE_TIMEOUT_S, RTDE_PORT, SCRIPT_PORT, probe_rtde
from drivers.ur_dashboard_server import DashboardServerClient, read_controller_info
from ftacq.errors import DeviceConnectionError, DeviceTimeoutError
from tests.fakes.ur_process import random_loopback_address

REPO_ROOT = Path(__file__).resolve().parents[1]
KILL_AFTER_S = 30.0
"""A hanging command is killed after this (only reached on a build without the deadline). The tests assert what
the deadline does (the call ends, with a message naming the deadline it waited), not how long it took: the elapsed
times are benchmarks/deadlines.py's (issue 15's acceptance: `ftacq robot info` exits within 5 s)."""
WAITED = f"within {PROBE_TIMEOUT_S:g} s"
"""What a message says when the call waited the default probe deadline."""


@contextlib.contextmanager
def silent_controller(ports=(RTDE_PORT, DASHBOARD_SERVER_PORT, SCRIPT_PORT)):
    """Listen on ``ports`` of a random 127.x.y.z and never accept nor answer; yield the host."""
    for _attempt in range(10):
        host, sockets = random_loopback_address(), []
        try:
            for port in ports:
                sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                sockets.append(sock)
                sock.bind((host, port))
                sock.listen(16)
        except OSError:
            for sock in sockets:
                sock.close()
            continue
        try:
            yield host
        finally:
            for sock in sockets:
                sock.close()
        return
    raise RuntimeError("no free 127.x.y.z for the silent controller")


def run_ftacq(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run ``ftacq ARGS`` in a subprocess (failing the test if it still runs after KILL_AFTER_S)."""
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    try:
        result = subprocess.run([sys.executable, "-m", "ftacq.app.cli", *args], capture_output=True, text=True,
                                timeout=KILL_AFTER_S, env=env, cwd=cwd or REPO_ROOT, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        pytest.fail(f"`ftacq {' '.join(args)}` against a silent controller still ran after {KILL_AFTER_S:g} s")
    return result


def test_robot_info_against_a_silent_controller_ends_at_the_probe_deadline_naming_host_and_port():
    with silent_controller() as host:
        result = run_ftacq("robot", "info", host)
    assert result.returncode == 1, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert host in lines[0] and str(RTDE_PORT) in lines[0] and f"no answer {WAITED}" in lines[0], lines[0]


def test_calibrate_dry_run_against_a_silent_controller_ends_at_the_probe_deadline(tmp_path):
    with silent_controller() as host:
        config = tmp_path / "CELL.toml"
        config.write_text(f'[robot]\nhost = "{host}"\n[sensor]\nurl = "netft://{host}"\n', encoding="utf-8")
        result = run_ftacq("calibrate", "--config", str(config), "--dry-run", cwd=tmp_path)
    assert result.returncode == 1, result.stderr
    assert "Traceback" not in result.stderr
    assert host in result.stderr and str(RTDE_PORT) in result.stderr and WAITED in result.stderr, result.stderr


def test_the_rtde_probe_names_the_step_that_got_no_answer():
    with silent_controller(ports=(RTDE_PORT,)) as host:
        with pytest.raises(DeviceConnectionError) as caught:
            probe_rtde(host, timeout_s=0.5)
    message = str(caught.value)
    assert host in message and f"port {RTDE_PORT}" in message and "protocol-version request" in message
    assert "got no answer within 0.5 s" in message  # the deadline given, not a default


def _greeting_then_silence(listener: socket.socket, held: list) -> None:
    client, _ = listener.accept()
    client.sendall(b"Connected: Universal Robots Dashboard Server\n")
    held.append(client)  # read nothing, answer nothing


def test_dashboard_server_silent_after_the_greeting_times_out_naming_host_and_port():
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    held: list = []
    server = threading.Thread(target=_greeting_then_silence, args=(listener, held), daemon=True)
    server.start()
    port = listener.getsockname()[1]
    try:
        client = DashboardServerClient("127.0.0.1", port=port, reply_timeout_s=0.3).connect()
        with pytest.raises(DeviceTimeoutError,
                           match=rf"127\.0\.0\.1 port {port} .*no answer to 'PolyscopeVersion' within 0\.3 s"):
            client.ask("PolyscopeVersion")
        assert client._sock is None  # closed: the next call does not read this answer late
    finally:
        server.join(timeout=5.0)
        for sock in held:
            sock.close()
        listener.close()


def test_read_controller_info_from_a_silent_dashboard_server_fails_within_its_deadline():
    with silent_controller(ports=(DASHBOARD_SERVER_PORT,)) as host:
        with pytest.raises(DeviceConnectionError, match=rf"{host} port {DASHBOARD_SERVER_PORT} .*within 0\.5 s"):
            read_controller_info(host, timeout_s=0.5)
