"""Benchmark: ``ftacq monitor --ros2`` → a subscriber in another process, on loopback; the MCAP record's cost.

    .venv/bin/python benchmarks/ros2.py            # 20 s per run
    .venv/bin/python benchmarks/ros2.py --quick    # 8 s per run
    .venv/bin/python benchmarks/ros2.py --quick --in-process   # the simulated Net F/T inside the monitor's process
    .venv/bin/python benchmarks/ros2.py --quick --read-periods-ms 0,2   # the monitor's read period swept

The cell as a real one is: the simulated UR controller and Net F/T (7 kHz) each in their own process
(tests/fakes/cell.py ``sensor_process=True``, the arm still), and ``ftacq monitor --config CELL.toml --calibration
CAL.json`` (the simulated tool's true calibration, with inertia: dynamic compensation) run in this process, which
holds nothing else. ``--in-process``: ``ftacq monitor --sim --sim-still`` instead, whose simulated Net F/T shares
the monitor's process (and its interpreter lock). Runs: without ROS 2, with ``--record X.mcap`` alone at 1 kHz and
at every sample (``--ros2-rate 0``), and with ``--ros2 --ros2-reliable`` at both rates (each with ``--record
X.mcap``); beside each ``--ros2`` run, tests/ros2_subscriber.py (Cyclone DDS, reliable, keep all) in its own
process. Discovery on loopback only (``CYCLONEDDS_URI``: drivers.ros2.node.LOCALHOST_CONFIG), a fresh domain per run.

Printed per run:

- sent: the wrench messages in the bag (the publisher and the bag share their messages, byte for byte:
  tests/test_ros2.py); received: those the subscriber took, as % of those sent from its first to its last
  (what is published before the subscriber is matched reaches no one on a volatile topic);
- latency sample time → receipt: the subscriber's receipt (UNIX clock, this host) − header.stamp, p50/p99/max;
- with ``--ros2`` the latency of every ``wrench_compensated`` message taken apart (:class:`Probe`: the monitor's
  own functions wrapped in this process, times on the host monotonic clock; the subscriber's UNIX receipt brought
  onto it with the publisher's stamp offset): stamp (the window's mean sample time) → the window's newest sample
  (half a window) → its datagram stamped by the driver's receive thread ("host receipt": the device, the simulator
  and the kernel, and the receive thread's wake-up) → the read that returned it → compensated → handed to the ROS 2
  path → (the read that sent the window: its newest sample's, or a later one that showed it complete) → written
  to DDS → the subscriber's receipt; and the product's own latency, host receipt of the window's newest sample →
  the subscriber's receipt;
- CPU, % of one core: what --ros2 and --record .mcap add: the acquisition thread's time in the ROS 2 listener
  (messages made and written to DDS: procedures.ros2_stream.Ros2Stream), the bag's thread, Cyclone DDS's own
  threads; the monitor's loop (the main thread, that listener included); the whole process while it streamed,
  against the run without either (that difference also counts reading on data and waiting for no robot state).
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
        self._before: dict[int, float] = {}
        self._loop: list[tuple[float, float]] = []  # (wall, the main thread's CPU) while the monitor streams

    def __enter__(self) -> "ThreadCpu":
        self._sample()
        self._before = {tid: cpu for tid, (_, cpu) in self.cpu_s.items()}  # threads older than the run: their CPU then
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    def _sample(self) -> None:
        import threading

        names = {thread.native_id: thread.name for thread in threading.enumerate()}
        streaming = "ftacq-listeners" in names.values()  # the monitor's listener thread lives while it streams
        if streaming:
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
            if streaming and tid == threading.main_thread().native_id:
                self._loop.append((time.monotonic(), self.cpu_s[tid][1]))

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self._sample()

    @property
    def stream_percent(self) -> float:
        """The whole process's CPU while the monitor streamed (the simulated devices included), % of one core."""
        (wall0, cpu0), (wall1, cpu1) = self._stream[0], self._stream[-1]
        return 100.0 * (cpu1 - cpu0) / (wall1 - wall0)

    @property
    def loop_percent(self) -> float:
        """The main thread's CPU (the monitor's loop: read, compensate, publish) while it streamed, % of one core."""
        (wall0, cpu0), (wall1, cpu1) = self._loop[0], self._loop[-1]
        return 100.0 * (cpu1 - cpu0) / (wall1 - wall0)

    def by_name(self, prefixes: tuple[str, ...]) -> float:
        """CPU time (s) the threads named so used since :meth:`__enter__`."""
        return sum(cpu - self._before.get(tid, 0.0) for tid, (name, cpu) in self.cpu_s.items()
                   if name.startswith(prefixes))


