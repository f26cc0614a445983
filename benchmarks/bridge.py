"""Benchmark: ``ftacq bridge`` on the simulated cell, the arm jogging and the tool pushed now and then.

    .venv/bin/python benchmarks/bridge.py            # 60 s of feeding
    .venv/bin/python benchmarks/bridge.py --quick    # 10 s
    .venv/bin/python benchmarks/bridge.py --feed raw
    .venv/bin/python benchmarks/bridge.py --moves dynamic   # real moveJ moves; calibration with the tool's inertia
    .venv/bin/python benchmarks/bridge.py --moves static    # the same moves; calibration without it

Three processes, as on a real cell: the simulated UR controller (tests/fakes/ur_controller.py, 500 Hz), a "world"
process (this script with ``--world``: the simulated Net F/T at 7 kHz whose wrench follows the controller's flange
pose, a technician jogging the arm at 30 Hz through the controller's back door, and a push of
:data:`CONTACT` on the tool for 2 s every 8 s), and this process running only what ``ftacq bridge`` runs: the real
ur-rtde control and receive interfaces, the Net F/T driver, drivers/ur_ft_input.py and procedures/bridge.py.

Printed figures (all from what the simulated controller recorded, not from what the bridge meant to send):

- controller cycles counted while enabled, fed / missed (a cycle is fed when a new value arrived since the
  previous output package to the feeding connection; the simulated controller reads what reached its socket at the
  start of each cycle, as a real one does). Each missed cycle is put down to one cause (:func:`attribute_misses`):
  the simulated controller's own delay, a machine stall seen by benchmarks/stall_probe.py, no answer, the way to
  the bridge, the bridge, the way back (all processes share one 2-core machine: the simulated controller is a
  Python process, not a real-time one); the simulated controller's package spacing is printed beside it;
- the bridge's answer time (package received → value written, this process) p50 / p99 / max, the feed thread's
  scheduling (SCHED_FIFO where allowed, docs/bridge.md "Timing");
- latency sensor sample → controller: from the driver's receive stamp of the newest sample a value includes to the
  controller's arrival stamp of that value (one CLOCK_MONOTONIC for all processes), p50 / p99 / max, over the values
  that carry samples received since the previous cycle (a value that repeats the held one because nothing came in,
  e.g. while the simulated sensor's process waits for a core, has no new sample to time; its age is in the
  staleness);
- staleness: at each controller cycle, the age of the newest sensor sample in the value the controller holds;
- fed-wrench error against the simulated contact (the truth at the newest sample's time, through the convention),
  without a push and during pushes, excluding :data:`SETTLE_S` after each push starts or ends (the filter's step
  response) and values written more than :data:`FRESH_S` after their newest sample; beside it the filtered sensor
  noise predicted from the truth's noise and the filter. While the arm jogs, the simulated technician moves it in
  30 Hz steps (as ``ftacq monitor --sim``) and the simulated sensor has no inertial wrench: the error then shows
  the compensation's one-orientation-per-cycle lag at each step, not a dynamic model;
- CPU of this process (every thread: ur-rtde's, the driver's, the bridge's) as % of one core.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import gc
import json
import os
import select
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FULL_SECONDS, QUICK_SECONDS = 60.0, 10.0
SENSOR_RATE_HZ = 7000.0
JOG_RATE_HZ = 30.0
JOG_AMPLITUDE_RAD = np.array([0.35, 0.15, 0.2, 0.7, 0.7, 1.2])
JOG_PERIOD_S = np.array([23.0, 17.0, 19.0, 11.0, 7.0, 13.0])
CONTACT = np.array([4.0, 6.0, -15.0, 0.3, -0.1, 0.05])
"""The push on the tool, sensor frame (N, N·m)."""
CONTACT_EVERY_S, CONTACT_DURATION_S = 8.0, 2.0
SETTLE_S = 0.1
STALL_S = 0.001
"""A wake-up of the stall probe this late or later is a stall of the machine (half a controller cycle)."""
FRESH_S = 0.01
"""The error statistics use values whose newest sample was at most this old when written: the truth is known at
the sample's *receive* stamp, which on a loaded machine lags its generation (the push schedule's clock)."""
SENSOR_OFFSET_M = (0.0, 0.0, 0.035)
SENSOR_BODY_KG = 0.3
MOVE_OFFSET_RAD = np.array([0.6, -0.3, 0.4, 0.8, 0.8, 1.0])
MOVE_SPEED_RAD_S, MOVE_ACCELERATION_RAD_S2 = 1.0, 2.0
"""``--moves``: moveJ back and forth between the start and start + MOVE_OFFSET_RAD at this speed and acceleration
(as benchmarks/dynamics.py)."""
GOALS = {"missed": 0, "latency_p99_ms": 4.0, "cpu_percent": 50.0}


def contact_at(elapsed_s: np.ndarray) -> np.ndarray:
    """The push (N, 6) at times since the world's t0: on for the last CONTACT_DURATION_S of every period."""
    on = (np.mod(elapsed_s, CONTACT_EVERY_S) > CONTACT_EVERY_S - CONTACT_DURATION_S) & (elapsed_s >= 0)
    return on[:, None] * CONTACT[None, :]


