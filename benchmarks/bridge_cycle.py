"""Micro-benchmark: the bridge's feed loop (procedures/bridge.py ``Bridge._feed``) per controller cycle, CPU only.

    .venv/bin/python benchmarks/bridge_cycle.py                    # dynamic, static and raw, 5000 cycles each
    .venv/bin/python benchmarks/bridge_cycle.py --model dynamic --profile     # cProfile of the loop
    .venv/bin/python benchmarks/bridge_cycle.py --save /tmp/fed.npz          # the fed values, to compare later
    .venv/bin/python benchmarks/bridge_cycle.py --compare /tmp/fed.npz       # max relative difference to them

No sockets, no other process: a scripted controller input hands the feed loop one synthetic 500 Hz cycle after
another (a smooth motion of all six joints; target q̇ leaves actual q̇ for 0.2 s every 2 s, so the dynamic model
takes the derivative path there too; packages arrive 0.1-0.5 ms after their controller time) and a scripted
Net F/T driver (drivers/netft: sequence tracking, decoding) reads the 7 kHz RDT records that had arrived by then
from a scripted receive ring (≈ 14 a cycle, arrival stamps with a coalesced receive delay). Everything is deterministic (seeded, its own clock), so two versions of the code can
be compared value for value; the watchdog limits are opened wide (the script's clock is not the host's).

The figure is the calling thread's CPU time (``time.thread_time``) over a fixed number of cycles, per cycle:
on a shared machine it does not depend on the other jobs as wall-clock time would (benchmarks/README.md,
"Controller bridge, per cycle").
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CONTROLLER_RATE_HZ = 500.0
SENSOR_RATE_HZ = 7000.0
CYCLES = 5000
WARMUP_CYCLES = 300
MOTION_AMPLITUDE_RAD = np.array([0.6, 0.3, 0.4, 0.8, 0.8, 1.0])
MOTION_PERIOD_S = np.array([3.1, 2.3, 2.9, 1.7, 1.3, 1.9])
OFF_TRACK_EVERY_S, OFF_TRACK_S = 2.0, 0.2
"""target q̇ differs from actual q̇ by more than the tracking tolerance for OFF_TRACK_S every OFF_TRACK_EVERY_S."""
EPOCH_S = 1000.0
"""Host time of the first cycle (the script's own clock)."""
COUNTS_PER_UNIT = 1e6


class ScriptedReceiver:
    """Stands in for drivers/netft/receiver.py's RdtReceiver: :meth:`take` hands the real Net F/T driver the RDT
    records (big-endian, as on the wire) that had arrived by :attr:`now_s`."""

    def __init__(self, cycles: int, seed: int) -> None:
        from drivers.netft.protocol import RECORD_DTYPE
        from drivers.sensor import SensorHealth

        rng = np.random.default_rng(seed)
        n = int((cycles + 10) / CONTROLLER_RATE_HZ * SENSOR_RATE_HZ)
        generated = EPOCH_S - 0.01 + np.arange(n) / SENSOR_RATE_HZ
        # the receive thread wakes every 0.3 ms and stamps what arrived since (plus a few longer stalls)
        wake = 0.0003 * np.ceil((generated + 5e-5 + rng.exponential(5e-5, n)) / 0.0003)
        stalls = rng.random(n) < 0.002
        wake[stalls] += rng.uniform(0.0, 0.003, int(stalls.sum()))
        self.arrival_s = np.maximum.accumulate(wake)
        wrench = np.array([3.0, -1.0, 12.0, 0.1, -0.3, 0.05]) + rng.normal(
            0.0, [0.05, 0.05, 0.08, 0.002, 0.002, 0.0015], (n, 6))
        wrench += 2.0 * np.sin(np.outer(generated, [1.0, 0.7, 0.3, 0.2, 0.9, 1.3]))
        self.records = np.zeros(n, dtype=RECORD_DTYPE)
        self.records["rdt_sequence"] = 1 + np.arange(n)
        self.records["ft_sequence"] = 50_000 + np.arange(n)
        self.records["counts"] = np.round(wrench * COUNTS_PER_UNIT)
        self.counters = SensorHealth()
        self.thread_error: BaseException | None = None
        self.now_s = -np.inf
        self.consumed = self.written = 0

    def take(self) -> tuple[np.ndarray, np.ndarray, int]:
        start = self.consumed
        self.written = end = max(int(np.searchsorted(self.arrival_s, self.now_s, side="right")), start)
        self.consumed = end
        return self.records[start:end].copy(), self.arrival_s[start:end].copy(), start

    def wait(self, timeout_s: float, stopped) -> None:
        pass

    def problems(self) -> str:
        return ""

    overflowed = 0

    def socket_drops(self) -> int | None:
        return None  # no socket


def scripted_sensor(cycles: int, seed: int):
    """The real Net F/T driver (drivers/netft/driver.py: sequence tracking, decoding, the sensor contract) reading
    from a :class:`ScriptedReceiver`."""
    from drivers.netft import NetFTSensor
    from drivers.netft.discovery import Discovered, Scaling

    sensor = NetFTSensor("192.0.2.1")
    scaling = Scaling(COUNTS_PER_UNIT, COUNTS_PER_UNIT, "N", "N-m", "benchmark")
    sensor._apply(Discovered(scaling=scaling, status_map="netft", rate_hz=SENSOR_RATE_HZ, buffer_size=1))
    receiver = ScriptedReceiver(cycles, seed)
    sensor._receiver = receiver  # type: ignore[assignment]
    sensor._started = True
    return sensor, receiver


class ScriptedInput:
    """What the bridge needs of drivers/ur_ft_input.URForceTorqueInput: synthetic cycles; stops the feed after
    ``cycles``."""

    frequency_hz = CONTROLLER_RATE_HZ

    def __init__(self, receiver: ScriptedReceiver, cycles: int, seed: int, q0: np.ndarray) -> None:
        rng = np.random.default_rng(seed + 1)
        self.receiver, self.cycles = receiver, cycles
        t = np.arange(cycles) / CONTROLLER_RATE_HZ
        phase = 2 * np.pi * t[:, None] / MOTION_PERIOD_S
        omega = 2 * np.pi / MOTION_PERIOD_S
        self.timestamp_s = 12_345.0 + t
        self.q = q0 + MOTION_AMPLITUDE_RAD * np.sin(phase)
        self.qd = MOTION_AMPLITUDE_RAD * omega * np.cos(phase) + rng.normal(0.0, 1e-4, (cycles, 6))
        self.qdd = -MOTION_AMPLITUDE_RAD * omega ** 2 * np.sin(phase)
        off_track = np.mod(t, OFF_TRACK_EVERY_S) < OFF_TRACK_S
        self.target_qd = self.qd + np.where(off_track[:, None], 0.05, 0.0)
        self.received_s = EPOCH_S + t + rng.uniform(1e-4, 5e-4, cycles)
        self.written: list[np.ndarray] = []
        self.stop = None
        self._k = 0

    def next_cycle(self, timeout_s: float = 0.1):
        from drivers.ur_ft_input import ControllerCycle

        k = self._k
        if k == self.cycles - 1 and self.stop is not None:
            self.stop.set()  # the feed loop ends after this cycle
        self._k += 1
        self.receiver.now_s = self.received_s[k] + 1e-4  # the feed reads the sensor ≈ 0.1 ms after the package
        return ControllerCycle(timestamp_s=float(self.timestamp_s[k]), q=self.q[k].copy(), qd=self.qd[k].copy(),
                               tcp_force=np.zeros(6), runtime_state=2, safety_status_bits=1,
                               received_s=float(self.received_s[k]), tcp_pose=np.zeros(6),
                               target_qd=self.target_qd[k].copy(), target_qdd=self.qdd[k].copy())

    def queued(self) -> bool:
        return False  # a scripted cycle is always the newest: no start-up backlog

    def write(self, wrench) -> None:
        self.written.append(np.asarray(wrench))


def build(model: str, cycles: int, seed: int):
    """A Bridge on the scripted sensor and input (not started)."""
    from ftacq.bridge_convention import plan_feed
    from ftacq.kinematics import ur_model
    from procedures.bridge import Bridge, BridgeSettings, _Log
    from procedures.plan import home_configuration_rad
    from tests.fakes.world import CellTruth

    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m))
    if model == "dynamic":
        calibration = replace(calibration, inertia=truth.inertia)
    sensor, receiver = scripted_sensor(cycles, seed)
    controller = ScriptedInput(receiver, cycles, seed, home_configuration_rad("floor"))
    plan = plan_feed(calibration, "raw" if model == "raw" else "compensated", truth.sensor_offset_m,
                     sensor_body_kg=0.3)
    settings = BridgeSettings(max_staleness_s=1e12, jump_force_n=1e12, jump_torque_nm=1e12, realtime_priority=0)
    bridge = Bridge(sensor, controller, None, plan, calibration, ur_model("UR5e"), settings,  # type: ignore[arg-type]
                    sensor_rate_hz=SENSOR_RATE_HZ)
    controller.stop = bridge._stop_feeding
    bridge._log = _Log(cycles)
    return bridge


