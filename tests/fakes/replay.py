"""A scripted, clock-driven run of the simulated controller and Net F/T, without sockets or threads: what each puts
on the wire (RTDE data packages, RDT datagrams) for one seed and one command script, on a fake host clock.

The simulated devices read ``time.monotonic()``; :func:`replay` replaces it by a :class:`ScriptedClock` for the
run, steps the controller at 500 Hz (with a seeded tick jitter) and asks the box for its due datagrams when its
next burst is due, as the devices' threads do, through the same calls (:meth:`URSimulator.step`, :class:`SharedPose`, the
RTDE output plan, :meth:`NetFTBox.due_datagrams`). Used by tests/test_fakes_replay.py (the fakes' outputs do not
change when their hot paths are restructured) and benchmarks/fakes_cpu.py ``--replay`` (CPU per simulated second,
which a loaded machine disturbs least).
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from ftacq.kinematics import ur_model
from tests.fakes.netft_box import NetFTBox
from tests.fakes.netft_protocol import RDT_HEADER, RDT_START
from tests.fakes.rtde_protocol import OUTPUT_TYPES, Recipe
from tests.fakes.ur_controller import _OutputPlan
from tests.fakes.ur_simulator import URSimulator
from tests.fakes.world import CellTruth, SensorPhysics, SharedPose

TICK_S = 0.002
"""The controller's tick (e-Series, 500 Hz)."""
BOX_WAKE_S = 0.0001
"""The box's thread wakes this long after its next burst is due at the earliest (select's latency)."""
WARM_UP_TICKS = 50
"""The first ticks (imports, first calls) are counted apart, as phase "warm-up"."""
OUTPUTS = ("timestamp", "target_q", "target_qd", "target_qdd", "actual_q", "actual_qd", "actual_TCP_pose",
           "actual_TCP_speed", "actual_TCP_force", "target_TCP_pose", "target_TCP_speed", "joint_temperatures",
           "robot_mode", "joint_mode", "safety_mode", "actual_tool_accelerometer", "speed_scaling",
           "target_speed_fraction", "runtime_state", "robot_status_bits", "safety_status_bits", "payload",
           "output_int_register_0", "output_double_register_0", "tcp_offset")
"""An output recipe like ur-rtde's receive interface's (the pose, speed and accelerometer fields computed each tick)."""


class ScriptedClock:
    """A host clock the script sets (``time.monotonic``'s stand-in), s."""

    def __init__(self, start_s: float = 1000.0) -> None:
        self.now_s = start_s

    def __call__(self) -> float:
        return self.now_s


@contextmanager
def scripted_time(clock: ScriptedClock) -> Iterator[None]:
    """Make ``time.monotonic`` read ``clock`` for the duration (the fakes call it through the ``time`` module)."""
    original = time.monotonic
    time.monotonic = clock  # type: ignore[assignment]
    try:
        yield
    finally:
        time.monotonic = original  # type: ignore[assignment]


@dataclass
class Cell:
    """The scripted cell's devices (built by :func:`build_cell`, under a scripted clock)."""

    clock: ScriptedClock
    sim: URSimulator
    shared: SharedPose
    physics: SensorPhysics
    box: NetFTBox
    plan: _OutputPlan
    packages: list[bytes] = field(default_factory=list)
    datagrams: list[bytes] = field(default_factory=list)
    cpu_s: dict[tuple[str, str], float] = field(default_factory=dict)
    """(device, phase) → thread CPU seconds: device "controller" (tick, shared pose, RTDE package) or "netft" (the
    box's polls), phase "moving" (the arm's joint state not at rest) or "still"."""
    ticks: dict[str, int] = field(default_factory=dict)
    """phase → ticks spent in it."""

    def tick(self, k: int, t0_s: float, jitter_s: float) -> None:
        """Controller tick ``k`` (at ``t0_s`` + k ticks + ``jitter_s``), then the box's polls within it."""
        start = time.thread_time()
        self.clock.now_s = t0_s + k * TICK_S + jitter_s
        snap = self.sim.step(self.clock.now_s)
        self.shared.set(snap["flange_pose"], snap["joint_speed_norm"], snap["joint_state"])
        self.packages.append(self.plan.package(snap))
        middle = time.thread_time()
        tick_end_s = t0_s + (k + 1) * TICK_S
        while True:  # the box's thread: asleep until its next burst is due, as tests/fakes/netft.py's RDT loop
            due_s = self.clock.now_s + max(self.box.next_send_in_s(self.clock.now_s), BOX_WAKE_S)
            if due_s >= tick_end_s:
                break
            self.clock.now_s = due_s
            self.datagrams += self.box.due_datagrams(due_s)[0]
        end = time.thread_time()
        phase = "warm-up" if k < WARM_UP_TICKS else "still" if snap["joint_state"].at_rest else "moving"
        self.ticks[phase] = self.ticks.get(phase, 0) + 1
        for device, cpu_s in (("controller", middle - start), ("netft", end - middle)):
            self.cpu_s[device, phase] = self.cpu_s.get((device, phase), 0.0) + cpu_s

    def cpu_per_simulated_s(self) -> dict[tuple[str, str], float]:
        """(device, phase) → CPU seconds per simulated second in that phase."""
        return {(device, phase): cpu_s / (self.ticks[phase] * TICK_S) for (device, phase), cpu_s in self.cpu_s.items()}