def near_switch(elapsed_s: np.ndarray, margin_s: float) -> np.ndarray:
    """True within ``margin_s`` after a push starts or ends."""
    phase = np.mod(elapsed_s, CONTACT_EVERY_S)
    start = CONTACT_EVERY_S - CONTACT_DURATION_S
    return ((phase >= start) & (phase < start + margin_s)) | (phase < margin_s)


# ---------------------------------------------------------------------------------------------------------- world
def world(args: argparse.Namespace) -> int:
    """The sensor fake, the jog and the pushes, until stdin closes."""
    import socket
    from multiprocessing import resource_tracker

    from tests.fakes.netft import FakeNetFT
    from tests.fakes.world import CellTruth, SensorPhysics, SharedPose

    sys.setswitchinterval(0.0005)  # the sensor's sender thread gets the interpreter promptly (a real box is not Python)
    pose = SharedPose(args.pose_shm)
    resource_tracker.unregister(pose._shm._name, "shared_memory")  # the benchmark process owns the block
    robot = None
    if args.rigid:
        from ftacq.kinematics import ur_model
        robot = ur_model("UR5e")  # the sensor reads the rigid tool's inertial wrench from the controller's joint state
    physics = SensorPhysics(CellTruth(), pose, seed=1, robot=robot)
    fake = FakeNetFT(physics, host="127.0.0.1", rate_hz=SENSOR_RATE_HZ)
    gc.freeze()  # a real box streams without collector pauses (as tests/fakes/netft.py's main)
    fake.start()
    control = socket.create_connection((args.host, args.control_port), timeout=5.0)
    replies = control.makefile("r")

    def set_q(q: np.ndarray) -> None:
        control.sendall(("set q " + " ".join(repr(float(v)) for v in q) + "\n").encode())
        replies.readline()

    q_start = np.array(json.loads(args.q0))
    t0 = time.monotonic() + 1.0
    print(json.dumps({"url": fake.url, "t0": t0}), flush=True)
    stop = threading.Event()

    def pushes() -> None:  # the push switches on and off at known times: wake then, not in a polling loop
        while True:
            elapsed = time.monotonic() - t0
            physics.contact_wrench = contact_at(np.array([elapsed]))[0]
            phase = elapsed % CONTACT_EVERY_S if elapsed >= 0 else elapsed
            start = CONTACT_EVERY_S - CONTACT_DURATION_S
            wait_s = (start - phase) if phase < start else (CONTACT_EVERY_S - phase)
            if stop.wait(max(wait_s, 0.0) + 1e-4):
                return

    pusher = threading.Thread(target=pushes, daemon=True)
    pusher.start()
    next_s = time.monotonic()
    try:
        while True:
            if not args.still:
                t = time.monotonic() - t0
                set_q(q_start + JOG_AMPLITUDE_RAD * np.sin(2 * np.pi * max(t, 0) / JOG_PERIOD_S))
            next_s += 1.0 / JOG_RATE_HZ
            ready, _, _ = select.select([sys.stdin], [], [], max(0.0, next_s - time.monotonic()))
            if ready and not sys.stdin.readline():
                break
    finally:
        stop.set()
        fake.close()
        control.close()
        pose.close()
    return 0


