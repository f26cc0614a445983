"""A fake ATI Net F/T box: RDT over UDP, the TCP command port and the HTTP configuration pages, on real sockets.

One :class:`FakeNetFT` (a :class:`tests.fakes.netft_box.NetFTBox`: the box's state, stream and fault knobs; wire
format in tests/fakes/netft_protocol.py; facts in docs/protocols-ati.md) binds three real sockets on a configurable
host (port 0 in tests):

- **RDT (UDP)**: 8-byte commands ``>HHI`` (header 0x1234, command, sample count), plus the 14-byte extended form.
  Records (36 bytes, ``>III6i``) go out **from the same socket** to the address of the latest start command.
  0x0000 stops; 0x0001/0x0002/0x0004 stream one record per datagram; 0x0003 streams ``comrdtbsiz`` records per
  datagram; count N > 0 sends exactly N records, 0 streams until stopped. Every start resets ``rdt_sequence`` to 1;
  ``ft_sequence`` is a power-up counter, +round(7000 / rate) per record, never reset by a start. 0x0042 biases
  (later records carry raw − bias, the stream goes on); 0x0041 clears the monitor latch.
- **TCP**: whole 20-byte commands, many per connection: READFT (16-byte reply, sysCommands bias / clear latch),
  READCALINFO (24 bytes: unit codes, counts per unit, scale factors), WRITETRANSFORM / WRITETHRESHOLD (4 bytes).
- **HTTP**: ``/netftapi2.xml`` and ``/netftcalapi.xml`` (query ignored) and the CGI pages ``comm.cgi``,
  ``setting.cgi``, ``config.cgi``, ``moncon.cgi`` (``k=v&k=v``), which update what the XML and RDT show.

Records are paced at ``comrdtrate`` (quantised to 7000/n Hz, rounded up) on the box's own sample clock
(``clock_rate_error`` off the host's; ``ft_sequence`` counts its samples) and sent as due or, with
``burst_interval_s``, in bursts with jitter; a sender that falls behind by more than ``max_backlog_s`` skips samples
(tests/fakes/netft_box.py, docs/simulation.md "Simulated clocks"). ``max_rate_hz`` above 7000 lets a benchmark run the fake faster than a
real box (an unfaithful extension, off by default). The wrench comes from a
:class:`tests.fakes.world.SensorPhysics`, converted to the configured units and counts:
``counts = round(value_in_device_units × counts_per_unit)``, torque possibly in N-mm.

Fault knobs (thread-safe, applied to the next records): :meth:`drop`, :meth:`duplicate`, :meth:`reorder`,
:meth:`send_truncated`, :meth:`send_garbage`, :meth:`go_silent` / :meth:`resume` (the link, not the box, goes
quiet), :meth:`power_off` / :meth:`power_on`, :meth:`restart`,
:meth:`stall_ft_sequence`, :meth:`set_status` / :meth:`saturate` / :meth:`latch`, :meth:`set_axia_status`.
Everything received is recorded (:attr:`commands`, :meth:`wait_for_command`), everything sent too
(:meth:`sent_records`). Threads are named, joined in
:meth:`close`, and their errors re-raised there.

Run alone: ``python -m tests.fakes.netft --host 127.0.0.1 --rdt-port 0 [--pose-shm NAME] [--model UR5e]
[--truth-json JSON] [--clock-rate-error E] [--burst-interval-s S] [--burst-jitter-s S] [--max-backlog-s S]`` prints
one JSON line with the bound ports and URL, then serves until stdin closes (or SIGTERM / SIGINT). A ``stats`` line
on stdin prints the counters as one JSON line. tests/fakes/netft_process.py starts it so for a simulated cell whose
sensor must keep its pace whatever the process that reads it does (its own interpreter lock).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import select
import selectors
import signal
import socket
import stat
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, HTTPServer
from urllib.parse import parse_qsl, urlsplit

from tests.fakes.netft_box import DEFAULT_WAIT_S, POLL_S, NetFTBox  # noqa: F401 (DEFAULT_WAIT_S re-exported)
from tests.fakes.netft_protocol import (  # noqa: F401 (re-exported for tests)
    INTERNAL_RATE_HZ,
    RECORD_DTYPE,
    RECORD_SIZE,
    TCP_COMMAND_SIZE,
    ReceivedCommand,
    quantise_rate_hz,
)

CLOSE_JOIN_TIMEOUT_S = 5.0


class FakeNetFT(NetFTBox):
    """A simulated ATI Net F/T on loopback (see the module docstring).

    Args:
        physics: a :class:`tests.fakes.world.SensorPhysics` (``sample(n)`` → (n, 6) N and N·m).
        host: address to bind all three sockets on. rdt_port, tcp_port, http_port: 0 picks free ports.
        serve_tcp: False serves no TCP port. send_from_other_socket: records leave from another UDP port (a
            box that does not answer from its RDT port; connected clients drop them).
        box: the box's settings (:class:`tests.fakes.netft_box.NetFTBox`: rate_hz, units, counts per unit, …).
    """

    def __init__(self, physics, host: str = "127.0.0.1", rdt_port: int = 0, tcp_port: int = 0, http_port: int = 0,
                 serve_tcp: bool = True, send_from_other_socket: bool = False, realtime_priority: int = 0,
                 **box) -> None:
        super().__init__(physics, **box)
        self.host = host
        self.realtime_priority = realtime_priority
        """SCHED_FIFO priority of the sending (RDT) thread, 0: normal (a real box sends whatever the host does)."""
        self._requested_ports = (rdt_port, tcp_port, http_port)
        self.serve_tcp = serve_tcp
        self.send_from_other_socket = send_from_other_socket
        self._udp: socket.socket | None = None
        self._udp_out: socket.socket | None = None
        self._tcp: socket.socket | None = None
        self._http: HTTPServer | None = None
        self._threads: list[threading.Thread] = []
        self._errors: list[BaseException] = []
        self._stop = threading.Event()
        self.rdt_port = self.tcp_port = self.http_port = 0
        self._started = self._closed = False

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> "FakeNetFT":
        """Bind the sockets and start the threads; return self."""
        if self._started:
            return self
        rdt_port, tcp_port, http_port = self._requested_ports
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        self._udp = socket.socket(family, socket.SOCK_DGRAM)
        self._udp.bind((self.host, rdt_port))
        self._udp.setblocking(False)
        try:
            self._udp.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
        except OSError:
            pass
        self.rdt_port = self._udp.getsockname()[1]
        if self.send_from_other_socket:  # a misbehaving box: records come from another port (clients drop them)
            self._udp_out = socket.socket(family, socket.SOCK_DGRAM)
            self._udp_out.bind((self.host, 0))
        if self.serve_tcp:
            self._tcp = socket.socket(family, socket.SOCK_STREAM)
            self._tcp.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._tcp.bind((self.host, tcp_port))
            self._tcp.listen(8)
            self._tcp.setblocking(False)
            self.tcp_port = self._tcp.getsockname()[1]
        self._http = _make_http_server(self, (self.host, http_port), family)
        self.http_port = self._http.server_address[1]
        self._started = True
        self._spawn("rdt", self._rdt_loop, self.realtime_priority)
        if self._tcp is not None:
            self._spawn("tcp", self._tcp_loop)
        self._spawn("http", lambda: self._http.serve_forever(poll_interval=POLL_S))
        return self

    def _spawn(self, name: str, target, realtime_priority: int = 0) -> None:
        def run() -> None:
            if realtime_priority > 0:
                from procedures.realtime import ask_realtime

                ask_realtime(realtime_priority)
            try:
                target()
            except BaseException as error:  # re-raised in close()
                self._errors.append(error)
        thread = threading.Thread(target=run, name=f"FakeNetFT-{name}-{self.rdt_port}", daemon=False)
        self._threads.append(thread)
        thread.start()

    def close(self) -> None:
        """Stop the threads, join them, close the sockets; re-raise the first thread error. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._http is not None and self._started:
            self._http.shutdown()
        for thread in self._threads:
            thread.join(CLOSE_JOIN_TIMEOUT_S)
        alive = [t.name for t in self._threads if t.is_alive()]
        for sock in (self._udp, self._udp_out, self._tcp):
            if sock is not None:
                sock.close()
        if self._http is not None:
            self._http.server_close()
        if self._errors:
            raise RuntimeError(f"FakeNetFT thread failed: {self._errors[0]!r}") from self._errors[0]
        if alive:
            raise RuntimeError(f"FakeNetFT threads did not stop within {CLOSE_JOIN_TIMEOUT_S} s: {alive}")

    def __enter__(self) -> "FakeNetFT":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def url(self) -> str:
        """The ``netft://`` URL of this fake for :class:`drivers.netft.NetFTSensor`."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"netft://{host}:{self.rdt_port}?tcp_port={self.tcp_port}&http_port={self.http_port}"

    # ------------------------------------------------------------------ RDT

    def _rdt_loop(self) -> None:
        buffer = bytearray(2048)
        while not self._stop.is_set():
            timeout = self.next_send_in_s(time.monotonic())
            readable, _, _ = select.select([self._udp], [], [], min(timeout, POLL_S))
            if readable:
                self._drain_commands(buffer)
            self._send_due()

    def _drain_commands(self, buffer: bytearray) -> None:
        while True:
            try:
                size, address = self._udp.recvfrom_into(buffer)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # e.g. ICMP port unreachable from a client that went away
                continue
            heard_at = time.monotonic()  # one instant: every sample up to it is sent, the new stream starts after
            self._send_due(flush=True, now=heard_at)  # what the box sampled before it heard the command goes first
            if self.handle_rdt(bytes(buffer[:size]), address, heard_at):
                self._send_due(first=True)

    def _send_due(self, first: bool = False, flush: bool = False, now: float | None = None) -> None:
        datagrams, target = self.due_datagrams(time.monotonic() if now is None else now, first, flush)
        if not datagrams:
            return
        failed = []
        sender = self._udp_out or self._udp
        for datagram in datagrams:
            try:
                sender.sendto(datagram, target)
            except OSError:
                failed.append(datagram)
        if failed:
            self.send_failed(failed)

    # ------------------------------------------------------------------ TCP 49151

    def _tcp_loop(self) -> None:
        selector = selectors.DefaultSelector()
        selector.register(self._tcp, selectors.EVENT_READ, None)
        buffers: dict[socket.socket, bytearray] = {}
        try:
            while not self._stop.is_set():
                for key, _ in selector.select(POLL_S):
                    if key.data is None:
                        try:
                            connection, _ = self._tcp.accept()
                        except OSError:
                            continue
                        connection.setblocking(False)
                        buffers[connection] = bytearray()
                        selector.register(connection, selectors.EVENT_READ, "client")
                        continue
                    connection = key.fileobj
                    try:
                        chunk = connection.recv(4096)
                    except (BlockingIOError, InterruptedError):
                        continue
                    except OSError:
                        chunk = b""
                    if not chunk:
                        selector.unregister(connection)
                        connection.close()
                        buffers.pop(connection, None)
                        continue
                    pending = buffers[connection]
                    pending += chunk
                    while len(pending) >= TCP_COMMAND_SIZE:
                        command = bytes(pending[:TCP_COMMAND_SIZE])
                        del pending[:TCP_COMMAND_SIZE]
                        reply = self.tcp_reply(command, connection.getpeername())
                        if reply:
                            try:
                                connection.sendall(reply)
                            except OSError:
                                break
        finally:
            for connection in list(buffers):
                connection.close()
            selector.close()


def _make_http_server(fake: FakeNetFT, address: tuple, family: int) -> HTTPServer:
    class Handler(BaseHTTPRequestHandler):
        server_version = "FakeNetFT/1.0"

        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            parts = urlsplit(self.path)
            params = dict(parse_qsl(parts.query, keep_blank_values=True))
            fake._record(ReceivedCommand("http", parts.path, 0, self.client_address, time.monotonic(),
                                         self.path.encode(), params))
            if parts.path == "/netftapi2.xml":
                self._reply(200, fake.netftapi2_xml(), "text/xml")
            elif parts.path == "/netftcalapi.xml" and fake.serve_calibration_page:
                self._reply(200, fake.netftcalapi_xml(), "text/xml")
            elif parts.path in ("/comm.cgi", "/setting.cgi", "/config.cgi", "/moncon.cgi"):
                fake.apply_cgi(parts.path, params)
                self._reply(200, "<html><body>OK</body></html>", "text/html")
            else:
                self._reply(404, "not found", "text/plain")

        def _reply(self, code: int, body: str, content_type: str) -> None:
            data = body.encode()
            self.send_response(code)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(data)))
            self.send_header("Connection", "close")
            self.end_headers()
            self.wfile.write(data)

        def log_message(self, format: str, *args) -> None:  # noqa: A002 (http.server's signature)
            pass

    class Server(HTTPServer):
        address_family = family
        allow_reuse_address = True

    return Server(address, Handler)

# ------------------------------------------------------------------------ running alone

def _watch_stdin() -> bool:
    """Whether stdin is a pipe or terminal that can tell us to stop (not /dev/null or closed)."""
    try:
        mode = os.fstat(0).st_mode
    except OSError:
        return False
    return stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode) or os.isatty(0) or stat.S_ISREG(mode)


def _truth_fields(values: dict) -> dict:
    """CellTruth keyword arguments from JSON (lists back to the tuples the frozen dataclass holds)."""
    def as_tuple(value):
        return tuple(as_tuple(v) for v in value) if isinstance(value, list) else value

    return {key: as_tuple(value) for key, value in values.items()}


def main(argv: list[str] | None = None) -> int:
    """Run one fake Net F/T until stdin closes (or SIGTERM / SIGINT); print its ports as one JSON line."""
    parser = argparse.ArgumentParser(description="A fake ATI Net F/T (RDT UDP, TCP, HTTP) on loopback.")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--rdt-port", type=int, default=0)
    parser.add_argument("--tcp-port", type=int, default=0)
    parser.add_argument("--http-port", type=int, default=0)
    parser.add_argument("--rate-hz", type=float, default=INTERNAL_RATE_HZ, help="comrdtrate, Hz (default %(default)s)")
    parser.add_argument("--max-rate-hz", type=float, default=INTERNAL_RATE_HZ,
                        help="allow rates above 7000 Hz (benchmarks only; a real box cannot)")
    parser.add_argument("--buffer-size", type=int, default=1, help="comrdtbsiz, records per buffered datagram")
    parser.add_argument("--force-unit", default="N")
    parser.add_argument("--torque-unit", default="Nm")
    parser.add_argument("--counts-per-force", type=int, default=1_000_000)
    parser.add_argument("--counts-per-torque", type=int, default=500_000)
    parser.add_argument("--serial", default="FT12345")
    parser.add_argument("--pose-shm", help="read the flange pose from this tests.fakes.world.SharedPose")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--model", help="UR model whose motion the physics follows (with --pose-shm: the tool's "
                        "inertia while the arm moves)")
    parser.add_argument("--truth-json", help="tests.fakes.world.CellTruth fields as a JSON object (default: its defaults)")
    parser.add_argument("--clock-rate-error", type=float, default=0.0, metavar="E",
                        help="the box's sample clock rate against the host's, minus one (e.g. 150e-6)")
    parser.add_argument("--burst-interval-s", type=float, default=0.0, help="mean time between bursts, s (0: none)")
    parser.add_argument("--burst-jitter-s", type=float, default=0.0, help="random extra delay of a burst, s")
    parser.add_argument("--max-backlog-s", type=float, default=None,
                        help="skip records due longer ago than this, s (default: a 4096-record backlog)")
    parser.add_argument("--realtime-priority", type=int, default=0, metavar="N",
                        help="SCHED_FIFO priority of the sending thread (0: normal scheduling)")
    parser.add_argument("--sent-log-limit", type=int, default=0,
                        help="records of what was sent to keep in memory (default 0: a long-running fake logs none)")
    args = parser.parse_args(argv)

    from tests.fakes.world import CellTruth, SensorPhysics, SettablePose, SharedPose

    shared = SharedPose(args.pose_shm) if args.pose_shm else None
    if shared is not None:
        # The block belongs to the process that created it: keep this process's resource tracker (Python < 3.13,
        # bpo-39959) from unlinking it when this process exits.
        from multiprocessing import resource_tracker

        try:
            resource_tracker.unregister("/" + shared.name.lstrip("/"), "shared_memory")
        except Exception:  # noqa: BLE001 (best effort; only matters for the owner's clean-up)
            pass
    truth = CellTruth(**_truth_fields(json.loads(args.truth_json))) if args.truth_json else CellTruth()
    robot = None
    if args.model:
        from ftacq.kinematics import ur_model

        robot = ur_model(args.model)
    physics = SensorPhysics(truth, shared if shared is not None else SettablePose(), seed=args.seed, robot=robot,
                            rate_hz=args.rate_hz)
    fake = FakeNetFT(physics, host=args.host, rdt_port=args.rdt_port, tcp_port=args.tcp_port,
                     http_port=args.http_port, rate_hz=args.rate_hz, buffer_size=args.buffer_size,
                     force_unit=args.force_unit, torque_unit=args.torque_unit,
                     counts_per_force=args.counts_per_force, counts_per_torque=args.counts_per_torque,
                     serial=args.serial, max_rate_hz=args.max_rate_hz, seed=args.seed,
                     sent_log_limit=args.sent_log_limit, clock_rate_error=args.clock_rate_error,
                     burst_interval_s=args.burst_interval_s, burst_jitter_s=args.burst_jitter_s,
                     max_backlog_s=args.max_backlog_s, realtime_priority=args.realtime_priority)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    gc.freeze()  # a real box streams without collector pauses: the setup's objects out of the collector's reach
    fake.start()
    try:
        print(json.dumps({"host": args.host, "rdt_port": fake.rdt_port, "tcp_port": fake.tcp_port,
                          "http_port": fake.http_port, "url": fake.url, "pid": os.getpid()}), flush=True)
        if _watch_stdin():
            while not stop.is_set():
                ready, _, _ = select.select([sys.stdin], [], [], POLL_S)
                if not ready:
                    continue
                line = sys.stdin.readline()
                if not line:
                    break
                if line.strip() == "stats":
                    print(json.dumps(fake.stats()), flush=True)
                elif line.startswith("rate "):
                    print(json.dumps({"rate_hz": fake.set_rate(float(line.split()[1]))}), flush=True)
                elif line.startswith("buffer "):
                    print(json.dumps({"buffer_size": fake.set_buffer_size(int(line.split()[1]))}), flush=True)
        else:
            while not stop.wait(POLL_S):
                pass
    finally:
        fake.close()
        if shared is not None:
            shared.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
