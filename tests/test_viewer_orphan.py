"""``--serve`` starts a Rerun web-viewer server; it must not outlive ftacq, even when ftacq is SIGKILLed (issue 15).

A child process starts the server the way ``--serve`` does (:func:`ftacq.app.dashboard.sinks._serve_web`) on free
loopback ports, reports them, and is killed; the server's gRPC port must then stop accepting connections.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SERVER_GONE_TIMEOUT_S = 15.0

CHILD = textwrap.dedent("""
    import socket, sys
    from ftacq.app.dashboard.sinks import _serve_web
    ports = []
    for _ in range(2):
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            ports.append(probe.getsockname()[1])
    process = _serve_web(*ports)
    print(ports[0], ports[1], process.pid, flush=True)
    sys.stdin.read()  # until killed
""")


def port_open(port: int) -> bool:
    with socket.socket() as sock:
        sock.settimeout(0.5)
        return sock.connect_ex(("127.0.0.1", port)) == 0


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # zombies count as gone: they hold no socket
    state = subprocess.run(["ps", "-o", "stat=", "-g", str(pgid)], capture_output=True, text=True).stdout.split()
    return any(not s.startswith("Z") for s in state)


def test_the_web_viewer_server_exits_when_ftacq_is_killed():
    child = subprocess.Popen([sys.executable, "-c", CHILD], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, cwd=REPO_ROOT,
                             env=dict(os.environ, PYTHONPATH=str(REPO_ROOT)))
    pgid = None
    try:
        line = child.stdout.readline().split()
        if len(line) != 3:
            pytest.fail(f"the server did not start: {child.stderr.read() if child.poll() is not None else line}")
        grpc_port, _web_port, pgid = (int(v) for v in line)
        assert port_open(grpc_port)
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=10.0)
        deadline = time.monotonic() + SERVER_GONE_TIMEOUT_S
        while port_open(grpc_port) or group_alive(pgid):
            assert time.monotonic() < deadline, "the viewer server outlived the killed ftacq"
            time.sleep(0.05)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        if pgid is not None and group_alive(pgid):
            os.killpg(pgid, signal.SIGKILL)  # clean up after a failure: never leave a server behind
        for stream in (child.stdin, child.stdout, child.stderr):
            stream.close()
