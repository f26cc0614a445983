"""Start the simulated UR controller (tests/fakes/ur_controller.py) as a subprocess on its own loopback address.

Used by tests, the procedure's tests and the ``--sim`` demo::

    with URControllerProcess(time_scale=0.0) as fake:
        robot = URRobot(fake.host, MotionLimits())
        ...
        fake.inject("protective_stop", "move_fraction", 0.5)
        fake.commands()  # every motion command the controller executed

The controller's ports are fixed (30004/29999/30003), so each instance binds a random 127.x.y.z (never 127.0.0.1).
If the address is taken (EADDRINUSE on 30004, e.g. the suite runs twice at once) the subprocess reports
``BIND_ERROR`` and this helper retries on another address. Disconnect ur-rtde clients before :meth:`stop`
(docs/protocols-ur.md): otherwise ur-rtde's control interface starts reconnecting.
"""

from __future__ import annotations

import json
import os
import random
import selectors
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ftacq.errors import DeviceError
from tests.fakes.child_process import STOP_TIMEOUT_S, end_process

REPO_ROOT = Path(__file__).resolve().parents[2]
READY_TIMEOUT_S = 20.0
CONTROL_TIMEOUT_S = 5.0
MAX_BIND_ATTEMPTS = 12
REALTIME_PRIORITY_VARIABLE = "FTACQ_SIM_REALTIME_PRIORITY"
"""Environment variable: the SCHED_FIFO priority a simulated controller asks for when not told (unset: 0, normal
scheduling). A real controller has its own computer; on a loaded test machine a simulated one at normal priority
misses its 2 ms cycle for whole seconds (a state stream silent past the driver's watchdog), so the test suite sets it
(tests/conftest.py). Refused without the right to (CAP_SYS_NICE, the rtprio limit): then normal scheduling."""


def default_realtime_priority() -> int:
    """The priority :data:`REALTIME_PRIORITY_VARIABLE` asks for (0 when unset or not a whole number 1-99)."""
    text = os.environ.get(REALTIME_PRIORITY_VARIABLE, "").strip()
    return int(text) if text.isdigit() and 1 <= int(text) <= 99 else 0


def random_loopback_address(rng: random.Random | None = None) -> str:
    """Return a random 127.x.y.z with x, y, z drawn from a large range, never 127.0.0.1."""
    rng = rng or random.SystemRandom()
    x, y, z = rng.randint(1, 254), rng.randint(0, 255), rng.randint(2, 254)
    return f"127.{x}.{y}.{z}"


