"""Simulated Universal Robots controller that the unmodified ur-rtde client drives, in its own process.

    python -m tests.fakes.ur_controller --host 127.0.0.2 [--model UR5e] [--time-scale 1.0] [--pose-shm NAME]
        [--initial-q q0 .. q5] [--mount floor|wall|ceiling|tilted:A,B|gravity:X,Y,Z] [--version 5.11.1.108318]

Listens on the controller's fixed ports of ``--host``: 30004 (RTDE), 29999 (UR Dashboard Server), 30003 (script), and on a
line-based control port (port 0, reported) for tests. Prints one line when listening::

    READY {"host": "127.0.0.2", "rtde": 30004, "dashboard_server": 29999, "script": 30003, "control": 40123, ...}

or, when a fixed port is taken, ``BIND_ERROR {"host": ..., "port": ..., "error": ...}`` and exits with status 3
(tests/fakes/ur_process.py then retries on another address). Why a process: ur-rtde's constructors hold the GIL,
so a fake in the client's process deadlocks (docs/protocols-ur.md).

Control port commands (one line each, one JSON line back, ``{"ok": true, ...}`` or ``{"ok": false, "error": ...}``):

- ``ping`` · ``state`` · ``commands`` (every motion command executed: kind, target, speed, acceleration, async,
  time, accepted, reason, source, move) · ``events`` · ``clear_commands``
- ``external_ft`` (the external F/T input: enable state and arguments, counts of received values and controller
  cycles fed/missed, watchdog trips) · ``external_ft_records`` (every received value with its arrival time, every
  counted cycle; tests/fakes/ur_external_ft.py)
- ``fault KIND [now | after S | move_after S [move K] | move_fraction F [move K]]`` with KIND one of
  ``protective_stop``, ``emergency_stop``, ``program_stop``, ``drop`` (close every client connection and
  refuse new ones until ``restore``), ``freeze`` (keep connections, stop sending data and answering: a pulled
  cable). K counts moves from 1 as in
  ``commands``' ``move`` field; default: the next move.
- ``release_estop`` (the e-stop button is released; then ``close safety popup``, ``power on``, ``brake release``
  on the UR Dashboard Server, as on a real arm) · ``restore`` (end a drop or freeze) · ``clear_faults``
- ``jog q0 .. q5 SPEED ACCELERATION`` (a moveJ from the teach pendant: the arm moves with the controller's motion
  profile, so a simulated sensor sees the tool's inertia; answers ``accepted`` and the move's ``duration_s``) ·
  ``set time_scale X`` · ``set q q0 .. q5`` (a jump, no motion) · ``set tcp_offset x y z rx ry rz`` · ``quit``
- ``clock`` (``host_s``: ``time.monotonic()`` now, ``controller_s``: the controller's clock then (RTDE ``timestamp``),
  ``start_host_s``, ``clock_rate_error``, ``send_jitter_s``)
- ``set external_ft_axes s1 .. s6`` (signs ±1: the controller reads ``external_force_torque`` with other signs,
  the deliberate error ``ftacq bridge --check`` must catch) · ``set external_ft_watchdog S`` (the input's watchdog
  period, 0.1 s by default, as a program's ``rtde_set_watchdog`` sets it)

Over 600 lines: the RTDE, UR Dashboard Server, script and control-port servers of one process; each could be its
own module (next split), the state they serve lives in ur_simulator.py.
"""

from __future__ import annotations

import argparse
import errno
import gc
import json
import math
import os
import select
import signal
import socket
import struct
import sys
import threading
import time

import numpy as np

from ftacq.kinematics import ur_model
from tests.fakes import rtde_protocol as rp
from tests.fakes.ur_dashboard_server import GREETING, dashboard_server_reply
from tests.fakes.ur_simulator import E_SERIES_CYCLE_S, ENCODER_NOISE_RAD, SERVO_LAG_S, Fault, URSimulator

RTDE_PORT, DASHBOARD_SERVER_PORT, SCRIPT_PORT = 30004, 29999, 30003
READ_POLL_S = 0.5
"""A connection's thread checks whether the connection was closed this often, s."""
RECEIVE_CHUNK_BYTES = 65536
SWITCH_INTERVAL_S = 0.0002
"""The interpreter's thread switch interval in this process (Python's default is 5 ms): the tick thread and the
connection threads each get the interpreter within this when they wake, as a real-time controller would serve them."""
IDLE_TICK_S = 0.01
"""Tick period while no client streams and nothing moves (keeps an idle controller CPU-light)."""
SEND_TIMEOUT_S = 1.0
BIND_ERROR_EXIT = 3
TOOL_MOTION_OUTPUTS = frozenset({"actual_TCP_speed", "target_TCP_speed", "actual_tool_accelerometer"})
FAULT_KINDS = ("protective_stop", "emergency_stop", "program_stop", "drop", "freeze")


SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_STAMP_SPACE = socket.CMSG_SPACE(16)


def _kernel_arrival_s(ancillary) -> float | None:
    """The kernel's receive stamp (SO_TIMESTAMPNS, CLOCK_REALTIME) of the newest bytes read, on the monotonic clock:
    when an input reached this controller, however late this process's threads got to it."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(data) >= 16:
            seconds, nanoseconds = struct.unpack("qq", data[:16])
            return time.monotonic() - (time.time() - (seconds + nanoseconds * 1e-9))
    return None


def _listener(host: str, port: int) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    sock.listen(8)
    return sock


def _alive(connection: "RTDEConnection") -> bool:
    """False once the peer closed its end (a pending EOF), even before the connection's thread has read it."""
    if connection.closed:
        return False
    try:
        return connection.sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) != b""
    except BlockingIOError:
        return True
    except OSError:
        return False


class _OutputPlan:
    """Turns a simulator snapshot into the flat value list of one output recipe."""

    def __init__(self, recipe: rp.Recipe) -> None:
        self.recipe = recipe
        self.items = []
        for name, type_name, count in zip(recipe.names, recipe.types, recipe.counts):
            source, key = "field", name
            for prefix, src in (("output_int_register_", "out_int"), ("output_double_register_", "out_dbl"),
                                ("input_int_register_", "in_int"), ("input_double_register_", "in_dbl")):
                if name.startswith(prefix):
                    source, key = src, int(name[len(prefix):])
            zero = 0.0 if rp.TYPE_FORMATS[type_name][0] == "d" else (False if type_name == "BOOL" else 0)
            self.items.append((source, key, count, zero))
        # the whole DATA_PACKAGE (size, type, recipe id, values) in one struct: rp.frame's bytes, one call per tick
        self.package_size = rp.HEADER_SIZE + 1 + recipe.codec.size
        self.package_codec = struct.Struct(">HBB" + recipe.codec.format.lstrip(">"))

    def package(self, snap: dict) -> bytes:
        """The DATA_PACKAGE of this recipe for a simulator snapshot (as ``rp.frame`` of ``recipe.pack``)."""
        if self.package_size > rp.MAX_PACKAGE_SIZE:
            return rp.frame(rp.DATA_PACKAGE, self.recipe.pack(self.flatten(snap)))  # raises: too large
        return self.package_codec.pack(self.package_size, rp.DATA_PACKAGE, self.recipe.recipe_id & 0xFF,
                                       *self.flatten(snap))

    def flatten(self, snap: dict) -> list:
        out: list = []
        fields = snap["fields"]
        for source, key, count, zero in self.items:
            value = fields.get(key) if source == "field" else snap[source][key]
            if value is None:
                value = (zero,) * count if count > 1 else zero
            if count > 1:
                out.extend(value)
            else:
                out.append(value)
        return out


