"""Benchmark: the CPU each simulated device costs, in its own process, with clients connected as in the tests.

    .venv/bin/python benchmarks/fakes_cpu.py               # 8 s per phase
    .venv/bin/python benchmarks/fakes_cpu.py --seconds 4   # shorter
    .venv/bin/python benchmarks/fakes_cpu.py --replay      # the devices' own work, CPU-s per simulated s

One :class:`tests.fakes.cell.SimulatedCell` with the Net F/T in its own process (``sensor_process=True``, the
default clocks: bursts, jitter, crystal errors) and the controller in its own (real time, servo lag, encoder
noise). Clients in this process: ur-rtde's ``RTDEReceiveInterface`` and ``RTDEControlInterface`` and the
product's :class:`drivers.ur_stream.URStateStream` on the controller; the product's
:class:`drivers.netft.NetFTSensor` reading the box. Each phase lasts ``--seconds``; a device's CPU is its
process's user + system time over the phase (``/proc/PID/stat``) as % of one core; "clients" is this process
(``time.process_time``: the drivers' threads and the reading loop).

Phases: **idle** (clients connected, arm still, box not streaming), **streaming** (the box at 7 kHz, arm still),
**moving** (the box at 7 kHz while the arm jogs back and forth between two configurations, 0.8 rad/s, 2 rad/s²).

``--replay``: no processes, sockets or clients: :func:`tests.fakes.replay.replay` steps the controller and polls the
box on a scripted clock (moveJs and a stop, :data:`tests.fakes.replay.JOINT_MOVES`) and reports each device's thread
CPU per simulated second, still and moving (the best of ``--rounds``): what the simulation itself costs, which a
loaded machine disturbs least.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.netft import NetFTSensor  # noqa: E402
from drivers.ur_stream import URStateStream  # noqa: E402
from tests.fakes.cell import SimulatedCell  # noqa: E402

CLOCK_TICKS_S = os.sysconf("SC_CLK_TCK")
RATE_HZ = 7000.0
JOG_SPEED_RAD_S, JOG_ACCELERATION_RAD_S2 = 0.8, 2.0
JOG_SWING_RAD = np.array([0.4, -0.3, 0.3, 0.3, 0.3, 0.4])


def process_cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` (every thread) from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS_S


def measure(pids: dict[str, int], seconds: float, work=None) -> dict[str, float]:
    """% of one core each process (and this one, "clients") used over ``seconds`` while ``work()`` runs."""
    print(f"phase of {seconds:g} s starts (pids {pids})", file=sys.stderr, flush=True)
    before = {name: process_cpu_s(pid) for name, pid in pids.items()}
    own, wall = time.process_time(), time.monotonic()
    end = wall + seconds
    while time.monotonic() < end:
        (work or (lambda: time.sleep(0.05)))()
    wall = time.monotonic() - wall
    out = {name: 100.0 * (process_cpu_s(pid) - before[name]) / wall for name, pid in pids.items()}
    out["clients"] = 100.0 * (time.process_time() - own) / wall
    return out


def replay_figures(rounds: int) -> int:
    """Print each device's CPU-s per simulated second, still and moving, the best of ``rounds`` replays."""
    from tests.fakes.replay import JOINT_MOVES, replay

    best: dict[tuple[str, str], float] = {}
    for _ in range(rounds):
        for key, value in replay(script=JOINT_MOVES).cpu_per_simulated_s().items():
            best[key] = min(best.get(key, value), value)
    print(f"{'device':<11} {'still':>7} {'moving':>7}  (CPU-s per simulated s, best of {rounds})")
    for device in ("controller", "netft"):
        print(f"{device:<11} {best[device, 'still']:>7.3f} {best[device, 'moving']:>7.3f}")
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=8.0, help="length of each phase, s")
    parser.add_argument("--replay", action="store_true", help="the scripted replay instead of the processes")
    parser.add_argument("--rounds", type=int, default=3, help="replays (--replay); the best of them is shown")
    args = parser.parse_args(argv)
    if args.replay:
        return replay_figures(args.rounds)

    import rtde_control
    import rtde_receive

    with SimulatedCell(sensor="netft", time_scale=1.0, rate_hz=RATE_HZ, sensor_process=True) as cell:
        controller, box = cell.controller, cell.netft
        pids = {"controller": controller.pid, "netft": box.pid}
        receive = rtde_receive.RTDEReceiveInterface(controller.host)
        control = rtde_control.RTDEControlInterface(controller.host)
        stream = URStateStream(controller.host).start()
        sensor = NetFTSensor.from_url(cell.sensor_url, timeout_s=1.0)
        samples = [0]
        stop = threading.Event()

        def read_sensor() -> None:
            while not stop.is_set():
                samples[0] += len(sensor.read(timeout_s=1.0))

        rows = {}
        try:
            time.sleep(1.0)  # connections settle
            rows["idle"] = measure(pids, args.seconds)
            sensor.start()
            reader = threading.Thread(target=read_sensor, name="bench-reader")
            reader.start()
            time.sleep(1.0)
            rows["streaming"] = measure(pids, args.seconds)
            home = np.array(receive.getActualQ())
            targets = [home + JOG_SWING_RAD, home]
            moving_until = [0.0]

            def jog() -> None:
                if time.monotonic() >= moving_until[0]:
                    duration = controller.jog(targets[0], JOG_SPEED_RAD_S, JOG_ACCELERATION_RAD_S2)
                    targets.reverse()
                    moving_until[0] = time.monotonic() + duration
                time.sleep(0.02)

            rows["moving"] = measure(pids, args.seconds, jog)
            controller.wait_for(lambda s: not s["moving"], timeout_s=10.0)
            stop.set()
            reader.join()
            health = sensor.health()
        finally:
            stop.set()
            sensor.close()
            stream.close()
            control.disconnect()
            receive.disconnect()
    print(f"{'phase':<10} {'controller %':>13} {'netft %':>8} {'clients %':>10}")
    for phase, row in rows.items():
        print(f"{phase:<10} {row['controller']:>13.1f} {row['netft']:>8.1f} {row['clients']:>10.1f}")
    print(f"samples read: {samples[0]}; {health}; load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