# ---------------------------------------------------------------------------------------------------------- bridge
def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help=f"{QUICK_SECONDS:g} s instead of {FULL_SECONDS:g} s")
    parser.add_argument("--seconds", type=float, help="feeding time, s")
    parser.add_argument("--feed", choices=("compensated", "raw"), default="compensated")
    parser.add_argument("--still", action="store_true", help="no jog")
    parser.add_argument("--moves", choices=("static", "dynamic"),
                        help="instead of the jog, real moveJ moves with the tool's inertial wrench in the sensor; the "
                             "bridge's calibration without (static) or with (dynamic) the tool's inertia")
    parser.add_argument("--rigid", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--max-staleness-s", type=float, default=None,
                        help="relax the bridge's staleness limit (default: the product's) so that a loaded machine "
                             "does not end the run early; the figures say so")
    parser.add_argument("--cycle-timeout-s", type=float, default=None, help="relax the lost-cycle limit likewise")
    parser.add_argument("--softirq-priority", type=int, default=0, metavar="N",
                        help="run the kernel's network threads (ksoftirqd) at SCHED_FIFO N during the run (needs root; "
                             "put back afterwards), as docs/bridge.md advises for a real cell; 0: leave them as they are")
    parser.add_argument("--explain-misses", action="store_true",
                        help="print the timeline of every missed cycle (package sent, received and answered by the "
                             "bridge, answer arrived, next cycle), ms")
    parser.add_argument("--world", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--pose-shm", help=argparse.SUPPRESS)
    parser.add_argument("--host", help=argparse.SUPPRESS)
    parser.add_argument("--control-port", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--q0", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.world:
        return world(args)
    seconds = args.seconds or (QUICK_SECONDS if args.quick else FULL_SECONDS)
    with softirq_priority(args.softirq_priority) as softirq:
        return bench(args, seconds, softirq)


@contextlib.contextmanager
def softirq_priority(priority: int):
    """``--softirq-priority``: SCHED_FIFO ``priority`` for the ksoftirqd threads at normal priority, put back at the
    end; yields how they run (for the report)."""
    from procedures.realtime import softirq_threads

    changed = []
    try:
        if priority > 0:
            for thread in softirq_threads():
                if thread.realtime_priority == 0:
                    try:
                        os.sched_setscheduler(thread.pid, os.SCHED_FIFO, os.sched_param(priority))
                    except OSError as error:
                        sys.exit(f"--softirq-priority: cannot change {thread.name} (pid {thread.pid}): {error.strerror}")
                    changed.append(thread.pid)
        threads = softirq_threads()
        priorities = sorted({t.realtime_priority for t in threads})
        yield ("not visible" if not threads else
               ", ".join("normal priority" if p == 0 else f"SCHED_FIFO {p}" for p in priorities)
               + (" (--softirq-priority)" if changed else ""))
    finally:
        for pid in changed:
            try:
                os.sched_setscheduler(pid, os.SCHED_OTHER, os.sched_param(0))
            except OSError:
                pass


def bench(args: argparse.Namespace, seconds: float, softirq: str) -> int:
    from drivers.robot import MotionLimits
    from drivers.sensor import open_sensor
    from drivers.ur import URRobot
    from drivers.ur_ft_input import URForceTorqueInput
    from ftacq.bridge_convention import plan_feed
    from ftacq.kinematics import ur_model
    from procedures.bridge import LOG_KEEP_S, ROBOT_STATE_RATE_HZ, Bridge, BridgeSettings, WrenchFilter
    from procedures.plan import home_configuration_rad
    from tests.fakes.ur_process import URControllerProcess
    from tests.fakes.world import CellTruth, SharedPose

    truth = CellTruth()
    calibration = truth.calibration()
    if args.moves:
        from dataclasses import replace
        calibration = replace(calibration, sensor_offset=np.array(truth.sensor_offset_m))
        if args.moves == "dynamic":
            calibration = replace(calibration, inertia=truth.inertia)
    q0 = home_configuration_rad("floor")
    shared = SharedPose(name=f"ftacq-bench-{os.getpid()}-{uuid.uuid4().hex[:6]}", create=True)
    with URControllerProcess(time_scale=1.0, pose_shm=shared.name, initial_q=q0) as controller:
        world_process = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), "--world", "--pose-shm", shared.name, "--host",
             controller.host, "--control-port", str(controller.control_port), "--q0", json.dumps(q0.tolist())]
            + (["--still"] if args.still or args.moves else []) + (["--rigid"] if args.moves else []),
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)
        prober = subprocess.Popen([sys.executable, str(ROOT / "benchmarks" / "stall_probe.py")], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True, cwd=ROOT)
        prober.stdout.readline()
        try:
            ready = json.loads(world_process.stdout.readline())
            limits = MotionLimits(joint_speed_rad_s=MOVE_SPEED_RAD_S, joint_acceleration_rad_s2=MOVE_ACCELERATION_RAD_S2)
            robot = URRobot(controller.host, limits, model="UR5e", leave_external_ft_input=True,
                            frequency_hz=ROBOT_STATE_RATE_HZ).start()
            client = URForceTorqueInput(controller.host).start()
            sensor = open_sensor(ready["url"])
            sensor.start()
            plan = plan_feed(calibration, args.feed, SENSOR_OFFSET_M, sensor_body_kg=SENSOR_BODY_KG)
            settings = BridgeSettings(log_keep_s=max(LOG_KEEP_S, 1.2 * seconds))  # the figures cover the whole run
            if args.max_staleness_s:
                settings = dataclasses.replace(settings, max_staleness_s=args.max_staleness_s)
            if args.cycle_timeout_s:
                settings = dataclasses.replace(settings, cycle_timeout_s=args.cycle_timeout_s)
            if args.max_staleness_s or args.cycle_timeout_s:
                controller.control("set external_ft_watchdog 1.0")  # as rtde_set_watchdog would
            bridge = Bridge(sensor, client, robot, plan, calibration, ur_model("UR5e"), settings,
                            sensor_rate_hz=SENSOR_RATE_HZ)
            cpu0, wall0 = time.process_time(), time.monotonic()
            stop_moving = threading.Event()
            if args.moves:
                mover = threading.Thread(target=move_back_and_forth, args=(robot, bridge, q0, stop_moving), daemon=True)
                mover.start()
            try:
                summary = bridge.run(duration_s=seconds)
                stop_moving.set()
                cpu_s, wall_s = time.process_time() - cpu0, time.monotonic() - wall0
                health = sensor.health()
            finally:  # ur-rtde's clients reconnect forever once the controller is gone: close them first
                sensor.close()
                client.close()
                robot.close()
            # only now: after a long run the simulated controller takes seconds to hand its records over, and
            # ur-rtde's control interface, still open, went into reconnecting and segfaulted twice (660 s, 900 s)
            state = controller.external_ft()
            records = controller.external_ft_records()
        finally:
            world_process.stdin.close()
            world_process.wait(10)
            stalls = json.loads(prober.communicate("", timeout=10)[0])
    shared.close()
    report(args, seconds, summary, state, records, plan, cpu_s, wall_s, ready["t0"], health, truth,
           WrenchFilter(bridge.cutoff_hz, SENSOR_RATE_HZ), settings, stalls,
           f"kernel network threads (ksoftirqd) {softirq}")
    return 0