def build_cell(clock: ScriptedClock, seed: int = 7) -> Cell:
    """The simulated cell's defaults (encoder noise, servo lag, clock errors, bursts); call under the clock."""
    model = ur_model("UR5e")
    sim = URSimulator(model, encoder_noise_rad=1e-6, seed=seed, servo_lag_s=0.004, clock_rate_error=20e-6)
    shared = SharedPose(create=True)
    physics = SensorPhysics(CellTruth(), shared, seed=seed, robot=model, rate_hz=7000.0, start_time_s=clock())
    box = NetFTBox(physics, rate_hz=7000.0, seed=seed, clock_rate_error=150e-6, burst_interval_s=0.002,
                   burst_jitter_s=0.001)
    box.handle_rdt(struct.pack(">HHI", RDT_HEADER, RDT_START, 0), ("127.0.0.1", 1), clock())
    return Cell(clock, sim, shared, physics, box, _OutputPlan(Recipe.build(1, list(OUTPUTS), OUTPUT_TYPES)))


def _move(kind: str, swing: tuple[float, ...], speed: float, acceleration: float) -> Callable[[URSimulator], None]:
    def command(sim: URSimulator) -> None:
        if kind == "movej":
            target = sim.q + np.array(swing)
        else:
            target = sim.flange_pose() + np.array(swing)
        with sim.lock:
            assert sim._start_move(kind, target, speed, acceleration, False), kind
    return command


def _stop(deceleration: float) -> Callable[[URSimulator], None]:
    def command(sim: URSimulator) -> None:
        with sim.lock:
            sim._begin_stop(deceleration)
    return command


def _set(**values) -> Callable[[URSimulator], None]:
    def command(sim: URSimulator) -> None:
        with sim.lock:
            for name, value in values.items():
                setattr(sim, name, value)
    return command


SCRIPT: dict[int, Callable[[URSimulator], None]] = {
    100: _move("movej", (0.4, -0.3, 0.3, 0.3, 0.3, 0.4), 0.8, 2.0),
    300: _set(tool_motion_outputs=False),                   # no client asks for the TCP speed or accelerometer
    520: _stop(3.0),                                        # a stop mid-move: deceleration, then ring-down
    700: _set(tool_motion_outputs=True),
    800: _set(tcp_offset=np.array([0.0, 0.01, 0.12, 0.0, 0.0, 0.3])),
    820: _move("movel", (0.02, -0.015, 0.01, 0.0, 0.0, 0.0), 0.1, 0.5),
    1080: _set(speed_slider=0.5),                           # a slower slider: motion time runs at half rate
    1100: _move("movej", (-0.3, 0.2, -0.2, -0.2, -0.3, -0.3), 1.0, 3.0),
    2200: _set(speed_slider=1.0),
}
"""Tick → command: a joint move stopped midway (part of it while no client asks for the tool's motion outputs), a
linear move with a TCP offset, a joint move at half speed, then
the arm at rest (still from about tick 3100: 2 s of motion time after the last change of q̈)."""

JOINT_MOVES: dict[int, Callable[[URSimulator], None]] = {
    100: _move("movej", (0.4, -0.3, 0.3, 0.3, 0.3, 0.4), 0.8, 2.0),
    520: _stop(3.0),
    800: _move("movej", (-0.4, 0.3, -0.3, -0.3, -0.3, -0.4), 1.0, 3.0),
    1400: _move("movej", (0.2, -0.2, 0.2, 0.2, 0.2, 0.2), 1.0, 3.0),
}
"""Tick → command: moveJ only, no TCP offset, as the procedures move (the benchmark's script); at rest from about
tick 2500."""


def replay(ticks: int = 4500, seed: int = 7, script: dict[int, Callable[[URSimulator], None]] | None = None,
           on_tick: Callable[[Cell, int], None] | None = None) -> Cell:
    """Run the scripted cell for ``ticks`` controller ticks and return it (its packages and datagrams)."""
    clock = ScriptedClock()
    jitter = np.random.default_rng([seed, 99]).uniform(0.0, 0.0003, ticks)
    script = SCRIPT if script is None else script
    with scripted_time(clock):
        cell = build_cell(clock, seed)
        try:
            t0 = clock.now_s + TICK_S
            for k in range(ticks):
                if k in script:
                    script[k](cell.sim)
                cell.tick(k, t0, float(jitter[k]))
                if on_tick is not None:
                    on_tick(cell, k)
        finally:
            cell.shared.close()
    return cell
