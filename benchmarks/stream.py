"""Benchmark: the Net F/T driver streaming from the fake box in another process, with batch compensation.

    .venv/bin/python benchmarks/stream.py            # 60 s at 7 kHz, then the rate searches (5 s per trial)
    .venv/bin/python benchmarks/stream.py --quick    # 10 s at 7 kHz, 2 s per trial

1. **7 kHz run.** ``python -m tests.fakes.netft`` runs in its own process at 7000 Hz (one record per datagram, as
   the real box). This process runs only the driver (receive thread + a reader that calls ``read()`` and
   ``Calibration.compensate`` with one orientation per batch). Prints samples, lost, the CPU time of *this*
   process (``time.process_time``: every thread of the driver, not the fake's process) as % of one core over the
   wall time, and the latency to each compensated sample: from the fake's send *schedule* (the fake sends
   record k no earlier than t0 + k / rate, and both processes share CLOCK_MONOTONIC), an upper bound of the
   datagram → compensated latency that includes kernel queueing and the receive thread's wake-up; and from the
   driver's receive stamp (taken when the receive thread drains the datagram, so it leaves out the time a
   datagram waits in the kernel while the thread coalesces wake-ups).
2. **Highest loss-free rate, our driver.** The fake is started with ``--max-rate-hz`` (an unfaithful extension: a
   real box stops at 7000 Hz) and the driver asks for each trial rate through the box's ``comm.cgi`` (its
   ``rate_hz`` URL key). Rates double from 14 kHz until a trial loses records, then are bisected. A trial is
   loss-free when the driver counts no lost, duplicate or out-of-order record, its ring never overflowed, and it
   delivered ≥ 98 % of what the fake sent in the trial. Run twice: one record per datagram (0x0002, like the
   box and like pynetft needs), and buffered (0x0003, ``comrdtbsiz`` = 40 records per datagram). When the fake
   itself cannot send as fast as asked (it is Python too) the search stops and says so ("fake-limited").
3. **pynetft 2.x** against the same fake process, one record per datagram (it accepts only 36-byte datagrams),
   consuming its sample iterator and compensating in batches of 256. Loss-free: ``lost_count`` and
   ``python_queue_dropped_count`` zero and ≥ 98 % delivered.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.netft import NetFTSensor  # noqa: E402
from ftacq.errors import DeviceError  # noqa: E402
from ftacq.so3 import rotation_from_rotvec  # noqa: E402
from tests.fakes.world import CellTruth  # noqa: E402

RATE_HZ = 7000.0
FULL_SECONDS, QUICK_SECONDS = 60.0, 10.0
FULL_TRIAL_S, QUICK_TRIAL_S = 5.0, 2.0
SEARCH_START_HZ = 14000.0
SEARCH_MAX_HZ = 1_000_000.0
BISECTION_STEPS = 3
DELIVERED_FRACTION = 0.999
"""A trial is loss-free only if the client, after draining, delivered this fraction of what the fake sent (the
last records of a trial may still be in flight)."""
FAKE_ACHIEVED_FRACTION = 0.95
"""Below this fraction of the asked rate the fake (not the client) is the limit."""
FAKE_LIMITED_TRIALS = 2
"""The search stops after this many loss-free trials in a row in which the fake could not send as fast as asked."""
MAX_RATE_FAKE_HZ = 5_000_000.0
BUFFERED_RECORDS = 40
READ_TIMEOUT_S = 1.0
DRAIN_S = 1.0
"""After a trial, how long a client may take to deliver what the fake had sent (backlog), seconds."""
PYNETFT_BATCH = 256
FAKE_POSE = np.array([0.4, 0.0, 0.4, np.pi, 0.0, 0.0])
"""The fake's fixed flange pose when it runs without --pose-shm (tests.fakes.world.SettablePose's default)."""


class FakeProcess:
    """``python -m tests.fakes.netft`` in its own process, driven through its stdin."""

    def __init__(self, rate_hz: float, max_rate_hz: float = RATE_HZ) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-m", "tests.fakes.netft", "--rate-hz", f"{rate_hz:g}", "--max-rate-hz",
             f"{max_rate_hz:g}"], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        line = self.process.stdout.readline()
        if not line:
            self.process.kill()
            raise RuntimeError("the fake Net F/T exited before printing its ports")
        self.ports = json.loads(line)

    def ask(self, line: str) -> dict:
        self.process.stdin.write(line + "\n")
        self.process.stdin.flush()
        return json.loads(self.process.stdout.readline())

    def stats(self) -> dict:
        return self.ask("stats")

    def close(self) -> None:
        try:
            self.process.stdin.close()
            self.process.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            self.process.terminate()
            self.process.wait(timeout=10.0)


def driver_run(fake: FakeProcess, seconds: float, query: str = "", latency: bool = False) -> dict:
    """Stream ``seconds`` into the driver, compensating each batch; return the figures."""
    calibration = CellTruth().calibration()
    flange_R_base = rotation_from_rotvec(FAKE_POSE[3:]).T
    before = fake.stats()
    sensor = NetFTSensor.from_url(fake.ports["url"] + query, timeout_s=1.0)
    sensor.start()
    stream = fake.stats()
    latencies, schedule_latencies = [], []
    samples = 0
    residual = np.zeros(6)
    try:
        cpu_start_s, wall_start_s = time.process_time(), time.monotonic()
        while time.monotonic() - wall_start_s < seconds:
            batch = sensor.read(timeout_s=READ_TIMEOUT_S)
            contact = calibration.compensate(batch.wrench, flange_R_base)
            done_s = time.monotonic()
            samples += len(batch)
            if latency:
                latencies.append(done_s - batch.time_s)
                schedule_latencies.append(done_s - (stream["stream_t0_s"] + batch.sequence / stream["rate_hz"]))
                residual += contact.sum(axis=0)
        cpu_s, wall_s = time.process_time() - cpu_start_s, time.monotonic() - wall_start_s
        after = fake.stats()
        caught_up = _drain(lambda: sensor.read(timeout_s=DRAIN_S), lambda: sensor.delivered,
                           after["records_sent"] - before["records_sent"])
        health = sensor.health()
    finally:
        sensor.close()
    result = {"samples": samples, "delivered": sensor.delivered, "lost": health.lost, "duplicate": health.duplicate,
              "out_of_order": health.out_of_order, "overflowed": sensor.overflowed, "reconnects": health.reconnects,
              "cpu_percent": 100.0 * cpu_s / wall_s, "wall_s": wall_s,
              "fake_sent": after["records_sent"] - before["records_sent"],
              "fake_send_errors": after["send_errors"] - before["send_errors"],
              "fake_rate_hz": (after["records_sent"] - before["records_sent"]) / wall_s,
              "receive_buffer_bytes": sensor.receive_buffer_bytes}
    if latency and latencies:
        result["p99_latency_ms"] = 1e3 * float(np.percentile(np.concatenate(latencies), 99))
        result["p50_latency_ms"] = 1e3 * float(np.percentile(np.concatenate(latencies), 50))
        if health.reconnects == 0:
            schedule = np.concatenate(schedule_latencies)
            result["p99_schedule_latency_ms"] = 1e3 * float(np.percentile(schedule, 99))
            result["p50_schedule_latency_ms"] = 1e3 * float(np.percentile(schedule, 50))
        result["mean_contact"] = residual / max(samples, 1)
    result["caught_up"] = caught_up
    result["loss_free"] = (health.lost == 0 and health.duplicate == 0 and health.out_of_order == 0
                           and sensor.overflowed == 0 and caught_up)
    return result


def pynetft_run(fake: FakeProcess, rate_hz: float, seconds: float) -> dict:
    """Stream ``seconds`` into pynetft's sample iterator, compensating in batches; return the figures."""
    import pynetft

    calibration = CellTruth().calibration()
    flange_R_base = rotation_from_rotvec(FAKE_POSE[3:]).T
    fake.ask(f"rate {rate_hz:g}")
    before = fake.stats()
    config = pynetft.Config(sensor_host="127.0.0.1", rdt_port=fake.ports["rdt_port"],
                            http_port=fake.ports["http_port"], receive_timeout=0.5)
    delivered = 0
    with pynetft.Client(config, queue_size=1 << 16) as client:
        samples = client.samples(timeout=READ_TIMEOUT_S)
        pending: list = []
        start_s = time.monotonic()
        for sample in samples:
            pending.append(sample.force + sample.torque)
            if len(pending) >= PYNETFT_BATCH:
                calibration.compensate(np.array(pending), flange_R_base)
                delivered += len(pending)
                pending.clear()
                if time.monotonic() - start_s >= seconds:
                    break
        wall_s = time.monotonic() - start_s
        after = fake.stats()
        sent = after["records_sent"] - before["records_sent"]

        def next_sample() -> None:
            nonlocal delivered
            next(samples)
            delivered += 1

        caught_up = _drain(next_sample, lambda: delivered, sent)
        health = client.health()
    dropped = health.python_queue_dropped_count
    return {"delivered": delivered, "lost": health.lost_count, "queue_dropped": dropped,
            "out_of_order": health.out_of_order_count, "fake_sent": sent, "fake_rate_hz": sent / wall_s,
            "caught_up": caught_up,
            "loss_free": health.lost_count == 0 and dropped == 0 and health.out_of_order_count == 0 and caught_up}