def move_back_and_forth(robot, bridge, q0: np.ndarray, stop: threading.Event) -> None:
    """``--moves``: once the feed runs, moveJ between q0 and q0 + MOVE_OFFSET_RAD until ``stop``."""
    while bridge.written == 0 and not stop.wait(0.01):
        pass
    targets = (q0 + MOVE_OFFSET_RAD, q0)
    k = 0
    while not stop.is_set():
        try:
            robot.move_joints(targets[k % 2], MOVE_SPEED_RAD_S, MOVE_ACCELERATION_RAD_S2)
        except Exception as error:  # noqa: BLE001 - the controller went away at the end of the run
            if not stop.is_set():  # the end of the run closes the connection under a move: not news
                print(f"  moves stopped: {error}", file=sys.stderr)
            return
        k += 1


def report(args, seconds, summary, state, records, plan, cpu_s, wall_s, t0, health, truth, wrench_filter,
           settings, stalls, scheduling) -> None:
    from procedures.bridge import FED_COLUMNS

    log = summary.log
    if summary.written == 0:
        print(f"ftacq bridge benchmark: nothing was written ({summary.trip})")
        return
    written = log[np.isfinite(log[:, 2])]
    received = records["received"]
    cycles = records["cycles"]
    n = min(len(written), len(received))
    same = np.array_equal(written[-n:, FED_COLUMNS], received[-n:, 2:]) if n else False
    # latency: newest sample (driver receive stamp) → controller arrival, over the values that carry new samples (a
    # value repeated because no sample arrived since the previous cycle has no sample to time: its age counts in the
    # staleness below)
    carries = written[-n:, 4] > 0
    latency_ms = (received[-n:, 0] - written[-n:, 3])[carries] * 1000.0
    # staleness at each controller cycle: age of the held value + its latency
    held = np.searchsorted(received[-n:, 1], cycles[:, 0], side="right") - 1
    valid = held >= 0
    staleness_ms = (cycles[valid, 2] + (received[-n:, 0] - written[-n:, 3])[held[valid]]) * 1000.0
    fed_cycles = int(cycles[:, 1].sum())
    missed = len(cycles) - fed_cycles
    period_s = 1.0 / summary.controller_rate_hz
    # the answers to the packages of the cycles counted while enabled (the first ones, before the enable call, warm
    # up the models and feed nothing the controller uses)
    enabled = written[:, 0] >= cycles[0, 0]
    answer_ms = (written[enabled, 2] - written[enabled, 1]) * 1000.0
    stall = np.array(stalls["late"]).reshape(-1, 2)
    big = stall[:, 1] > STALL_S
    causes = attribute_misses(cycles, log, stall, period_s)
    simulator, machine = causes["simulator"], causes["machine"]
    send_gap_ms = np.diff(cycles[:, 3]) * 1000.0
    if args.explain_misses:
        explain_misses(cycles, log, received)
    # error against the truth at the newest sample's time
    elapsed = written[:, 3] - t0
    truth_fed = plan.fed_wrench(contact_at(elapsed))
    if plan.feed == "raw":
        # the raw feed carries the tool's weight at the pose: known here only while the arm stays at q0
        truth_fed = None
        if args.still and not args.moves:
            from ftacq.kinematics import forward_kinematics, ur_model
            from procedures.plan import home_configuration_rad

            calibration = truth.calibration()
            base_R_flange = forward_kinematics(ur_model("UR5e"), home_configuration_rad("floor"))[:3, :3]
            bias = np.concatenate([calibration.force_bias, calibration.torque_bias])
            tool_weight = -calibration.compensate(bias[None, :], base_R_flange.T)[0]  # sensor frame, bias removed
            truth_fed = plan.fed_wrench(contact_at(elapsed) + tool_weight)
    error = written[:, FED_COLUMNS] - truth_fed if truth_fed is not None else None
    keep = ~near_switch(elapsed, SETTLE_S) & (elapsed > 0.5) & (written[:, 2] - written[:, 3] <= FRESH_S)
    pushing = contact_at(elapsed)[:, 2] != 0
    noise = np.array(truth.force_noise_n + truth.torque_noise_nm)
    rng = np.random.default_rng(0)
    # the sensor's noise through the filter and the convention (the fed frame mixes the sensor's axes)
    filtered_noise = plan.fed_wrench(wrench_filter(rng.standard_normal((70000, 6)) * noise))[1000:].std(axis=0)
    print(f"ftacq bridge benchmark: {seconds:g} s, feed {plan.feed}, sensor {SENSOR_RATE_HZ:g} Hz, controller "
          f"{summary.controller_rate_hz:g} Hz, low-pass {summary.cutoff_hz:g} Hz (group delay "
          f"{summary.filter_delay_s * 1000:.2f} ms), arm {arm_motion(args)}, push "
          f"{np.linalg.norm(CONTACT[:3]):.1f} N every {CONTACT_EVERY_S:g} s; {scheduling}")
    span_s = float(cycles[-1, 0] - cycles[0, 0]) if len(cycles) > 1 else float("nan")
    print(f"  controller cycles while enabled {len(cycles)}: fed {fed_cycles}, missed {missed} "
          f"({(len(cycles) - 1) / span_s:.0f} cycles/s of controller time); values received {state['received']}, "
          f"written {summary.written}, identical to the bridge's log: {same}; watchdog trips "
          f"{len(state['watchdog_trips'])}; bridge trip: {summary.trip or 'none'}")
    print(f"  machine stalls (a SCHED_FIFO 99 probe woken {STALL_S * 1e3:g} ms late or more, "
          f"benchmarks/stall_probe.py): {int(big.sum())}, longest {stall[:, 1].max(initial=0) * 1e3:.2f} ms, "
          f"{stall[big, 1].sum() * 1e3:.0f} ms in all")
    print(f"  missed cycles put down to: the simulated controller's own delay (its package sent less than half a "
          f"cycle before the next cycle) {causes['simulator']}; a machine stall {causes['machine']}; not answered (the "
          f"feed had stopped or not begun) {causes['unanswered']}; the way to the bridge (package received more than "
          f"half a cycle after it left) {causes['way_there']}; the bridge (wrote after the next cycle began, or took "
          f"longer than a cycle) {causes['bridge']}; the way back {causes['way_back']}; simulated controller's package "
          f"spacing p1 / p99 {np.percentile(send_gap_ms, 1):.2f} / {np.percentile(send_gap_ms, 99):.2f} ms (real "
          f"controller: {period_s * 1000:g} ms)")
    print(f"  bridge answer time while enabled (package received -> value written): p50 {np.percentile(answer_ms, 50):.2f} ms, p99 "
          f"{np.percentile(answer_ms, 99):.2f} ms, max {answer_ms.max():.2f} ms; feed thread {summary.feed_priority}; "
          f"compensation {summary.compensation}")
    print(f"  latency sensor sample -> controller: p50 {np.percentile(latency_ms, 50):.2f} ms, p99 "
          f"{np.percentile(latency_ms, 99):.2f} ms, max {latency_ms.max():.2f} ms over the {len(latency_ms)} values with "
          f"new samples ({n - len(latency_ms)} repeated a held value: no sample came in that cycle) (plus the filter's "
          f"{summary.filter_delay_s * 1000:.2f} ms group delay)")
    print(f"  staleness at each controller cycle: p50 {np.percentile(staleness_ms, 50):.2f} ms, p99 "
          f"{np.percentile(staleness_ms, 99):.2f} ms, max {staleness_ms.max():.2f} ms (bridge limit "
          f"{settings.max_staleness_s * 1000:.0f} ms{'' if settings.max_staleness_s == bridge_limit_ms() / 1000 else ', RELAXED from ' + format(bridge_limit_ms(), '.0f') + ' ms'})")
    print(f"  load average at the end: {', '.join(f'{v:.1f}' for v in os.getloadavg())} (2 cores)")
    if error is not None:
        for label, mask in (("no push", keep & ~pushing), ("pushed", keep & pushing)):
            if not mask.any():
                continue
            rms = np.sqrt(np.mean(error[mask] ** 2, axis=0))
            print(f"  fed-wrench error {label} ({mask.sum()} values): RMS force {np.round(rms[:3], 4).tolist()} N, "
                  f"torque {np.round(rms[3:], 5).tolist()} N·m; max |F| error "
                  f"{np.linalg.norm(error[mask][:, :3], axis=1).max():.3f} N; RMS / filtered noise "
                  f"{np.round(rms / filtered_noise, 2).tolist()}")
        print(f"  filtered sensor noise in the fed frame (truth's 1σ through the filter and the convention): force {np.round(filtered_noise[:3], 4).tolist()}"
              f" N, torque {np.round(filtered_noise[3:], 5).tolist()} N·m; at rest the truth's calibration is exact "
              "(1σ band 0)")
    print(f"  sensor: {health.received} samples, {health.lost} lost; CPU of this process {100 * cpu_s / wall_s:.1f} % "
          f"of one core ({cpu_s:.1f} s in {wall_s:.1f} s)")
    p99 = float(np.percentile(latency_ms, 99))
    cpu = 100 * cpu_s / wall_s
    ok = missed - simulator - machine <= GOALS["missed"] and p99 <= GOALS["latency_p99_ms"] and cpu < GOALS["cpu_percent"]
    print(f"  goals (0 missed but for the simulator's and the machine's stalls, p99 <= {GOALS['latency_p99_ms']:g} ms, < {GOALS['cpu_percent']:g} % CPU): "
          f"{'met' if ok else 'NOT met'}")