class Probe:
    """Times each read through the monitor (module docstring) by wrapping, in this process only, the sensor's
    ``read``, ``LiveMonitor._process``, ``Ros2Stream`` (the hand-over) and ``Ros2Publisher`` (the DDS write)."""

    def __init__(self) -> None:
        self.reads: list[tuple] = []  # (sample_time_s, receive_time_s, read returned, compensated, handed, compensated?)
        self.writes: list[tuple[np.ndarray, float]] = []  # (wrench_compensated stamps ns, written)
        self.offset_s = 0.0
        self.period_s = 0.0
        self._pending: dict[int, list] = {}
        self.stream_cpu_s = 0.0  # CPU time of the acquisition thread in procedures.ros2_stream.Ros2Stream

    @contextlib.contextmanager
    def installed(self):
        from drivers.sensor import SensorBase
        from procedures.monitor import LiveMonitor
        from procedures.ros2_stream import Ros2Publisher, Ros2Stream
        from procedures.events import WrenchSamples

        probe, now = self, time.monotonic
        read, process, hand, send = SensorBase.read, LiveMonitor._process, Ros2Stream.__call__, Ros2Publisher.__call__

        def timed_read(sensor, timeout_s=1.0):
            batch = read(sensor, timeout_s)
            probe._pending[id(batch)] = [batch, now()]
            return batch

        def timed_process(monitor, batch, sample_time_s):
            samples = process(monitor, batch, sample_time_s)
            entry = probe._pending.get(id(batch))
            if entry is not None:
                entry += [now(), samples]
            return samples

        def timed_hand(stream, event):
            cpu_s = time.thread_time()
            if isinstance(event, WrenchSamples):
                entry = probe._pending.pop(id(event.batch), None)
                if entry is not None and len(entry) == 4:
                    batch, read_s, compensated_s, samples = entry
                    probe.reads.append((np.asarray(samples.sample_time_s, dtype=float),
                                        np.asarray(batch.time_s, dtype=float), read_s, compensated_s, now(),
                                        samples.compensated is not None))
                probe.offset_s = stream.messages.clock.offset_s
                probe.period_s = stream.messages.streams.raw.period_s
            hand(stream, event)
            probe.stream_cpu_s += time.thread_time() - cpu_s

        def timed_send(publisher, messages):
            send(publisher, messages)
            for name, _, _, stamp_ns in messages:
                if name == "wrench_compensated":
                    probe.writes.append((stamp_ns, now()))

        patches = [(SensorBase, "read", timed_read), (LiveMonitor, "_process", timed_process),
                   (Ros2Stream, "__call__", timed_hand), (Ros2Publisher, "__call__", timed_send)]
        try:
            for owner, name, function in patches:
                setattr(owner, name, function)
            yield self
        finally:
            for (owner, name, _), original in zip(patches, (read, process, hand, send)):
                setattr(owner, name, original)

    def stages(self, received: list[dict]) -> dict[str, np.ndarray]:
        """Per ``wrench_compensated`` message received: each stage's duration, ms (module docstring)."""
        reads = [r for r in self.reads if r[5]]  # the compensated stream's windows hold compensated reads only
        sample_s = np.maximum.accumulate(np.concatenate([r[0] for r in reads]))  # as procedures.ros2_stream.WindowMean
        receipt_s = np.concatenate([r[1] for r in reads])
        read_of = np.concatenate([np.full(len(r[0]), i) for i, r in enumerate(reads)])
        read_s, compensated_s, handed_s = (np.array([r[k] for r in reads]) for k in (2, 3, 4))
        written_s = {int(stamp): at for stamps, at in self.writes for stamp in stamps.tolist()}
        stamp_ns = np.array([e["stamp"][0] * 10**9 + e["stamp"][1] for e in received], dtype=np.int64)
        keep = np.array([int(s) in written_s for s in stamp_ns], dtype=bool)
        stamp_ns = stamp_ns[keep]
        subscriber_s = np.array([e["received_s"] for e in received])[keep] - self.offset_s
        stamp_s = stamp_ns * 1e-9 - self.offset_s
        if self.period_s > 0:  # the window's newest sample
            window = np.floor(sample_s / self.period_s)
            newest = np.searchsorted(window, np.floor(stamp_s / self.period_s), side="right") - 1
        else:
            after = np.clip(np.searchsorted(sample_s, stamp_s), 1, len(sample_s) - 1)  # the nearest sample
            newest = after - (stamp_s - sample_s[after - 1] < sample_s[after] - stamp_s)
        written = np.array([written_s[int(s)] for s in stamp_ns])
        # the read that sent the window (it, or a later one that showed it complete): the last handed before the write
        r, c = read_of[newest], np.maximum(np.searchsorted(handed_s, written, side="right") - 1, read_of[newest])
        steady = r > 0  # the first read holds what came since the sensor started (start-up, not the stream)
        newest, r, c, written, subscriber_s, stamp_s = (a[steady] for a in (newest, r, c, written, subscriber_s,
                                                                           stamp_s))
        ms = 1e3
        return {"stamp → newest sample (window)": ms * (sample_s[newest] - stamp_s),
                "→ host receipt (device, simulator, kernel)": ms * (receipt_s[newest] - sample_s[newest]),
                "→ read returned (driver hold, read pacing)": ms * (read_s[r] - receipt_s[newest]),
                "→ compensated": ms * (compensated_s[r] - read_s[r]),
                "→ handed to ROS 2": ms * (handed_s[r] - compensated_s[r]),
                "→ window closed (its read or a later one)": ms * (handed_s[c] - handed_s[r]),
                "→ DDS written (means, CDR, write)": ms * (written - handed_s[c]),
                "→ subscriber receipt": ms * (subscriber_s - written),
                "PRODUCT: host receipt → subscriber": ms * (subscriber_s - receipt_s[newest]),
                "end to end: stamp → subscriber": ms * (subscriber_s - stamp_s)}