def _drain(read_more, delivered, sent: int) -> bool:
    """After a trial: keep consuming until the client delivered what the fake had sent by the trial's end (the
    stream goes on meanwhile), for at most DRAIN_S. Return whether it caught up."""
    deadline = time.monotonic() + DRAIN_S
    while delivered() < DELIVERED_FRACTION * sent:
        if time.monotonic() > deadline:
            return False
        try:
            read_more()
        except (TimeoutError, StopIteration):
            return False
    return True


def search(trial, label: str) -> tuple[float, bool, list[str]]:
    """Double the asked rate from SEARCH_START_HZ while trials are loss-free, then bisect between the last good and
    the first bad rate. Return (highest rate the fake actually sent in a loss-free trial, fake_limited, log lines);
    fake_limited when no trial lost records: the fake (Python too) ran out of speed first.
    ``trial(rate)`` returns a result dict with ``loss_free`` and ``fake_rate_hz``."""
    log: list[str] = []
    best = 0.0
    good, bad = RATE_HZ, None
    limited_in_a_row = 0

    def attempt(rate_hz: float) -> tuple[bool, bool]:
        nonlocal best
        result = trial(rate_hz)
        achieved = result["fake_rate_hz"]
        limited = achieved < FAKE_ACHIEVED_FRACTION * rate_hz
        log.append(f"  {label} {rate_hz:>9.0f} Hz asked, fake sent {achieved:>9.0f} Hz: "
                   f"{'loss-free' if result['loss_free'] else 'LOSS'}{' (fake-limited)' if limited else ''} "
                   f"({_short(result)})")
        if result["loss_free"]:
            best = max(best, achieved)
        return result["loss_free"], limited

    rate = SEARCH_START_HZ
    while rate <= SEARCH_MAX_HZ and limited_in_a_row < FAKE_LIMITED_TRIALS:
        loss_free, limited = attempt(rate)
        if not loss_free:
            bad = rate
            break
        good = rate
        limited_in_a_row = limited_in_a_row + 1 if limited else 0
        rate *= 2.0
    if bad is not None:
        for _ in range(BISECTION_STEPS):
            middle = 0.5 * (good + bad)
            if attempt(middle)[0]:
                good = middle
            else:
                bad = middle
    return best, bad is None, log