def attribute_misses(cycles: np.ndarray, log: np.ndarray, stall: np.ndarray, period_s: float) -> dict[str, int]:
    """Each missed cycle k, put down to the first that applies, on the one monotonic clock: the simulated
    controller (the package of cycle k-1 left less than half a cycle before cycle k), a machine stall (the probe's
    real-time thread held off :data:`STALL_S` or more between that package and cycle k), not answered, the way to
    the bridge (received more than half a cycle after it left), the bridge (it wrote after cycle k began, or took
    longer than a cycle), the way back (written in time, arrived late)."""
    causes = dict.fromkeys(("simulator", "machine", "unanswered", "way_there", "bridge", "way_back"), 0)
    row_of_time = {float(t): i for i, t in enumerate(log[:, 0])}
    stall_start, stall_end = stall[:, 0], stall[:, 0] + stall[:, 1]
    big = stall[:, 1] > STALL_S
    for k in np.flatnonzero(cycles[1:, 1] == 0) + 1:
        i = row_of_time.get(float(cycles[k - 1, 0]))
        sent, next_cycle = cycles[k - 1, 4], cycles[k, 3]
        if next_cycle - sent < period_s / 2:
            cause = "simulator"
        elif np.any(big & (stall_end > cycles[k - 1, 3]) & (stall_start < next_cycle)):
            cause = "machine"
        elif i is None or not np.isfinite(log[i, 2]):
            cause = "unanswered"  # the package never reached the feed loop, or it wrote nothing (stopped, no sample)
        elif log[i, 1] - sent > period_s / 2:
            cause = "way_there"
        elif log[i, 2] > next_cycle or log[i, 2] - log[i, 1] > period_s:
            cause = "bridge"
        else:
            cause = "way_back"
        causes[cause] += 1
    return causes


