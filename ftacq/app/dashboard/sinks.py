"""Where a recording goes: the viewer flags (``--spawn``, ``--connect``, ``--serve``, ``--save``) and the viewer
processes ftacq starts and stops.

Without a flag: spawn a native viewer when a display is available, else save an .rrd under ``runs/``. Every
process ftacq starts is bound to 127.0.0.1 (Rerun's own ``spawn`` and ``serve_web_viewer`` listen on every
interface) and has a start-up deadline. This module does not import ``rerun`` until a recording is opened, so
adding the flags to a parser costs nothing.

A saved recording is written to a hidden temporary file beside the target and renamed when it is closed; a run
that recorded nothing (it failed before its first sample, e.g. the robot was unreachable) leaves no file, and
"view it with …" is said only of a file that exists (:func:`close_recording`).
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import socket
import subprocess
import sys
import time
import webbrowser
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Callable
from urllib.parse import quote

from ftacq.app.hints import command
from ftacq.errors import DeviceConnectionError

log = logging.getLogger(__name__)

APP_ID = "ftacq"
"""Rerun application id of every ftacq recording (the viewer keys blueprints by it)."""
RECORDING_FLUSH_TIMEOUT_S = 5.0
"""Longest wait for a recording's sinks to take what was logged (closing, flushing)."""
DEFAULT_VIEWER_PORT = 9876
DEFAULT_WEB_PORT = 9090
LOCALHOST = "127.0.0.1"
VIEWER_START_TIMEOUT_S = 10.0


def add_sink_args(parser: argparse.ArgumentParser) -> None:
    """Add the viewer flags (one of --spawn, --connect, --serve, --save) as Rerun's example scripts do.

    Without a flag: spawn a native viewer when a display is available, else save an .rrd under ``runs/``.
    """
    group = parser.add_argument_group("Rerun viewer (pick one; default: --spawn with a display, else --save)")
    sinks = group.add_mutually_exclusive_group()
    sinks.add_argument("--spawn", action="store_true",
                       help=f"start a native Rerun viewer bound to {LOCALHOST} (or reuse one on --viewer-port)")
    sinks.add_argument("--connect", nargs="?", const=f"rerun+http://{LOCALHOST}:{DEFAULT_VIEWER_PORT}/proxy",
                       metavar="URL", help="stream to a running viewer (default URL rerun+http://127.0.0.1:9876/proxy)")
    sinks.add_argument("--serve", action="store_true",
                       help=f"serve the web viewer on http://{LOCALHOST}:WEB_PORT and the data on gRPC "
                            "(--viewer-port), both localhost only; keeps serving after the run until Ctrl-C")
    sinks.add_argument("--save", metavar="FILE.rrd", type=Path, help="write the recording to an .rrd file")
    group.add_argument("--viewer-port", type=int, default=DEFAULT_VIEWER_PORT, metavar="PORT",
                       help="gRPC port of the spawned viewer or of the --serve server (default %(default)s)")
    group.add_argument("--web-port", type=int, default=DEFAULT_WEB_PORT, metavar="PORT",
                       help="HTTP port of the --serve web viewer (default %(default)s)")
    group.add_argument("--no-browser", action="store_true", help="with --serve: do not open a browser")


