"""Benchmark: how fast the ATI CAN driver polls the fake NETCANOEM board on python-can's virtual bus.

    .venv/bin/python benchmarks/can_poll.py            # 10 s per run
    .venv/bin/python benchmarks/can_poll.py --quick    # 2 s per run

Both ends live in this process (the ``virtual`` interface is in-process only), so the figure is the Python cost
of one poll (1 request + 2 reply frames, each deep-copied by the virtual bus, and the fake's physics) on this
machine, not a CAN bus limit: a real 250 kbit/s bus carries ~300 bits per poll, i.e. at most ~800 polls/s
(~3 300 at 1 Mbit/s). Prints, for an unpaced run and for paced runs: polls answered per second, unanswered
polls, the wrench error against the noiseless physics, and the CPU time of this process as % of one core.
"""

from __future__ import annotations

import argparse
import sys
import time
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.ati_can import AtiCanSensor  # noqa: E402
from drivers.sensor import WrenchBatch  # noqa: E402
from tests.fakes.netcanoem import FakeNetCanOem  # noqa: E402
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose  # noqa: E402

FULL_SECONDS = 10.0
QUICK_SECONDS = 2.0
PACED_RATES_HZ = (500.0, 1000.0)
READ_TIMEOUT_S = 1.0


def run(rate_hz: float | None, seconds: float) -> dict:
    """Poll for ``seconds`` at ``rate_hz`` (None = as fast as the board answers); return the figures."""
    channel = f"bench-{uuid.uuid4()}"
    pose = SettablePose()
    physics = SensorPhysics(CellTruth(force_noise_n=(0.0,) * 3, torque_noise_nm=(0.0,) * 3), pose)
    with FakeNetCanOem(channel, physics, counts_per_force=816_326, counts_per_torque=1_234, torque_unit_code=4) as board:
        with AtiCanSensor.from_url(f"can://virtual/{channel}", rate_hz=rate_hz) as sensor:
            sensor.read(timeout_s=READ_TIMEOUT_S)
            before = sensor.health()
            cpu0, wall0 = time.process_time(), time.monotonic()
            batches = []
            while time.monotonic() - wall0 < seconds:
                batches.append(sensor.read(timeout_s=READ_TIMEOUT_S))
            cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
            after = sensor.health()
        batch = WrenchBatch.concatenate(batches)
        error = np.abs(batch.wrench - physics.noiseless_wrench(pose.read()[0])).max(axis=0)
        within = bool(np.all(error <= board.active_calibration.quantisation_tolerance()))
    return {
        "requested": "unpaced" if rate_hz is None else f"{rate_hz:.0f} Hz",
        "samples": len(batch),
        "rate_hz": len(batch) / wall,
        "unanswered": (after.timeouts - before.timeouts) + (after.lost - before.lost),
        "within_one_count": within,
        "cpu_percent": 100.0 * cpu / wall,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help=f"{QUICK_SECONDS:.0f} s per run instead of {FULL_SECONDS:.0f} s")
    parser.add_argument("--seconds", type=float, default=None, help="seconds per run (overrides --quick)")
    args = parser.parse_args(argv)
    seconds = args.seconds or (QUICK_SECONDS if args.quick else FULL_SECONDS)
    print(f"ATI CAN driver ↔ fake NETCANOEM on python-can virtual, {seconds:.0f} s per run")
    print(f"{'requested':>10} {'samples':>8} {'rate Hz':>8} {'unanswered':>10} {'≤1 count':>8} {'CPU %':>6}")
    for rate_hz in (None, *PACED_RATES_HZ):
        r = run(rate_hz, seconds)
        print(f"{r['requested']:>10} {r['samples']:>8d} {r['rate_hz']:>8.0f} {r['unanswered']:>10d} "
              f"{str(r['within_one_count']):>8} {r['cpu_percent']:>6.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