def explain_misses(cycles: np.ndarray, log: np.ndarray, received: np.ndarray) -> None:
    """``--explain-misses``: for each missed cycle k, on the one monotonic clock, relative to the package sent at
    cycle k-1: when the bridge received it, wrote its answer, when the answer reached the controller, and cycle k."""
    rows_written = np.flatnonzero(np.isfinite(log[:, 2]))
    n = min(len(rows_written), len(received))
    arrival_of = {int(r): float(a) for r, a in zip(rows_written[-n:], received[-n:, 0])}
    row_of_time = {float(t): i for i, t in enumerate(log[:, 0])}
    print("  missed cycles, ms after the previous cycle's start: its package sent / bridge received / wrote / "
          "answer arrived / next cycle's start")
    for k in np.flatnonzero(cycles[1:, 1] == 0) + 1:
        sent = cycles[k - 1, 3]
        i = row_of_time.get(float(cycles[k - 1, 0]))
        if i is None:
            print(f"    cycle {k}: package not received by the bridge; cycle read at {(cycles[k, 3] - sent) * 1e3:.2f}")
            continue
        arrived = arrival_of.get(i, float("nan"))
        print(f"    cycle {k}: {(cycles[k - 1, 4] - sent) * 1e3:6.2f} / {(log[i, 1] - sent) * 1e3:6.2f} / {(log[i, 2] - sent) * 1e3:6.2f} / "
              f"{(arrived - sent) * 1e3:6.2f} / {(cycles[k, 3] - sent) * 1e3:6.2f}")


def arm_motion(args) -> str:
    if args.moves:
        return (f"moving (moveJ {MOVE_SPEED_RAD_S:g} rad/s, {MOVE_ACCELERATION_RAD_S2:g} rad/s², tool inertia in the "
                f"sensor; calibration {'with' if args.moves == 'dynamic' else 'without'} inertia)")
    return "still" if args.still else "jogging"


def bridge_limit_ms() -> float:
    from procedures.bridge import MAX_STALENESS_S

    return MAX_STALENESS_S * 1000.0


if __name__ == "__main__":
    sys.exit(main())