class RTDEConnection:
    """One client on port 30004: setup requests answered synchronously, data packages sent by the tick thread."""

    def __init__(self, server: "ControllerServer", sock: socket.socket) -> None:
        self.server, self.sock = server, sock
        self.send_lock = threading.Lock()
        self.protocol_version = 1
        self.outputs: _OutputPlan | None = None
        self.inputs: dict[int, rp.Recipe] = {}
        self.period_s = 0.0
        """Between two data packages, s: set with the output recipe (the controller's cycle or the rate asked)."""
        self.next_send_s = 0.0
        self.last_sent_seq = 0
        self.streaming = False
        self.closed = False
        self.receive_lock = threading.Lock()
        self.received = bytearray()
        self.unsent = b""
        """The rest of a data package the kernel took only in part (sent first, so that packages stay whole)."""
        self.dropped_packages = 0
        """Data packages not sent because the client did not read them in time (a real controller drops them)."""
        sock.settimeout(None)
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)  # the kernel stamps when each input arrived
        # a send timeout only (a Python socket timeout would also apply to the reader thread's recv)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, struct.pack("ll", int(SEND_TIMEOUT_S), 0))

    def send(self, package_type: int, payload: bytes = b"") -> bool:
        with self.send_lock:
            return self._send_locked(rp.frame(package_type, payload))

    def _send_locked(self, data: bytes) -> bool:
        """Send a reply (blocking up to SEND_TIMEOUT_S), after the rest of a partly sent data package."""
        if self.closed:
            return False
        try:
            self.sock.sendall(self.unsent + data)
            self.unsent = b""
            return True
        except OSError:
            self.close()
            return False

    def _send_droppable(self, package: bytes) -> None:
        """Send a data package without waiting: a client that does not read in time loses packages, whole ones,
        and never holds up the tick (the controller drops packages rather than queueing them; docs/protocols-ur.md),
        so one slow client cannot silence the others."""
        if self.closed:
            return
        try:
            if self.unsent:
                self.unsent = self.unsent[self.sock.send(self.unsent, socket.MSG_DONTWAIT):]
                if self.unsent:
                    self.dropped_packages += 1
                    return
            sent = self.sock.send(package, socket.MSG_DONTWAIT)
            self.unsent = package[sent:]
        except BlockingIOError:
            self.dropped_packages += 1
        except OSError:
            self.close()

    def send_data(self, snap: dict) -> None:
        with self.send_lock:
            if self.streaming and self.outputs is not None:
                self._send_droppable(self.outputs.package(snap))

    def close(self) -> None:
        if self.closed:
            return
        self.closed, self.streaming = True, False
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()

    def serve(self) -> None:
        """The connection's thread: wait for bytes, then :meth:`pump` them (the tick thread pumps too)."""
        try:
            while not self.closed:
                readable, _, _ = select.select([self.sock], [], [], READ_POLL_S)
                if readable and not self.pump():
                    break
        except (OSError, ValueError):  # closed under us
            pass
        finally:
            self.close()
            self.server.forget(self)

    def pump(self) -> bool:
        """Read whatever has arrived (never wait for more) and handle every whole package in order; False once the
        client has closed. Called by the connection's thread and, for the owner of ``external_force_torque``, by
        the tick thread at the start of each cycle: a controller reads its inputs at the start of a cycle, so a
        value that reached the socket before the cycle counts for it even if this process's reader thread has
        not run yet (a real controller has no interpreter lock)."""
        with self.receive_lock:
            arrival_s = None
            while True:
                try:
                    chunk, ancillary, _flags, _address = self.sock.recvmsg(RECEIVE_CHUNK_BYTES, _STAMP_SPACE,
                                                                           socket.MSG_DONTWAIT)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    return False
                if not chunk:
                    return False
                arrival_s = _kernel_arrival_s(ancillary)
                self.received += chunk
                if len(chunk) < RECEIVE_CHUNK_BYTES:
                    break
            buffer = self.received
            while len(buffer) >= rp.HEADER_SIZE:
                size, package_type = rp.HEADER.unpack_from(buffer)
                end = max(size, rp.HEADER_SIZE)
                if len(buffer) < end:
                    break
                body = bytes(buffer[rp.HEADER_SIZE:end])
                del buffer[:end]
                if not self.server.frozen:
                    self._handle(package_type, body, arrival_s)
        return True

    def _handle(self, package_type: int, body: bytes, arrival_s: float | None = None) -> None:
        sim = self.server.sim
        if package_type == rp.REQUEST_PROTOCOL_VERSION:
            requested = struct.unpack(">H", body[:2])[0] if len(body) >= 2 else 1
            accepted = requested in (1, 2)
            if accepted:
                self.protocol_version = requested
            self.send(rp.REQUEST_PROTOCOL_VERSION, bytes([1 if accepted else 0]))
        elif package_type == rp.GET_URCONTROL_VERSION:
            self.send(rp.GET_URCONTROL_VERSION, rp.pack_version(*sim.version))
        elif package_type == rp.CONTROL_PACKAGE_SETUP_OUTPUTS:
            fastest_hz = 1.0 / sim.cycle_s
            requested = fastest_hz
            if self.protocol_version >= 2 and len(body) >= 8:
                requested = struct.unpack(">d", body[:8])[0]
                body = body[8:]
            recipe = rp.Recipe.build(1, rp.split_names(body), rp.OUTPUT_TYPES)
            if recipe.known:
                self.outputs = _OutputPlan(recipe)
                self.server.update_tool_motion_outputs()
                # faster than the controller's cycle (500 Hz asked of a CB3): streamed at the cycle, no refusal
                frequency = requested if 0 < requested <= fastest_hz else fastest_hz
                self.period_s = 1.0 / frequency
                with sim.lock:
                    sim._event("output_setup", requested_hz=requested, streamed_hz=frequency)
            self.send(rp.CONTROL_PACKAGE_SETUP_OUTPUTS, recipe.setup_reply())
        elif package_type == rp.CONTROL_PACKAGE_SETUP_INPUTS:
            names = rp.split_names(body)
            taken = self.server.claim_inputs(self, names)
            if taken:
                # RTDE guide: only one client may control a variable at a time; the recipe is refused
                types = [rp.IN_USE if name in taken else rp.INPUT_TYPES.get(name, rp.NOT_FOUND) for name in names]
                self.send(rp.CONTROL_PACKAGE_SETUP_INPUTS, bytes([0]) + ",".join(types).encode("ascii"))
                return
            recipe = rp.Recipe.build(len(self.inputs) + 1, names, rp.INPUT_TYPES)
            self.inputs[recipe.recipe_id] = recipe
            self.send(rp.CONTROL_PACKAGE_SETUP_INPUTS, recipe.setup_reply())
        elif package_type == rp.CONTROL_PACKAGE_START:
            with self.send_lock:
                ok = self._send_locked(rp.frame(rp.CONTROL_PACKAGE_START, bytes([1 if self.outputs else 0])))
                if ok and self.outputs is not None:
                    self.last_sent_seq = self.server.sim.tick_seq
                    self.streaming = True
                    self.next_send_s = time.monotonic()
            self.server.update_stream_period()
        elif package_type == rp.CONTROL_PACKAGE_PAUSE:
            with self.send_lock:
                self.streaming = False
                self._send_locked(rp.frame(rp.CONTROL_PACKAGE_PAUSE, bytes([1])))
        elif package_type == rp.DATA_PACKAGE and body:
            recipe = self.inputs.get(body[0])
            if recipe is None or not recipe.known:
                return
            if len(body) - 1 != recipe.codec.size:
                with sim.lock:  # ur-rtde sends short packages for wrong-length vectors (setExternalForceTorque)
                    sim._event("short_package", recipe=recipe.recipe_id, bytes=len(body) - 1, expected=recipe.codec.size)
            values = recipe.unpack_partial(body[1:])
            doubles = sum(c for t, c in zip(recipe.types, recipe.counts) if rp.TYPE_FORMATS[t][0] == "d")
            sim.apply_inputs(values, doubles, arrival_s)