def run(folder: Path, seconds: float, ros2: list[str] | None, bag: bool, cell_args: list[str],
        dds: bool = True) -> dict:
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
    command = ["monitor", *cell_args, "--seconds", str(seconds), "--save", str(folder / f"{name}.rrd")]
    if bag:
        command += ["--record", str(folder / f"{name}.mcap")]
    if dds:
        command += ["--ros2", "--ros2-domain-id", str(domain_id), "--ros2-namespace", namespace]
    command += ros2 or []
    from ftacq.app.cli import main as ftacq_main

    os.environ["CYCLONEDDS_URI"] = LOCALHOST_CONFIG
    out = io.StringIO()
    with ThreadCpu() as threads, Probe().installed() as probe, contextlib.redirect_stderr(io.StringIO()), \
            contextlib.redirect_stdout(out):
        code = ftacq_main(command)
    if code != 0:
        raise SystemExit(f"ftacq monitor exited {code}: {out.getvalue()[-2000:]}")
    ros2_cpu_s = threads.by_name(("ftacq-mcap", "dds:")) + probe.stream_cpu_s
    figures: dict = {"cpu_percent": 100.0 * ros2_cpu_s / seconds,
                     "dds_percent": 100.0 * threads.by_name(("dds:",)) / seconds,
                     "mcap_percent": 100.0 * threads.by_name(("ftacq-mcap",)) / seconds,
                     "publisher_percent": 100.0 * probe.stream_cpu_s / seconds,
                     "loop_percent": threads.loop_percent,
                     "process_percent": threads.stream_percent, "reads": len(probe.reads)}
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
        figures["stages"] = probe.stages(received["wrench_compensated"])
    return figures


@contextlib.contextmanager
def cell_outside(folder: Path):
    """The simulated cell's devices in their own processes (the arm still); the monitor's options to reach them."""
    from ftacq.app.sim_technician import DEFAULT_SIM_MODEL, SIM_SENSOR_RATE_HZ
    from ftacq.app.simcell import true_calibration
    from ftacq.calfile import save_calibration
    from tests.fakes.cell import SimulatedCell

    with SimulatedCell(sensor="netft", model=DEFAULT_SIM_MODEL, rate_hz=SIM_SENSOR_RATE_HZ,
                       sensor_process=True) as cell:
        toml, calibration = folder / "CELL.toml", folder / "calibration.json"
        toml.write_text(f'[robot]\nhost = "{cell.robot_host}"\nmodel = "{DEFAULT_SIM_MODEL}"\n[sensor]\n'
                        f'url = "{cell.sensor_url}"\n', encoding="utf-8")
        save_calibration(calibration, true_calibration(cell.truth))
        yield ["--config", str(toml), "--calibration", str(calibration)]