def _short(result: dict) -> str:
    keys = ("delivered", "fake_sent", "caught_up", "lost", "duplicate", "out_of_order", "overflowed",
            "queue_dropped", "fake_send_errors", "cpu_percent")
    return ", ".join(f"{k} {result[k]:.0f}" if isinstance(result[k], float) else f"{k} {result[k]}"
                     for k in keys if k in result)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10 s at 7 kHz and 2 s trials (CI)")
    parser.add_argument("--seconds", type=float, help="length of the 7 kHz run (overrides --quick)")
    parser.add_argument("--no-search", action="store_true", help="only the 7 kHz run")
    args = parser.parse_args(argv)
    seconds = args.seconds or (QUICK_SECONDS if args.quick else FULL_SECONDS)
    trial_s = QUICK_TRIAL_S if args.quick else FULL_TRIAL_S

    fake = FakeProcess(RATE_HZ)
    try:
        result = driver_run(fake, seconds, latency=True)
    finally:
        fake.close()
    print(f"7 kHz run, {seconds:.0f} s, fake in its own process, one record per datagram:")
    print(f"  samples {result['samples']}, lost {result['lost']}, duplicate {result['duplicate']}, "
          f"out of order {result['out_of_order']}, reconnects {result['reconnects']} "
          f"(fake sent {result['fake_sent']}, {result['fake_rate_hz']:.0f} Hz)")
    print(f"  CPU {result['cpu_percent']:.1f} % of one core (driver process: receive thread + read + compensate)")
    print(f"  latency receive stamp → compensated: p50 {result.get('p50_latency_ms', float('nan')):.2f} ms, "
          f"p99 {result.get('p99_latency_ms', float('nan')):.2f} ms; fake's send schedule → compensated (upper "
          f"bound): p50 {result.get('p50_schedule_latency_ms', float('nan')):.2f} ms, "
          f"p99 {result.get('p99_schedule_latency_ms', float('nan')):.2f} ms")
    print(f"  mean compensated wrench {np.array2string(result.get('mean_contact', np.zeros(6)), precision=3)} "
          f"(≈ 0: the fake holds the truth's tool at a fixed pose); SO_RCVBUF {result['receive_buffer_bytes']} B")
    if args.no_search:
        return 0

    fake = FakeProcess(RATE_HZ, max_rate_hz=MAX_RATE_FAKE_HZ)
    try:
        single, single_limited, log_single = search(
            lambda rate: driver_run(fake, trial_s, f"&rate_hz={rate:.0f}&buffer_size=1"), "driver 0x0002")
        buffered, buffered_limited, log_buffered = search(
            lambda rate: driver_run(fake, trial_s, f"&rate_hz={rate:.0f}&buffered=1&buffer_size={BUFFERED_RECORDS}"),
            "driver 0x0003")
        try:
            import pynetft  # noqa: F401

            fake.ask("buffer 1")
            theirs, theirs_limited, log_theirs = search(lambda rate: pynetft_run(fake, rate, trial_s), "pynetft")
        except ImportError:
            theirs, theirs_limited, log_theirs = float("nan"), False, ["  pynetft not installed"]
    except DeviceError as error:
        print(f"rate search failed: {error}", file=sys.stderr)
        return 1
    finally:
        fake.close()
    print(f"Highest loss-free rate on loopback ({trial_s:.0f} s trials; the fake runs unpaced above 7 kHz):")
    for line in log_single + log_buffered + log_theirs:
        print(line)

    def fmt(rate: float, limited: bool) -> str:
        return f"≥ {rate:.0f} Hz (fake-limited)" if limited else f"{rate:.0f} Hz"

    print(f"  our driver, one record per datagram: {fmt(single, single_limited)}")
    print(f"  our driver, buffered {BUFFERED_RECORDS} records per datagram: {fmt(buffered, buffered_limited)}")
    print(f"  pynetft (one record per datagram only): {fmt(theirs, theirs_limited)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