class ControllerServer:
    """All listeners, connection threads and the tick thread of one simulated controller."""

    def __init__(self, sim: URSimulator, host: str, pose_shm: str | None = None, send_jitter_s: float = 0.0,
                 seed: int | None = None) -> None:
        self.sim, self.host = sim, host
        if send_jitter_s < 0.0:
            raise ValueError(f"send_jitter_s {send_jitter_s!r}: must be >= 0")
        self.send_jitter_s = float(send_jitter_s)
        """Each cycle, the receive-only clients' packages leave after a random delay in [0, this] s (a real
        controller's network stack); the client that feeds external_force_torque is served first, undelayed."""
        self._jitter_rng = np.random.default_rng(None if seed is None else [seed, 2])
        self.stop_event = threading.Event()
        self.frozen = False
        self.dropped = False
        self.lock = threading.Lock()
        self.rtde_connections: list[RTDEConnection] = []
        self.input_owners: dict[str, RTDEConnection] = {}
        self.other_sockets: list[socket.socket] = []
        self.control_sockets: list[socket.socket] = []
        """The test harness's control connections: not a client's, so a "drop" leaves them; shut at close."""
        self.threads: list[threading.Thread] = []
        self.listeners: dict[str, socket.socket] = {}
        self.shared_pose = None
        if pose_shm:
            from multiprocessing import resource_tracker

            from tests.fakes.world import SharedPose
            self.shared_pose = SharedPose(pose_shm)
            # attaching registers the block with this process's resource tracker, which would unlink it when
            # this process exits; the creator owns it
            resource_tracker.unregister(self.shared_pose._shm._name, "shared_memory")
        sim.on_network_fault = self._network_fault
        sim.tool_motion_outputs = False

    # -------------------------------------------------------------- setup
    def bind(self) -> None:
        """Bind the fixed ports, then the control port (raises OSError with ``.port`` set on failure)."""
        for name, port in (("rtde", RTDE_PORT), ("dashboard_server", DASHBOARD_SERVER_PORT), ("script", SCRIPT_PORT), ("control", 0)):
            try:
                self.listeners[name] = _listener(self.host, port)
            except OSError as error:
                error.port = port  # type: ignore[attr-defined]
                self.close_listeners()
                raise

    def ready_info(self) -> dict:
        return {"host": self.host, "rtde": RTDE_PORT, "dashboard_server": DASHBOARD_SERVER_PORT, "script": SCRIPT_PORT,
                "control": self.listeners["control"].getsockname()[1], "model": self.sim.model.name,
                "version": ".".join(str(v) for v in self.sim.version), "time_scale": self.sim.time_scale}

    def start(self) -> None:
        for name, handler in (("rtde", self._rtde_client), ("dashboard_server", self._dashboard_server_client),
                              ("script", self._script_client), ("control", self._control_client)):
            self._spawn(f"ur-fake-accept-{name}", self._accept_loop, self.listeners[name], handler, name)
        self._spawn("ur-fake-tick", self._tick_loop)

    def _spawn(self, name: str, target, *args) -> threading.Thread:
        thread = threading.Thread(target=target, args=args, name=name, daemon=True)
        thread.start()
        self.threads.append(thread)
        return thread

    def _accept_loop(self, listener: socket.socket, handler, name: str) -> None:
        while not self.stop_event.is_set():
            try:
                client, _ = listener.accept()
            except OSError:
                return
            if self.dropped and name != "control":
                client.close()  # a dropped link: nothing reaches the controller until `restore`
                continue
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._spawn(f"ur-fake-{name}-client", handler, client)

    # -------------------------------------------------------------- RTDE
    def _rtde_client(self, sock: socket.socket) -> None:
        connection = RTDEConnection(self, sock)
        with self.lock:
            self.rtde_connections.append(connection)
        connection.serve()

    def forget(self, connection: RTDEConnection) -> None:
        with self.lock:
            if connection in self.rtde_connections:
                self.rtde_connections.remove(connection)
            for name in [n for n, owner in self.input_owners.items() if owner is connection]:
                del self.input_owners[name]
            owned = "external_force_torque" in self.input_owners
        with self.sim.lock:
            self.sim.external_ft.owned = owned
        self.update_stream_period()
        self.update_tool_motion_outputs()

    def update_tool_motion_outputs(self) -> None:
        """Tell the simulator whether any client's output recipe needs the tool's speed or accelerometer."""
        with self.lock:
            wanted = any(c.outputs is not None and TOOL_MOTION_OUTPUTS & set(c.outputs.recipe.names)
                         for c in self.rtde_connections)
        with self.sim.lock:
            self.sim.tool_motion_outputs = wanted

    def claim_inputs(self, connection: RTDEConnection, names: list[str]) -> set[str]:
        """Give ``connection`` the input variables ``names``; return those another live connection owns (then
        nothing is claimed). A connection whose peer has already closed (EOF not yet read by its thread) is gone."""
        with self.lock:
            taken = {name for name in names if name in rp.INPUT_TYPES and self.input_owners.get(name) not in
                     (None, connection) and _alive(self.input_owners[name])}
            if not taken:
                for name in names:
                    if name in rp.INPUT_TYPES:
                        self.input_owners[name] = connection
            owned = "external_force_torque" in self.input_owners
        with self.sim.lock:
            self.sim.external_ft.owned = owned
        return taken

    def update_stream_period(self) -> None:
        with self.lock:
            periods = [c.period_s for c in self.rtde_connections if c.streaming]
        with self.sim.lock:
            self.sim.stream_period_s = max(periods) if periods else self.sim.cycle_s

    def _tick_loop(self) -> None:
        """One controller cycle per tick (``sim.cycle_s``). A CB3's state is that of its cycle's start, so its
        ``timestamp`` steps whole 8 ms cycles (more when a tick is late); the e-Series keeps the tick's host time."""
        period, start_s = self.sim.cycle_s, self.sim.start_s
        whole_cycles = period > E_SERIES_CYCLE_S
        next_tick, cycle = time.monotonic(), -1
        while not self.stop_event.is_set():
            now = time.monotonic()
            cycle = max(math.floor((now - start_s) / period), cycle + 1)  # (a wake a rounding error early)
            snap = self.sim.step(start_s + cycle * period if whole_cycles else now)
            connections = []
            if self.shared_pose is not None:
                self.shared_pose.set(snap["flange_pose"], snap["joint_speed_norm"], snap["joint_state"])
            if not self.frozen:
                with self.lock:
                    # the owner of external_force_torque first (its answer is due before the next cycle), then
                    # receive-only clients: a client must never see 'done' on its control connection before its
                    # other connections have the final state
                    feeder = self.input_owners.get("external_force_torque")
                    connections = sorted((c for c in self.rtde_connections if c.streaming),
                                         key=lambda c: (c is not feeder, bool(c.inputs)))
                jittered = False
                for connection in connections:
                    if now >= connection.next_send_s:
                        if connection is not feeder and not jittered and self.send_jitter_s > 0.0:
                            jittered = True  # the rest of this cycle's packages leave a little late
                            time.sleep(self.send_jitter_s * self._jitter_rng.random())  # a fraction of a tick
                        if connection is feeder:
                            connection.pump()  # the inputs that reached the controller before this cycle
                            with self.sim.lock:
                                if self.sim.external_ft.count_cycle(now, snap["fields"]["timestamp"],
                                                                    connection.period_s):
                                    self.sim.external_ft_watchdog_pause()
                        connection.send_data(snap)
                        if connection is feeder:
                            with self.sim.lock:
                                self.sim.external_ft.package_sent(time.monotonic())
                        connection.last_sent_seq = snap["seq"]
                        connection.next_send_s += connection.period_s
                        if connection.next_send_s < now:
                            connection.next_send_s = now + connection.period_s
                published = min((c.last_sent_seq for c in connections), default=snap["seq"])
                with self.sim.lock:
                    self.sim.published_seq = published
            idle = not connections if not self.frozen else True
            if idle and self.sim.motion is None:
                next_tick += IDLE_TICK_S
            else:
                next_tick = start_s + (cycle + 1) * period if whole_cycles else next_tick + period
            delay = next_tick - time.monotonic()
            if delay > 0:
                time.sleep(delay)  # at most IDLE_TICK_S; an Event's wait costs more per tick than the tick's work
            else:
                next_tick = time.monotonic()

    # -------------------------------------------------------------- UR Dashboard Server, script, control
    def _track(self, sock: socket.socket) -> None:
        with self.lock:
            self.other_sockets.append(sock)

    def _untrack(self, sock: socket.socket) -> None:
        with self.lock:
            if sock in self.other_sockets:
                self.other_sockets.remove(sock)
        try:
            sock.close()
        except OSError:
            pass

    def _lines(self, sock: socket.socket):
        buffer = b""
        while True:
            while b"\n" not in buffer:
                chunk = sock.recv(4096)
                if not chunk:
                    return
                buffer += chunk
            line, buffer = buffer.split(b"\n", 1)
            yield line.decode("utf-8", "replace").rstrip("\r")

    def _dashboard_server_client(self, sock: socket.socket) -> None:
        self._track(sock)
        try:
            sock.sendall((GREETING + "\n").encode())
            for line in self._lines(sock):
                if self.frozen:
                    continue
                reply = dashboard_server_reply(self.sim, line)
                sock.sendall((reply + "\n").encode())
                if line.strip().lower() == "quit":
                    break
        except OSError:
            pass
        finally:
            self._untrack(sock)

    def _script_client(self, sock: socket.socket) -> None:
        self._track(sock)
        buffer = b""
        try:
            while True:
                chunk = sock.recv(65536)
                if not chunk:
                    break
                buffer += chunk
                if buffer.endswith(b"\nend\n") or buffer.endswith(b"\nend"):
                    if not self.frozen:
                        self.sim.receive_script(buffer.decode("utf-8", "replace"))
                    buffer = b""
        except OSError:
            pass
        finally:
            if buffer.strip() and not self.frozen:
                self.sim.receive_script(buffer.decode("utf-8", "replace"))
            self._untrack(sock)

    def _control_client(self, sock: socket.socket) -> None:
        with self.lock:
            self.control_sockets.append(sock)
        try:
            for line in self._lines(sock):
                if not line.strip():
                    continue
                try:
                    reply = {"ok": True, **self.control(line)}
                except (ValueError, IndexError, KeyError) as error:
                    reply = {"ok": False, "error": f"{type(error).__name__}: {error}"}
                sock.sendall((json.dumps(reply) + "\n").encode())
        except OSError:
            pass
        finally:
            with self.lock:
                if sock in self.control_sockets:
                    self.control_sockets.remove(sock)
            sock.close()

    def control(self, line: str) -> dict:
        """Execute one control-port command (see the module docstring)."""
        words = line.split()
        command = words[0].lower()
        sim = self.sim
        if command == "ping":
            return {}
        if command == "clock":
            now = time.monotonic()
            return {"host_s": now, "controller_s": sim.controller_time_s(now), "start_host_s": sim.start_s,
                    "clock_rate_error": sim.clock_rate_error, "send_jitter_s": self.send_jitter_s}
        if command == "state":
            return {"state": sim.state_view(), "frozen": self.frozen, "dropped": self.dropped}
        if command == "commands":
            with sim.lock:
                return {"commands": list(sim.commands)}
        if command == "events":
            with sim.lock:
                return {"events": list(sim.events)}
        if command == "external_ft":
            with sim.lock:
                return {"external_ft": {**sim.external_ft.summary(), "payload": float(sim.payload_kg),
                                        "payload_cog": sim.payload_cog.tolist()}}
        if command == "external_ft_records":
            with sim.lock:
                return sim.external_ft.records()
        if command == "clear_commands":
            with sim.lock:
                sim.commands.clear()
            return {}
        if command == "fault":
            kind = words[1]
            if kind not in FAULT_KINDS:
                raise ValueError(f"unknown fault {kind!r}; known: {', '.join(FAULT_KINDS)}")
            fault = Fault(kind)
            rest = words[2:]
            if rest:
                fault.trigger = rest[0]
                if fault.trigger not in ("now", "after", "move_after", "move_fraction"):
                    raise ValueError(f"unknown trigger {fault.trigger!r}")
                if fault.trigger != "now":
                    fault.value = float(rest[1])
                if len(rest) >= 4 and rest[2] == "move":
                    fault.move = int(rest[3])
            sim.inject(fault)
            return {"fault": {"kind": fault.kind, "trigger": fault.trigger, "value": fault.value, "move": fault.move}}
        if command == "clear_faults":
            with sim.lock:
                sim.faults.clear()
            return {}
        if command == "release_estop":
            sim.release_emergency_stop()
            return {}
        if command == "restore":
            self.frozen = self.dropped = False
            return {}
        if command == "set":
            what, values = words[1], [float(v) for v in words[2:]]
            with sim.lock:
                if what == "time_scale":
                    sim.time_scale = values[0]
                elif what == "q":
                    if len(values) != 6:
                        raise ValueError("set q needs 6 joint angles (rad)")
                    sim.q = np.array(values)
                elif what == "external_ft_watchdog":
                    if not values or values[0] <= 0:
                        raise ValueError("set external_ft_watchdog needs a period > 0 (s)")
                    sim.external_ft.watchdog_period_s = values[0]
                elif what == "external_ft_axes":
                    if len(values) != 6 or any(abs(v) != 1.0 for v in values):
                        raise ValueError("set external_ft_axes needs 6 signs (1 or -1)")
                    sim.external_ft.axis_signs = np.array(values)
                elif what == "tcp_offset":
                    if len(values) != 6:
                        raise ValueError("set tcp_offset needs x y z rx ry rz")
                    sim.tcp_offset = np.array(values)
                else:
                    raise ValueError(f"cannot set {what!r}")
            return {}
        if command == "jog":
            values = [float(v) for v in words[1:]]
            if len(values) != 8:
                raise ValueError("jog needs q0 .. q5 (rad), speed (rad/s) and acceleration (rad/s²)")
            with sim.lock:
                accepted = sim._start_move("movej", np.array(values[:6]), values[6], values[7], True, source="pendant")
                scale = sim.motion_time_scale()
                duration_s = sim.motion.duration_s / scale if accepted and scale > 0 else 0.0
            return {"accepted": accepted, "duration_s": duration_s}
        if command == "halt":  # another client's stopj (a program on the pendant, a second RTDE client): the
            with sim.lock:      # move ends where the arm is, the control program keeps running
                sim._halt_motion()
            return {}
        if command == "quit":
            threading.Timer(0.05, self.stop_event.set).start()
            return {}
        raise ValueError(f"unknown control command {command!r}")

    # -------------------------------------------------------------- faults and shutdown
    def _network_fault(self, kind: str) -> None:
        if kind == "freeze":
            self.frozen = True
            return
        self.dropped = True
        self.close_clients()

    def close_clients(self) -> None:
        with self.lock:
            connections, others = list(self.rtde_connections), list(self.other_sockets)
        for connection in connections:
            connection.close()
        for sock in others:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def close_listeners(self) -> None:
        for listener in self.listeners.values():
            try:
                listener.shutdown(socket.SHUT_RDWR)  # wakes the thread blocked in accept()
            except OSError:
                pass
            try:
                listener.close()
            except OSError:
                pass

    def close(self) -> None:
        self.stop_event.set()
        self.close_listeners()
        self.close_clients()
        with self.lock:
            control_sockets = list(self.control_sockets)
        for sock in control_sockets:  # wakes its thread's recv: the parent closes its end only once we exited
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        for thread in self.threads[:6]:
            thread.join(timeout=1.0)
        if self.shared_pose is not None:
            self.shared_pose.close()