BREAKDOWN = (("input", "next_cycle"), ("states", "append"), ("sensor", "read"), ("bridge", "_sensor_frame"),
             ("dynamic.clock", "host_times"), ("dynamic", "_update_predictions"), ("bridge", "filter"),
             ("plan", "fed_wrench"), ("input", "write"))
"""The parts of a cycle ``--breakdown`` times (object path from the bridge, attribute)."""


def timed(parts: dict[str, list[float]], name: str, function):
    """``function`` adding its thread CPU time to ``parts[name]``."""
    clock = time.thread_time
    spent = parts.setdefault(name, [0.0])

    def wrapper(*args, **kwargs):
        start = clock()
        try:
            return function(*args, **kwargs)
        finally:
            spent[0] += clock() - start
    return wrapper


def instrument(bridge) -> dict[str, list[float]]:
    """Wrap the :data:`BREAKDOWN` parts that exist on this bridge (inner ones are included in outer ones)."""
    parts: dict[str, list[float]] = {}
    for path, attribute in BREAKDOWN:
        owner = bridge
        for step in path.split(".")[1:] if path.startswith("bridge") else path.split("."):
            owner = getattr(owner, step, None)
        if owner is None or not hasattr(owner, attribute):
            continue
        object.__setattr__(owner, attribute, timed(parts, f"{path}.{attribute}", getattr(owner, attribute)))
    return parts


