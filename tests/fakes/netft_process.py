"""Start the simulated Net F/T (tests/fakes/netft.py) in its own process, for a simulated cell.

A real Net F/T keeps its pace whatever the host does. In the process that also reads it (the monitor, a benchmark's
recorder) the fake's sending thread competes for one interpreter lock with the reader, and under load both starve:
the fake then skips samples it would never skip on a real box. In its own process it competes only for a core, as
the controller's process does. :class:`tests.fakes.cell.SimulatedCell` uses this with ``sensor_process=True``
(the benchmarks do); the physics reads the controller's pose and joint state from the shared memory block.

The process prints one JSON line (ports, URL) when it serves; ``stats`` on its stdin prints its counters; closing
its stdin stops it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import selectors
import subprocess
import sys
import time
from pathlib import Path

from tests.fakes.child_process import end_process

REPO_ROOT = Path(__file__).resolve().parents[2]
READY_TIMEOUT_S = 20.0
"""How long the process may take to import and bind, s."""
REPLY_TIMEOUT_S = 5.0
"""How long a ``stats`` answer may take, s."""


class NetFTProcess:
    """A simulated Net F/T in a subprocess: ``url``, ``rdt_port``, :meth:`stats`, :meth:`close` (safe twice).

    Args:
        truth: the :class:`tests.fakes.world.CellTruth` its physics follows. pose_shm: the SharedPose block the
            controller publishes into. model: UR model (the tool's inertia while moving). rate_hz: comrdtrate.
        seed: noise seed. box_args: further ``python -m tests.fakes.netft`` options (clock, bursts, backlog).
    """

    def __init__(self, truth, pose_shm: str, model: str, rate_hz: float, seed: int = 0,
                 box_args: list[str] | None = None) -> None:
        truth_json = json.dumps(dataclasses.asdict(truth))
        self._command = [sys.executable, "-m", "tests.fakes.netft", "--host", "127.0.0.1", "--pose-shm", pose_shm,
                         "--model", model, "--rate-hz", repr(float(rate_hz)), "--seed", str(seed),
                         "--truth-json", truth_json, *(box_args or [])]
        self._process: subprocess.Popen | None = None
        self.info: dict = {}

    def start(self) -> "NetFTProcess":
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        env["PYTHONPATH"] = str(REPO_ROOT) + os.pathsep + env.get("PYTHONPATH", "")
        self._process = subprocess.Popen(self._command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                         stderr=subprocess.PIPE, cwd=str(REPO_ROOT), env=env, text=True,
                                         start_new_session=True)
        line = self._read_line(READY_TIMEOUT_S)
        if not line.startswith("{"):
            self.close()
            raise RuntimeError(f"simulated Net F/T process did not start: {line or 'no output'}")
        self.info = json.loads(line)
        return self

    def _read_line(self, timeout_s: float) -> str:
        selector = selectors.DefaultSelector()
        selector.register(self._process.stdout, selectors.EVENT_READ)
        try:
            if not selector.select(timeout_s):
                return ""
            return self._process.stdout.readline().strip()
        finally:
            selector.close()

    @property
    def url(self) -> str:
        """The ``netft://`` URL of the simulated box."""
        return self.info["url"]

    @property
    def pid(self) -> int:
        return self._process.pid

    def stats(self) -> dict:
        """The box's counters (records produced, sent, skipped_backlog, sequences, ...) as a dict."""
        self._process.stdin.write("stats\n")
        self._process.stdin.flush()
        deadline = time.monotonic() + REPLY_TIMEOUT_S
        while (remaining := deadline - time.monotonic()) > 0:
            line = self._read_line(remaining)
            if line.startswith("{") and "records_produced" in line:
                return json.loads(line)
        raise TimeoutError(f"simulated Net F/T process: no stats within {REPLY_TIMEOUT_S} s")

    @property
    def skipped_backlog(self) -> int:
        """Records the box skipped because its process fell behind (``ft_sequence`` jumps over them)."""
        return int(self.stats()["skipped_backlog"])

    def close(self) -> None:
        """Stop the process (stdin closed, then SIGTERM, then SIGKILL at the deadlines)."""
        process, self._process = self._process, None
        if process is None:
            return
        try:
            process.stdin.close()
        except OSError:
            pass
        end_process(process)
        for stream in (process.stdout, process.stderr):
            if stream is not None:
                stream.close()