def parse_version(text: str) -> tuple[int, int, int, int]:
    parts = [int(p) for p in text.split(".")]
    if not 2 <= len(parts) <= 4:
        raise argparse.ArgumentTypeError(f"version {text!r}: expected MAJOR.MINOR[.BUGFIX[.BUILD]]")
    return tuple(parts + [0] * (4 - len(parts)))  # type: ignore[return-value]


CB3_MODELS = frozenset({"UR3", "UR5", "UR10"})
"""Arms of the CB3 generation: they run PolyScope 3 (the others 5 or X; docs/protocols-ur.md)."""


def default_version(model: str) -> tuple[int, int, int, int]:
    """The software a real controller of ``model`` runs: PolyScope 3.15 on a CB3 arm, 5.11 on the others (the
    Dashboard Server names UR5 and UR5e alike; the version tells them apart)."""
    return (3, 15, 7, 106331) if ur_model(model).name in CB3_MODELS else (5, 11, 1, 108318)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m tests.fakes.ur_controller", description=__doc__.split("\n\n")[0])
    parser.add_argument("--host", required=True, help="loopback address to bind, e.g. 127.0.0.2")
    parser.add_argument("--model", default="UR5e", help="UR model (default UR5e)")
    parser.add_argument("--time-scale", type=float, default=1.0, help="0 = instant moves, 1 = real time")
    parser.add_argument("--pose-shm", default=None, help="SharedPose block to publish the flange pose into")
    parser.add_argument("--initial-q", type=float, nargs=6, default=None, metavar="Q", help="initial joint angles, rad")
    parser.add_argument("--mount", default="floor", help="floor, wall, ceiling, tilted:ALPHA,BETA or gravity:X,Y,Z")
    parser.add_argument("--version", type=parse_version, default=None,
                        help="controller version (default: PolyScope 3.15 for a CB3 model, 5.11 for the others)")
    parser.add_argument("--serial-number", default="20235500123")
    parser.add_argument("--encoder-noise-rad", type=float, default=0.0,
                        help=f"1σ jitter of the reported joint angles, rad (default 0: exact; a real UR5e "
                             f"{ENCODER_NOISE_RAD:g})")
    parser.add_argument("--seed", type=int, default=None, help="seed of the encoder jitter")
    parser.add_argument("--servo-lag-s", type=float, default=0.0, metavar="S",
                        help=f"the physical arm (actual_q, actual_qd, the tool's physics) follows the target S s "
                             f"late (default 0: exact; the simulated cell {SERVO_LAG_S:g})")
    parser.add_argument("--clock-rate-error", type=float, default=0.0, metavar="E",
                        help="the controller's clock rate against the host's, minus one (e.g. -30e-6): RTDE "
                             "timestamp runs (1 + E) s per host second (default 0)")
    parser.add_argument("--send-jitter-s", type=float, default=0.0, metavar="S",
                        help="receive-only clients' packages leave a random 0..S s after their cycle (default 0)")
    parser.add_argument("--realtime-priority", type=int, default=0, metavar="N",
                        help="run the controller's threads at SCHED_FIFO N, as a real controller's real-time cycle "
                             "(0: normal scheduling; refused without CAP_SYS_NICE, then normal)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    version = args.version or default_version(args.model)
    sim = URSimulator(ur_model(args.model), time_scale=args.time_scale, version=version,
                      initial_q=np.array(args.initial_q) if args.initial_q else None, mount=args.mount,
                      serial_number=args.serial_number, encoder_noise_rad=args.encoder_noise_rad, seed=args.seed,
                      clock_rate_error=args.clock_rate_error, servo_lag_s=args.servo_lag_s)
    server = ControllerServer(sim, args.host, args.pose_shm, send_jitter_s=args.send_jitter_s, seed=args.seed)
    try:
        server.bind()
    except OSError as error:
        info = {"host": args.host, "port": getattr(error, "port", None), "errno": error.errno,
                "in_use": error.errno == errno.EADDRINUSE, "error": str(error)}
        print("BIND_ERROR " + json.dumps(info), flush=True)
        return BIND_ERROR_EXIT
    signal.signal(signal.SIGTERM, lambda *_: server.stop_event.set())
    signal.signal(signal.SIGINT, lambda *_: server.stop_event.set())
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    # a real controller's cycle has no collector pauses: the setup's objects out of the cyclic collector's reach
    # (a full collection walking them holds the interpreter for tens of ms, a dozen missed cycles)
    gc.freeze()
    if args.realtime_priority > 0:  # before the threads start: each inherits its creator's policy
        from procedures.realtime import ask_realtime

        ask_realtime(args.realtime_priority)
    server.start()
    print("READY " + json.dumps(server.ready_info()), flush=True)
    parent = os.getppid()
    try:
        while not server.stop_event.wait(0.5):
            if os.getppid() != parent:  # the test process died: do not linger as an orphan
                break
    finally:
        server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