def run(model: str, cycles: int, seed: int, profile: bool, breakdown: bool = False) -> tuple[float, np.ndarray]:
    """Feed ``cycles`` scripted cycles; return (CPU µs per cycle after the warm-up, the fed values (cycles, 6))."""
    from procedures.bridge import FED_COLUMNS

    bridge = build(model, cycles, seed)
    parts = instrument(bridge) if breakdown else {}
    controller = bridge.input
    assert isinstance(controller, ScriptedInput)
    marks: list[float] = []
    original = controller.next_cycle

    def next_cycle(timeout_s: float = 0.1):
        if controller._k in (WARMUP_CYCLES, cycles - 1):
            marks.append(time.thread_time())
        return original(timeout_s)

    controller.next_cycle = next_cycle  # type: ignore[method-assign]
    profiler = cProfile.Profile() if profile else None
    if profiler is not None:
        profiler.enable()
    bridge._feed()
    if profiler is not None:
        profiler.disable()
        pstats.Stats(profiler).sort_stats("tottime").print_stats(25)
    if bridge._trip:
        raise SystemExit(f"{model}: the feed tripped: {bridge._trip}")
    fed = bridge._log.rows(bridge._log.first_kept, bridge._log.count)[:, FED_COLUMNS].copy()
    for name, spent in parts.items():
        print(f"    {name:34s} {1e6 * spent[0] / cycles:7.1f} µs per cycle (wrapper included)")
    return 1e6 * (marks[1] - marks[0]) / (cycles - 1 - WARMUP_CYCLES), fed


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", choices=("dynamic", "static", "raw"), action="append",
                        help="which compensation (repeatable; default all three)")
    parser.add_argument("--cycles", type=int, default=CYCLES)
    parser.add_argument("--repeat", type=int, default=3, help="runs per model; the fastest is reported")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--profile", action="store_true", help="print cProfile's top functions (one run)")
    parser.add_argument("--breakdown", action="store_true", help="time the parts of a cycle (one run)")
    parser.add_argument("--save", help="save the fed values (.npz)")
    parser.add_argument("--compare", help="compare the fed values with a saved .npz")
    args = parser.parse_args()
    models = args.model or ["dynamic", "static", "raw"]
    saved: dict[str, np.ndarray] = {}
    reference = np.load(args.compare) if args.compare else None
    for model in models:
        costs = []
        fed = np.empty((0, 6))
        for _ in range(1 if args.profile or args.breakdown else args.repeat):
            cost, fed = run(model, args.cycles, args.seed, args.profile, args.breakdown)
            costs.append(cost)
        saved[model] = fed
        line = (f"{model:8s} {min(costs):7.1f} µs CPU per cycle (best of {len(costs)}: "
                + ", ".join(f"{c:.1f}" for c in costs) + f"; {args.cycles} cycles, ≈ "
                f"{SENSOR_RATE_HZ / CONTROLLER_RATE_HZ:.0f} samples each)")
        if reference is not None and model in reference:
            ref = reference[model]
            if ref.shape != fed.shape:
                line += f"; fed values: shape {fed.shape} vs {ref.shape}"
            else:
                finite = np.isfinite(ref).all(axis=1)
                same_rows = np.array_equal(finite, np.isfinite(fed).all(axis=1))
                difference = np.abs(fed[finite] - ref[finite])
                elementwise = float(np.max(difference / np.maximum(np.abs(ref[finite]), 1e-300)))
                per_channel = float(np.max(difference / np.abs(ref[finite]).max(axis=0)))
                line += (f"; vs saved: max relative difference {elementwise:.1e} per value, {per_channel:.1e} of "
                         f"the channel's largest (rows alike: {same_rows})")
        print(line, flush=True)
    if args.save:
        np.savez(args.save, **saved)
    return 0


if __name__ == "__main__":
    sys.exit(main())
