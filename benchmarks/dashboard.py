"""Benchmark: the live monitor at 7 kHz: Net F/T driver → gravity compensation → Rerun logging to an .rrd file.

    .venv/bin/python benchmarks/dashboard.py            # 60 s
    .venv/bin/python benchmarks/dashboard.py --quick    # 10 s

The simulated Net F/T runs in its own process (``python -m tests.fakes.netft``), so only the monitor's own work
is charged: the driver's receive thread, compensation, the dashboard thread and Rerun's encoder/file threads.
Prints the samples the driver delivered, the samples lost (by the stream, and dropped for the viewer), the
samples read back from the .rrd with Rerun's reader, the chunks in the file (fewer load faster in the viewer),
and the CPU time of this process as a percentage of one core. Targets: 0 lost, < 60 % of one core.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.sensor import open_sensor  # noqa: E402
from ftacq.app.dashboard.layout import APP_ID, COMPENSATED_FORCE  # noqa: E402
from ftacq.app.dashboard.listener import DashboardListener  # noqa: E402
from ftacq.app.dashboard.recorder import FILE_SEND_PERIOD_S, Dashboard  # noqa: E402
from ftacq.app.dashboard.sinks import close_recording  # noqa: E402
from ftacq.kinematics import flange_pose, ur_model  # noqa: E402
from procedures.monitor import GravityCompensator, LiveMonitor  # noqa: E402
from tests.fakes.world import CellTruth  # noqa: E402
from tests.rrd_reader import read_scalars  # noqa: E402

RATE_HZ = 7000.0
FULL_SECONDS = 60.0
QUICK_SECONDS = 10.0
TARGET_CPU_PERCENT = 60.0
Q_RAD = np.array([0.3, -1.2, 1.4, -1.6, -1.5, 0.4])


class StillRobot:
    """The latest state of an arm standing still (the benchmark measures the sensor path, not the robot reader)."""

    def __init__(self, model, q_rad: np.ndarray) -> None:
        self.q_rad = np.asarray(q_rad, dtype=float)
        self.pose = flange_pose(model, self.q_rad)

    def joint_positions(self) -> np.ndarray:
        return self.q_rad

    def flange_pose(self) -> np.ndarray:
        return self.pose


def start_fake_sensor(rate_hz: float) -> tuple[subprocess.Popen, dict]:
    """Start ``python -m tests.fakes.netft`` in its own process; return it and the ports it printed as JSON."""
    process = subprocess.Popen(
        [sys.executable, "-m", "tests.fakes.netft", "--rate-hz", str(rate_hz)],
        cwd=ROOT, stdout=subprocess.PIPE, stdin=subprocess.PIPE, text=True)
    line = process.stdout.readline()
    if not line:
        process.kill()
        raise RuntimeError("the fake Net F/T exited before printing its ports")
    return process, json.loads(line)


def stop_fake_sensor(process: subprocess.Popen) -> None:
    """Ask the fake to exit (close its stdin), then wait; kill it if it does not stop in time."""
    try:
        process.stdin.close()
        process.wait(timeout=5.0)
    except subprocess.TimeoutExpired:
        process.terminate()
        process.wait(timeout=5.0)


def sensor_url(ports: dict, rate_hz: float) -> str:
    """Return the netft:// URL of the fake from its printed ports."""
    if "url" in ports:
        return ports["url"]
    host = ports.get("host", "127.0.0.1")
    return (f"netft://{host}:{ports['rdt_port']}?tcp_port={ports['tcp_port']}&http_port={ports['http_port']}"
            f"&rate_hz={rate_hz:g}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help=f"run {QUICK_SECONDS:.0f} s instead of {FULL_SECONDS:.0f} s")
    parser.add_argument("--seconds", type=float, help="run this many seconds (overrides --quick)")
    parser.add_argument("--rate-hz", type=float, default=RATE_HZ, help="sensor rate in Hz (default %(default)s)")
    parser.add_argument("--keep", type=Path, help="keep the .rrd at this path (default: a temporary file)")
    args = parser.parse_args(argv)
    seconds = args.seconds or (QUICK_SECONDS if args.quick else FULL_SECONDS)

    import rerun as rr

    model = ur_model("UR5e")
    calibration = CellTruth().calibration()
    fake, ports = start_fake_sensor(args.rate_hz)
    with tempfile.TemporaryDirectory() as tmp:
        rrd_path = args.keep or Path(tmp) / "benchmark.rrd"
        try:
            sensor = open_sensor(sensor_url(ports, args.rate_hz))
            sensor.start()
            try:
                recording = rr.RecordingStream(APP_ID, recording_id=uuid.uuid4())
                recording.save(rrd_path)
                dashboard = DashboardListener(Dashboard(recording, send_period_s=FILE_SEND_PERIOD_S), model=model)
                dashboard.set_calibration(calibration)
                monitor = LiveMonitor(sensor, robot=StillRobot(model, Q_RAD),
                                      compensator=GravityCompensator(calibration), listeners=[dashboard])
                lost_before = sensor.health().lost
                cpu_start_s, wall_start_s = time.process_time(), time.monotonic()
                summary = monitor.run(duration_s=seconds)
                dashboard.flush()
                close_recording(recording)
                cpu_s, wall_s = time.process_time() - cpu_start_s, time.monotonic() - wall_start_s
                health = sensor.health()
            finally:
                sensor.close()
        finally:
            stop_fake_sensor(fake)
        stored, _ = read_scalars(rrd_path, COMPENSATED_FORCE)
        from rerun.chunk import RrdReader

        chunks = sum(1 for _ in RrdReader(rrd_path).stream().to_chunks())

    lost = health.lost - lost_before
    cpu_percent = 100.0 * cpu_s / wall_s
    print(f"dashboard benchmark: {seconds:.0f} s at {args.rate_hz:.0f} Hz through the Net F/T driver, compensation "
          f"and Rerun logging to an .rrd file")
    print(f"samples        {summary.samples} delivered by the driver over {summary.span_s:.2f} s of receive time "
          f"= {summary.rate_hz:.0f} Hz (host monotonic clock)")
    print(f"lost           {lost} by the stream, {summary.dropped_samples} dropped for the viewer")
    print(f"in the .rrd    {stored.size} compensated samples read back; {chunks} chunks ({chunks / seconds:.1f} per s "
          f"of run; streams sent every {FILE_SEND_PERIOD_S:g} s of data)")
    print(f"CPU            {cpu_percent:.1f} % of one core ({cpu_s:.1f} s CPU in {wall_s:.1f} s; the fake sensor's "
          f"process not counted)")
    ok = lost == 0 and summary.dropped_samples == 0 and cpu_percent < TARGET_CPU_PERCENT
    print(f"target         0 lost, < {TARGET_CPU_PERCENT:.0f} % of one core: {'met' if ok else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