class URControllerProcess:
    """A running simulated controller: ``host``, ``control_port``, :meth:`control`, :meth:`inject`, :meth:`commands`.

    Args mirror ``python -m tests.fakes.ur_controller``: model, time_scale (0 = instant moves), pose_shm
    (SharedPose name to publish the flange pose into), initial_q (rad), mount, version ("5.11.1.108318").
    ``host`` forces one address (no retry). ``realtime_priority``: SCHED_FIFO for its threads (None:
    :func:`default_realtime_priority`).
    """

    def __init__(self, model: str = "UR5e", time_scale: float = 0.0, pose_shm: str | None = None,
                 initial_q=None, mount: str = "floor", version: str | None = None, host: str | None = None,
                 extra_args: list[str] | None = None, realtime_priority: int | None = None) -> None:
        self.model, self.time_scale, self.pose_shm = model, time_scale, pose_shm
        self.realtime_priority = default_realtime_priority() if realtime_priority is None else realtime_priority
        self.initial_q, self.mount, self.version = initial_q, mount, version
        self._fixed_host = host
        self._extra = list(extra_args or [])
        self.host: str | None = None
        self.control_port: int | None = None
        self.info: dict = {}
        self._process: subprocess.Popen | None = None
        self._control_sock: socket.socket | None = None
        self._control_buffer = b""
        self._stderr = None

    # ------------------------------------------------------------------ life cycle
    def _command(self, host: str) -> list[str]:
        cmd = [sys.executable, "-m", "tests.fakes.ur_controller", "--host", host, "--model", self.model,
               "--time-scale", repr(float(self.time_scale)), "--mount", self.mount]
        if self.pose_shm:
            cmd += ["--pose-shm", self.pose_shm]
        if self.initial_q is not None:
            cmd += ["--initial-q", *[repr(float(v)) for v in self.initial_q]]
        if self.version:
            cmd += ["--version", self.version]
        if self.realtime_priority:
            cmd += ["--realtime-priority", str(self.realtime_priority)]
        return cmd + self._extra

    def start(self) -> "URControllerProcess":
        """Start the controller and wait for READY; retries on another address when the ports are taken."""
        attempts = 1 if self._fixed_host else MAX_BIND_ATTEMPTS
        last_error = ""
        for _ in range(attempts):
            host = self._fixed_host or random_loopback_address()
            env = dict(os.environ, PYTHONUNBUFFERED="1")
            env["PYTHONPATH"] = str(REPO_ROOT) + os.pathsep + env.get("PYTHONPATH", "")
            stderr = tempfile.TemporaryFile()
            # Own session: a Ctrl-C at the terminal reaches ftacq only, which then stops the (simulated) arm itself.
            process = subprocess.Popen(self._command(host), stdout=subprocess.PIPE, stderr=stderr,
                                       stdin=subprocess.DEVNULL, cwd=str(REPO_ROOT), env=env,
                                       start_new_session=True)
            line = self._read_first_line(process)
            if line.startswith("READY "):
                self._process, self.host, self._stderr = process, host, stderr
                self.info = json.loads(line[len("READY "):])
                self.control_port = int(self.info["control"])
                return self
            process.kill()
            process.wait(timeout=STOP_TIMEOUT_S)
            process.stdout.close()
            stderr.seek(0)
            last_error = line or stderr.read().decode(errors="replace")[-2000:]
            stderr.close()
            if not line.startswith("BIND_ERROR"):
                break
        raise DeviceError(f"simulated UR controller did not start: {last_error}")

    @staticmethod
    def _read_first_line(process: subprocess.Popen) -> str:
        selector = selectors.DefaultSelector()
        selector.register(process.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + READY_TIMEOUT_S
        data = b""
        try:
            while b"\n" not in data and time.monotonic() < deadline:
                if not selector.select(timeout=max(deadline - time.monotonic(), 0.0)):
                    break
                chunk = os.read(process.stdout.fileno(), 4096)
                if not chunk:
                    break
                data += chunk
        finally:
            selector.close()
        return data.split(b"\n", 1)[0].decode(errors="replace").strip()

    def stop(self) -> None:
        """Stop the controller process (quit over the control port, then terminate/kill). Safe to call twice."""
        if self._process is None:
            return
        process, self._process = self._process, None
        try:
            if process.poll() is None:
                try:
                    self.control("quit")
                except (OSError, DeviceError):
                    pass
                end_process(process)
        finally:
            if self._control_sock is not None:
                self._control_sock.close()
                self._control_sock = None
            if process.stdout is not None:
                process.stdout.close()
            if self._stderr is not None:
                self._stderr.close()
                self._stderr = None

    def kill(self) -> None:
        """SIGKILL the controller process (a crashed or switched-off controller); :meth:`stop` still cleans up."""
        if self._process is not None and self._process.poll() is None:
            self._process.kill()
            self._process.wait()

    def stderr_text(self) -> str:
        """What the controller process wrote to stderr so far (for test failure messages)."""
        if self._stderr is None:
            return ""
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace")

    @property
    def running(self) -> bool:
        return self._process is not None and self._process.poll() is None

    @property
    def pid(self) -> int:
        """The controller process's id (e.g. for its CPU time in /proc)."""
        if self._process is None:
            raise RuntimeError("simulated UR controller not started")
        return self._process.pid

    def __enter__(self) -> "URControllerProcess":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------------ control channel
    def control(self, line: str) -> dict:
        """Send one control-port command; return its JSON reply. Raises DeviceError when it says ok=false."""
        if self.host is None or self.control_port is None:
            raise DeviceError("simulated UR controller is not running")
        if self._control_sock is None:
            self._control_sock = socket.create_connection((self.host, self.control_port), timeout=CONTROL_TIMEOUT_S)
            self._control_buffer = b""
        self._control_sock.sendall((line.strip() + "\n").encode())
        while b"\n" not in self._control_buffer:
            chunk = self._control_sock.recv(1 << 16)
            if not chunk:
                raise DeviceError(f"simulated UR controller closed the control port during {line!r}")
            self._control_buffer += chunk
        reply_line, self._control_buffer = self._control_buffer.split(b"\n", 1)
        reply = json.loads(reply_line)
        if not reply.get("ok"):
            raise DeviceError(f"control command {line!r} failed: {reply.get('error')}")
        return reply

    def state(self) -> dict:
        """The controller's state: q, flange_pose, tcp_pose, modes, moving, move_count, …"""
        return self.control("state")["state"]

    def commands(self) -> list[dict]:
        """Every motion command executed so far (kind, target, speed, acceleration, async, time, accepted, …)."""
        return self.control("commands")["commands"]

    def events(self) -> list[dict]:
        return self.control("events")["events"]

    def inject(self, kind: str, trigger: str = "now", value: float | None = None, move: int | None = None) -> dict:
        """Inject a fault: kind protective_stop | emergency_stop | program_stop | drop | freeze;
        trigger now | after | move_after | move_fraction (value = seconds or fraction; move = 1-based move number)."""
        line = f"fault {kind} {trigger}"
        if trigger != "now":
            line += f" {value!r}"
            if move is not None:
                line += f" move {int(move)}"
        return self.control(line)

    def external_ft(self) -> dict:
        """The external F/T input as the controller holds it: enabled, function, sensor_mass,
        sensor_measuring_offset, sensor_cog, wrench, received, cycles, cycles_fed, cycles_missed, watchdog_trips,
        enable_calls, owned (an RTDE client holds the input: freed when the controller reads its connection's end)."""
        return self.control("external_ft")["external_ft"]

    def external_ft_records(self) -> dict:
        """Every value the controller received (rows: arrival monotonic s, controller time s, Fx..Tz) and every
        controller cycle counted while enabled (rows: controller time s, fed 0/1, age of the held value s)."""
        reply = self.control("external_ft_records")
        return {"received": np.array(reply["received"]).reshape(-1, 8), "cycles": np.array(reply["cycles"]).reshape(-1, 5)}

    def set_time_scale(self, time_scale: float) -> None:
        self.control(f"set time_scale {float(time_scale)!r}")

    def set_joint_positions(self, q) -> None:
        self.control("set q " + " ".join(repr(float(v)) for v in q))

    def jog(self, q, speed_rad_s: float, acceleration_rad_s2: float) -> float:
        """Move to ``q`` as a moveJ from the teach pendant (the controller's motion profile, not a jump); return the
        move's duration (s). Raises DeviceError when the controller refuses it (not running, a limit)."""
        reply = self.control("jog " + " ".join(repr(float(v)) for v in (*q, speed_rad_s, acceleration_rad_s2)))
        if not reply.get("accepted"):
            raise DeviceError(f"simulated controller {self.host}: refused the jog to {list(np.round(q, 3))}")
        return float(reply["duration_s"])

    def set_tcp_offset(self, tcp) -> None:
        self.control("set tcp_offset " + " ".join(repr(float(v)) for v in tcp))

    def wait_for(self, predicate, timeout_s: float = 10.0, poll_s: float = 0.01) -> dict:
        """Poll :meth:`state` until ``predicate(state)`` is true; return that state (raises TimeoutError)."""
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.state()
            if predicate(state):
                return state
            if time.monotonic() > deadline:
                raise TimeoutError(f"simulated controller state never satisfied the condition: {state}")
            time.sleep(poll_s)


def start_ur_controller(**kwargs) -> URControllerProcess:
    """Start a simulated controller (see :class:`URControllerProcess`) and return it, READY."""
    return URControllerProcess(**kwargs).start()