def _percentiles(values: np.ndarray) -> str:
    return "/".join(f"{v:.2f}" for v in np.percentile(values, [50, 99, 100]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="8 s per run instead of 20 s")
    parser.add_argument("--in-process", action="store_true", help="ftacq monitor --sim: the simulated Net F/T in "
                        "the monitor's process (default: the devices in their own processes, as a real cell)")
    parser.add_argument("--latency-only", action="store_true", help="only the run without ROS 2 and --ros2 at 1 kHz")
    parser.add_argument("--read-periods-ms", default="", help="--ros2-read-period values to try, ms, "
                        "comma-separated (default: ftacq's)")
    args = parser.parse_args()
    seconds = 8.0 if args.quick else 20.0
    print(f"load average before: {os.getloadavg()[0]:.1f}; {seconds:g} s per run; the simulated devices "
          + ("in the monitor's process (--sim)" if args.in_process else "in their own processes"))
    with tempfile.TemporaryDirectory() as folder, contextlib.ExitStack() as stack:
        cell_args = (["--sim", "--sim-still"] if args.in_process else stack.enter_context(cell_outside(Path(folder))))
        base = run(Path(folder), seconds, None, bag=False, cell_args=cell_args, dds=False)
        print(f"monitor alone: process {base['process_percent']:.1f} % of one core while streaming (main thread "
              f"{base['loop_percent']:.1f} %)")
        runs = [] if args.latency_only else [
            ("--record X.mcap (1 kHz)", [], False),
            ("--record X.mcap --ros2-rate 0 (every sample)", ["--ros2-rate", "0"], False)]
        periods = [float(p) for p in args.read_periods_ms.split(",")] if args.read_periods_ms else [None]
        for period_ms in periods:
            at = "" if period_ms is None else f" --ros2-read-period {period_ms / 1e3:g}"
            paced = [] if period_ms is None else ["--ros2-read-period", f"{period_ms / 1e3:g}"]
            runs += [(f"--ros2 --ros2-reliable{at} (1 kHz) + --record X.mcap", ["--ros2-reliable", *paced], True)]
            if not args.latency_only:
                runs += [(f"--ros2 --ros2-reliable{at} --ros2-rate 0 (every sample) + --record X.mcap",
                          ["--ros2-reliable", "--ros2-rate", "0", *paced], True)]
        for label, options, dds in runs:
            f = run(Path(folder), seconds, options, bag=True, cell_args=cell_args, dds=dds)
            print(f"{label}: ROS 2 {f['cpu_percent']:.1f} % of one core (messages + DDS writes in the loop {f['publisher_percent']:.1f},"
                  f" Cyclone DDS {f['dds_percent']:.1f}, MCAP {f['mcap_percent']:.1f}); main thread "
                  f"{f['loop_percent']:.1f} % (+{f['loop_percent'] - base['loop_percent']:.1f}); process "
                  f"{f['process_percent']:.1f} % (+{f['process_percent'] - base['process_percent']:.1f}); bag "
                  f"{f['bag_messages']}, {f['bag_bytes'] / seconds / 1e3:.0f} kB/s; the monitor's samples "
                  f"{f['samples']} over {f['span_s']:.2f} s, {f['reads']} reads")
            if dds:
                for topic in ("wrench_raw", "wrench_compensated"):
                    t = f[topic]
                    print(f"  {topic}: received {t['received']} of {t['sent_in_span']} sent over its span "
                          f"({t['received_percent']:.2f} %), latency sample → receipt p50/p99/max "
                          f"{t['latency_ms_p50_p99_max']} ms")
                print("  wrench_compensated per message, ms p50/p99/max:")
                for stage, values in f["stages"].items():
                    print(f"    {stage:45s} {_percentiles(values)}")
        print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
