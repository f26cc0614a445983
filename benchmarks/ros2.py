"""Benchmark: ``ftacq monitor --sim --ros2`` → a subscriber in another process, on loopback; the MCAP record's cost.

    .venv/bin/python benchmarks/ros2.py            # 20 s per run
    .venv/bin/python benchmarks/ros2.py --quick    # 8 s per run
    .venv/bin/python benchmarks/ros2.py --quick --read-periods-ms 1,2,10   # the monitor's read period swept

Runs ``ftacq monitor --sim --sim-still --save X.rrd`` in this process (the simulated Net F/T at 7 kHz and the UR
controller in it too), once without ROS 2, with ``--record X.mcap`` alone at 1 kHz and at every sample
(``--ros2-rate 0``), and with ``--ros2 --ros2-reliable`` at both rates (each with ``--record X.mcap``); beside each
``--ros2`` run, tests/ros2_subscriber.py (Cyclone DDS, reliable, keep all) in its own process. Discovery on
loopback only (``CYCLONEDDS_URI``: drivers.ros2.node.LOCALHOST_CONFIG), a fresh domain per run.

Printed per run:

- sent: the wrench messages in the bag (the publisher and the bag share their messages and stamps, byte for byte:
  tests/test_ros2.py); received: those the subscriber took, as % of those sent from its first to its last
  (discovery takes a moment: what is published before the subscriber is matched reaches no one on a volatile
  topic); nothing lost in the bag: at every sample its wrench_raw messages against the samples the monitor
  counted (its last line);
- latency sample time → receipt: the subscriber's receipt (UNIX clock, this host) − the message's header.stamp
  (the sample time, or a window's mean sample time at 1 kHz), p50 / p99 / max;
- CPU: the threads --ros2 and --record .mcap add (the publisher's, the bag's, Cyclone DDS's own), their CPU time
  over the run's seconds, % of one core; and the whole process while it streamed (the simulated devices included)
  against the run without either (that difference also counts the shorter read period of --ros2).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.ros2.node import LOCALHOST_CONFIG  # noqa: E402

SUBSCRIBER = ROOT / "tests" / "ros2_subscriber.py"
FTACQ = [sys.executable, "-c", "import sys; from ftacq.app.cli import main; sys.exit(main())"]


def _env() -> dict[str, str]:
    return dict(os.environ, CYCLONEDDS_URI=LOCALHOST_CONFIG, PYTHONPATH=str(ROOT))


class ThreadCpu:
    """Samples this process's threads' CPU time (/proc/self/task/*/stat, utime + stime) every ``period_s`` and keeps
    each thread's last figure under its name: the Python name (``threading``) or the OS one (Cyclone DDS names its
    own threads: recvUC, tev, dq.builtins, …)."""

    def __init__(self, period_s: float = 0.1) -> None:
        import threading

        self.period_s = period_s
        self.cpu_s: dict[int, tuple[str, float]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="benchmark-cpu-sampler", daemon=True)
        self._tick_s = 1.0 / os.sysconf("SC_CLK_TCK")
        self._comm = Path("/proc/self/comm").read_text().strip()
        self._stream: list[tuple[float, float]] = []  # (wall, process CPU) while the monitor streams

    def __enter__(self) -> "ThreadCpu":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    def _sample(self) -> None:
        import threading

        names = {thread.native_id: thread.name for thread in threading.enumerate()}
        if "ftacq-listeners" in names.values():  # the monitor's listener thread lives while it streams
            fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
            self._stream.append((time.monotonic(), (int(fields[11]) + int(fields[12])) * self._tick_s))
        for task in Path("/proc/self/task").iterdir():
            try:
                stat = (task / "stat").read_text()
                comm = (task / "comm").read_text().strip()
            except OSError:
                continue  # the thread ended
            fields = stat.rsplit(")", 1)[1].split()
            tid = int(task.name)
            name = names.get(tid) or (f"dds:{comm}" if comm != self._comm else "other")
            self.cpu_s[tid] = (name, (int(fields[11]) + int(fields[12])) * self._tick_s)

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self._sample()

    @property
    def stream_percent(self) -> float:
        """The whole process's CPU while the monitor streamed (the simulated devices included), % of one core."""
        (wall0, cpu0), (wall1, cpu1) = self._stream[0], self._stream[-1]
        return 100.0 * (cpu1 - cpu0) / (wall1 - wall0)

    def by_name(self, prefixes: tuple[str, ...]) -> float:
        return sum(cpu for name, cpu in self.cpu_s.values() if name.startswith(prefixes))


def run(folder: Path, seconds: float, ros2: list[str] | None, bag: bool, dds: bool = True) -> dict:
    """One monitor run with the options ``ros2`` (and ``--ros2`` and a subscriber if ``dds``); its figures."""
    token = uuid.uuid4()
    domain_id, namespace = 1 + token.int % 200, f"/b{token.hex[:10]}"
    name = token.hex[:6]
    received_path = folder / f"{name}.json"
    subscriber = None
    dds = dds and ros2 is not None
    if dds:
        subscriber = subprocess.Popen([sys.executable, str(SUBSCRIBER), str(domain_id), namespace,
                                       str(seconds + 120), str(received_path), "--reliable"],
                                      stdout=subprocess.PIPE, text=True, env=_env())
        assert subscriber.stdout is not None and subscriber.stdout.readline().strip() == "ready"
    command = [*FTACQ, "monitor", "--sim", "--sim-still", "--seconds", str(seconds), "--save",
               str(folder / f"{name}.rrd")]
    if bag:
        command += ["--record", str(folder / f"{name}.mcap")]
    if dds:
        command += ["--ros2", "--ros2-domain-id", str(domain_id), "--ros2-namespace", namespace]
    command += ros2 or []
    from ftacq.app.cli import main as ftacq_main

    os.environ["CYCLONEDDS_URI"] = LOCALHOST_CONFIG
    out = io.StringIO()
    with ThreadCpu() as threads, contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(out):
        code = ftacq_main(command[len(FTACQ):])
    if code != 0:
        raise SystemExit(f"ftacq monitor exited {code}")
    ros2_cpu_s = threads.by_name(("ftacq-ros2", "ftacq-mcap", "dds:"))
    figures: dict = {"cpu_percent": 100.0 * ros2_cpu_s / seconds,
                     "dds_percent": 100.0 * threads.by_name(("dds:",)) / seconds,
                     "mcap_percent": 100.0 * threads.by_name(("ftacq-mcap",)) / seconds,
                     "publisher_percent": 100.0 * threads.by_name(("ftacq-ros2",)) / seconds,
                     "process_percent": threads.stream_percent}
    import re

    found = re.search(r"(\d+) samples received over ([\d.]+) s", out.getvalue())
    figures["samples"], figures["span_s"] = (int(found[1]), float(found[2])) if found else (0, 0.0)
    sent: dict[str, np.ndarray] = {}
    if bag:
        from rosbags.rosbag2 import Reader

        with Reader(folder / f"{name}.mcap") as reader:
            for connection, stamp_ns, _ in reader.messages():
                sent.setdefault(connection.topic.rsplit("/", 1)[-1], []).append(stamp_ns)  # type: ignore[arg-type]
        sent = {topic: np.sort(np.array(stamps)) for topic, stamps in sent.items()}
        figures["bag_bytes"] = (folder / f"{name}.mcap").stat().st_size
        figures["bag_messages"] = {topic: len(stamps) for topic, stamps in sent.items()}
    if subscriber is not None:
        subscriber.wait(timeout=180)
        received = json.loads(received_path.read_text())
        for topic in ("wrench_raw", "wrench_compensated"):
            entries = received[topic]
            stamp_ns = np.array([e["stamp"][0] * 10**9 + e["stamp"][1] for e in entries], dtype=np.int64)
            latency_ms = 1e3 * (np.array([e["received_s"] for e in entries]) - stamp_ns * 1e-9)
            in_span = sent[topic][(sent[topic] >= stamp_ns.min()) & (sent[topic] <= stamp_ns.max())]
            figures[topic] = {"received": len(entries), "sent_in_span": len(in_span),
                              "received_percent": 100.0 * len(stamp_ns) / max(1, len(in_span)),
                              "latency_ms_p50_p99_max": np.percentile(latency_ms, [50, 99, 100]).round(2).tolist()}
    return figures


def set_read_period(period_s: float) -> None:
    from ftacq.app import ros2_outputs

    ros2_outputs.ROS2_READ_PERIOD_S = period_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="8 s per run instead of 20 s")
    parser.add_argument("--read-periods-ms", default="2", help="the monitor's read periods with --ros2 to try, "
                        "comma-separated (default: ftacq's, 2)")
    args = parser.parse_args()
    seconds = 8.0 if args.quick else 20.0
    print(f"load average before: {os.getloadavg()[0]:.1f}; {seconds:g} s per run")
    with tempfile.TemporaryDirectory() as folder:
        base = run(Path(folder), seconds, None, bag=False, dds=False)
        print(f"monitor alone: process {base['process_percent']:.1f} % of one core while streaming (the simulated "
              "devices included)")
        runs = [("--record X.mcap (1 kHz)", [], False, None),
                ("--record X.mcap --ros2-rate 0 (every sample)", ["--ros2-rate", "0"], False, None)]
        for period_ms in [float(p) for p in args.read_periods_ms.split(",")]:
            runs += [(f"--ros2 --ros2-reliable (1 kHz) + --record X.mcap, reads every {period_ms:g} ms",
                      ["--ros2-reliable"], True, period_ms),
                     (f"--ros2 --ros2-reliable --ros2-rate 0 (every sample) + --record X.mcap, reads every "
                      f"{period_ms:g} ms", ["--ros2-reliable", "--ros2-rate", "0"], True, period_ms)]
        for label, options, dds, period_ms in runs:
            if period_ms is not None:
                set_read_period(period_ms / 1e3)
            f = run(Path(folder), seconds, options, bag=True, dds=dds)
            print(f"{label}: ROS 2 threads {f['cpu_percent']:.1f} % of one core (publisher {f['publisher_percent']:.1f},"
                  f" Cyclone DDS {f['dds_percent']:.1f}, MCAP {f['mcap_percent']:.1f}); process "
                  f"{f['process_percent']:.1f} % (+{f['process_percent'] - base['process_percent']:.1f}); bag {f['bag_messages']}, "
                  f"{f['bag_bytes'] / seconds / 1e3:.0f} kB/s; the monitor's samples {f['samples']} over {f['span_s']:.2f} s")
            if dds:
                for topic in ("wrench_raw", "wrench_compensated"):
                    t = f[topic]
                    print(f"  {topic}: received {t['received']} of {t['sent_in_span']} sent over its span "
                          f"({t['received_percent']:.2f} %), latency sample → receipt p50/p99/max "
                          f"{t['latency_ms_p50_p99_max']} ms")
        print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