def has_display() -> bool:
    """Return True when a native viewer window can open (Linux needs $DISPLAY or $WAYLAND_DISPLAY)."""
    if sys.platform.startswith("linux") or sys.platform.startswith("freebsd"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def default_rrd_path(app_id: str = APP_ID, runs_dir: Path = Path("runs")) -> Path:
    """Return ``runs/<app_id>-YYYYmmdd-HHMMSS.rrd`` (local time)."""
    return runs_dir / f"{app_id}-{datetime.now():%Y%m%d-%H%M%S}.rrd"


@dataclass(frozen=True)
class SinkChoice:
    """Where the recording goes: ``kind`` is "spawn", "connect", "serve" or "save"; ``target`` the URL or path."""

    kind: str
    target: str
    message: str
    web_url: str = ""


def _port_open(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.settimeout(0.2)
        return probe.connect_ex((host, port)) == 0


def _rerun_executable() -> str:
    executable = Path(sys.executable).with_name("rerun")
    return str(executable) if executable.exists() else "rerun"


def _wait_for_port(port: int, process: subprocess.Popen | None = None) -> bool:
    """Wait until 127.0.0.1:``port`` accepts connections (at most VIEWER_START_TIMEOUT_S); False if it never does."""
    deadline = time.monotonic() + VIEWER_START_TIMEOUT_S
    while time.monotonic() < deadline:
        if _port_open(LOCALHOST, port):
            return True
        if process is not None and process.poll() is not None:
            return False
        time.sleep(0.05)
    return False


def _spawn_viewer(port: int) -> None:
    """Start ``rerun --bind 127.0.0.1 --port PORT`` detached (unless one already listens there) and wait for it.

    Detached like ``rerun.spawn``: the window stays open after ftacq exits. Bound to localhost, unlike
    ``rerun.spawn`` (whose viewer listens on every interface).
    """
    if _port_open(LOCALHOST, port):
        return
    process = subprocess.Popen([_rerun_executable(), "--bind", LOCALHOST, "--port", str(port)],
                               stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                               start_new_session=True, env={**os.environ, "RERUN_APP_ONLY": "true"})
    if not _wait_for_port(port, process):
        log.warning("the Rerun viewer did not open port %d within %.0f s; streaming anyway", port,
                    VIEWER_START_TIMEOUT_S)


_WEB_SERVERS: dict[int, tuple[subprocess.Popen, str]] = {}
"""Web-viewer servers started by :func:`open_recording` (``--serve``), keyed by ``id(recording)``; stopped by
:func:`close_recording`."""


def _stop_process_group(process: subprocess.Popen, timeout_s: float = RECORDING_FLUSH_TIMEOUT_S) -> None:
    """Stop a process started with ``start_new_session=True`` and its children (``.venv/bin/rerun`` is a Python
    wrapper around the ``rerun_cli`` binary: terminating only the wrapper would leave the server running)."""
    def signal_group(signum: int) -> None:
        try:
            os.killpg(process.pid, signum)
        except (AttributeError, ProcessLookupError, PermissionError):  # no process groups, or already gone
            if process.poll() is None:
                process.send_signal(signum)

    signal_group(signal.SIGTERM)
    try:
        process.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        signal_group(getattr(signal, "SIGKILL", signal.SIGTERM))
        process.wait()
    if process.stdin is not None:
        process.stdin.close()


_EXIT_WITH_PARENT = ("sh", "-c", 'exec 3<&0; "$@" 3<&- & child=$!; { read -r _ <&3; kill -TERM 0; } & '
                     'wait "$child"; kill -TERM 0', "ftacq-viewer-guard")
"""Runs a command in its process group and ends the group when ftacq dies, however (even SIGKILL): ftacq holds
the write end of the guard's stdin, the kernel closes it with the process, and the guard's read then returns."""


def _serve_web(grpc_port: int, web_port: int):
    """Start ``rerun --serve-web`` bound to 127.0.0.1 (gRPC on ``grpc_port``, HTTP on ``web_port``); return it.

    Rerun's in-process ``serve_web_viewer`` listens on every interface; the CLI honours ``--bind``. Raises
    DeviceConnectionError when the server does not come up (e.g. a port is taken).
    """
    process = subprocess.Popen(
        [*_EXIT_WITH_PARENT, _rerun_executable(), "--serve-web", "--bind", LOCALHOST, "--port", str(grpc_port),
         "--web-viewer-port", str(web_port)],
        stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,  # stdin: see _EXIT_WITH_PARENT
        start_new_session=True,  # Ctrl-C stops ftacq first; close_recording then stops the server
        env={**os.environ, "RERUN_APP_ONLY": "true"})
    if not (_wait_for_port(grpc_port, process) and _wait_for_port(web_port, process)):
        _stop_process_group(process)
        raise DeviceConnectionError(f"rerun --serve-web did not start on 127.0.0.1 ports {grpc_port} (gRPC) and "
                                    f"{web_port} (HTTP) within {VIEWER_START_TIMEOUT_S:.0f} s: are they taken? "
                                    "Pick others with --viewer-port / --web-port")
    return process


_SAVES: dict[int, tuple[Path, Path, Callable[[str], None]]] = {}
"""Recordings being saved by :func:`open_recording`, keyed by ``id(recording)``: (temporary file, target, announce)."""
_ATTACHED: dict[int, tuple[Callable[[], None], Callable[[], bool]]] = {}
"""What a :class:`~ftacq.app.dashboard.recorder.Dashboard` attached to a recording (:func:`attach`): a flush of
the columns it still holds, and whether it recorded anything."""


def attach(recording, flush: Callable[[], None], recorded: Callable[[], bool]) -> None:
    """Have :func:`close_recording` call ``flush`` first (send what the caller still holds) and ask ``recorded``
    whether a saved file is worth keeping (False: the file is not written)."""
    _ATTACHED[id(recording)] = (flush, recorded)


def is_saved(recording) -> bool:
    """Return True when ``recording`` was opened by :func:`open_recording` to be saved to a file."""
    return id(recording) in _SAVES


def open_recording(args: argparse.Namespace, app_id: str = APP_ID, *,
                   announce: Callable[[str], None] | None = None):
    """Return a new :class:`rerun.RecordingStream` connected to the sink the flags of :func:`add_sink_args` chose.

    ``announce`` receives one line telling the user where the data goes (default: print to stderr); for a saved
    file, a second line from :func:`close_recording` says how to view it. The layout is sent by :class:`~ftacq.app.dashboard.recorder.Dashboard`; the caller owns the stream and ends with
    :func:`close_recording`.
    """
    import rerun as rr  # here, not at the top: see the package docstring

    announce = announce or (lambda line: print(line, file=sys.stderr))
    recording = rr.RecordingStream(app_id, recording_id=None)
    choice = _choose_sink(args, app_id)
    if choice.kind == "save":
        path = Path(choice.target)
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f".{path.name}.partial-{os.getpid()}")
        recording.save(partial)
        _SAVES[id(recording)] = (partial, path, announce)
    elif choice.kind == "connect":
        recording.connect_grpc(choice.target)
    elif choice.kind == "spawn":
        _spawn_viewer(args.viewer_port)
        recording.connect_grpc(choice.target)
    elif choice.kind == "serve":
        process = _serve_web(args.viewer_port, args.web_port)
        _WEB_SERVERS[id(recording)] = (process, choice.web_url)
        recording.connect_grpc(choice.target)
        if not args.no_browser:
            webbrowser.open(choice.web_url)
    announce(choice.message)
    return recording


def _choose_sink(args: argparse.Namespace, app_id: str) -> SinkChoice:
    port = getattr(args, "viewer_port", DEFAULT_VIEWER_PORT)
    if getattr(args, "save", None) is not None:
        path = Path(args.save)
        return SinkChoice("save", str(path), f"rerun: recording to {path} (written when the run ends)")
    if getattr(args, "connect", None):
        return SinkChoice("connect", args.connect, f"rerun: streaming to the viewer at {args.connect}")
    if getattr(args, "serve", False):
        grpc_url = f"rerun+http://{LOCALHOST}:{port}/proxy"
        web_url = f"http://{LOCALHOST}:{getattr(args, 'web_port', DEFAULT_WEB_PORT)}/?url={quote(grpc_url, safe='')}"
        return SinkChoice("serve", grpc_url, f"rerun: web viewer at {web_url} (native: {command('rerun', grpc_url)})",
                          web_url)
    if getattr(args, "spawn", False) or has_display():
        url = f"rerun+http://{LOCALHOST}:{port}/proxy"
        return SinkChoice("spawn", url, f"rerun: streaming to a native viewer on {url}")
    path = default_rrd_path(app_id)
    return SinkChoice("save", str(path), f"rerun: no display found, recording to {path} (written when the run "
                                         "ends; or pass --serve / --connect URL)")


def close_recording(recording, timeout_s: float = RECORDING_FLUSH_TIMEOUT_S, *,
                    wait_while_serving: bool = True) -> None:
    """Flush (at most ``timeout_s`` seconds) and close the recording's sinks, finishing an .rrd file.

    A saved recording is renamed from its temporary file to its target and the user told how to view it, or, when
    the :class:`~ftacq.app.dashboard.recorder.Dashboard` attached to it recorded nothing, removed and the user told
    so. A web viewer started by ``--serve`` keeps the data only while it runs: like Rerun's ``script_teardown``,
    this keeps serving until Ctrl-C (unless ``wait_while_serving`` is False), then stops the server.
    """
    flush, recorded = _ATTACHED.pop(id(recording), (None, None))
    if flush is not None:
        try:
            flush()
        except Exception:  # noqa: BLE001 - a broken viewer must not fail the caller's shutdown
            log.warning("rerun: the dashboard's last columns could not be sent", exc_info=True)
    try:
        recording.flush(timeout_sec=timeout_s)
    except Exception:  # noqa: BLE001 - a viewer that went away must not fail the caller's shutdown
        log.warning("rerun: flush did not finish within %.1f s", timeout_s, exc_info=True)
    recording.disconnect()
    saved = _SAVES.pop(id(recording), None)
    if saved is not None:
        partial, path, announce = saved
        if recorded is not None and not recorded():
            partial.unlink(missing_ok=True)
            announce(f"rerun: nothing was recorded; {path} not written")
        else:
            os.replace(partial, path)
            announce(f"rerun: saved {path}; view it with: {command('rerun', path)}")
    served = _WEB_SERVERS.pop(id(recording), None)
    if served is not None:
        process, web_url = served
        try:
            if wait_while_serving and process.poll() is None:
                print(f"rerun: still serving the recording at {web_url}; Ctrl-C to stop", file=sys.stderr)
                process.wait()
        except KeyboardInterrupt:
            pass
        finally:
            _stop_process_group(process, timeout_s)


__all__ = ["add_sink_args", "attach", "is_saved", "open_recording", "close_recording", "has_display",
           "default_rrd_path", "SinkChoice"]
