"""Offline: what linear interpolation of the 2 ms robot states' predictions costs across a moveJ's acceleration
steps, and what a timing error costs (issue 27). No sockets, no clocks: exact timing, no noise.

    .venv/bin/python benchmarks/dynamics_steps.py [--moves 5] [--seed 0] [--state-period-s 0.008]
    .venv/bin/python benchmarks/dynamics_steps.py --cpu-runs 7 [--state-period-s 0.008]

(``--state-period-s 0.008``: a CB3's 125 Hz states instead of the e-Series' 2 ms.)

The simulated arm's q̈ is the moveJ trapezoid's (tests/fakes/ur_motion.py), with steps at any instant, and the
simulated sensor follows it exactly; the model is evaluated at each 2 ms state (q, q̇, target q̈) and interpolated
linearly onto the samples. Per move of the live benchmark's
jog (tests/fakes/jog.py targets, 1 rad/s, 2 rad/s², the 4.2 kg tool of benchmarks/dynamics_live.py): RMS per
component of (interpolated − true) at 7 kHz; the same with the step located from the velocity change
(q̇ₖ₊₁ − q̇ₖ = q̈ₖ τ + q̈ₖ₊₁ (Δ − τ), least squares over the joints) and the prediction's q̈-linear part switched
there, as the live compensator does (procedures/dynamic_compensation.py, ftacq.dynamics.acceleration); and the
error of a prediction shifted by 0.5, 1, 2 ms.

``--cpu-runs N``: the live compensator's own cost instead, thread CPU per 10 ms read of 70 samples over the moves
(the arm 4 ms behind its target), with the step location and without (the linear interpolation alone), side by
side read by read, N runs; median µs per read.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

SAMPLE_RATE_HZ = 7000.0
STATE_PERIOD_S = 0.002


def rms_per_component(error: np.ndarray) -> tuple[float, float]:
    """(force N, torque N·m): RMS over samples and the three components."""
    return float(np.sqrt(np.mean(error[:, :3] ** 2))), float(np.sqrt(np.mean(error[:, 3:] ** 2)))


def main(moves: int, seed: int, state_period_s: float = STATE_PERIOD_S) -> int:
    from benchmarks.dynamics_live import heavy_truth
    from ftacq.dynamics.acceleration import acceleration_steps, step_shape
    from ftacq.dynamics.model import SensorDynamics, WrenchPredictor
    from ftacq.dynamics.timing import interpolate_rows
    from ftacq.kinematics import ur_model
    from procedures.plan import home_configuration_rad
    from tests.fakes.jog import plan_targets
    from tests.fakes.ur_motion import JointMove

    truth = heavy_truth()
    calibration = replace(truth.calibration(), inertia=truth.inertia, sensor_offset=np.array(truth.sensor_offset_m))
    robot = ur_model("UR5e")
    predict = WrenchPredictor(SensorDynamics.for_calibration(robot, calibration), calibration)
    start = home_configuration_rad("floor")
    rng = np.random.default_rng(seed + 1)
    q_from = start
    for target in plan_targets(start, moves, seed, "UR5e", 1.0, 2.0):
        move = JointMove(robot, q_from, target, 1.0, 2.0)
        q_from = target

        def states(times: np.ndarray, move: JointMove = move) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            rows = [(*move.sample(t), move.acceleration(t)[0]) for t in times]
            return tuple(np.array([row[i] for row in rows]) for i in range(3))  # type: ignore[return-value]

        samples_s = np.arange(0.0, move.duration_s, 1.0 / SAMPLE_RATE_HZ)
        true = predict(*states(samples_s))
        states_s = np.arange(-2 * state_period_s + rng.uniform(0, state_period_s), move.duration_s + 2 * state_period_s,
                             state_period_s)
        q, qd, qdd = states(states_s)
        predicted = predict(q, qd, qdd)
        linear = interpolate_rows(samples_s, states_s, predicted)
        stepped = linear.copy()  # the live compensator's step location (ftacq.dynamics.acceleration), no servo lag
        for k, step_s, change in zip(*acceleration_steps(states_s, qd, qdd)):
            jump = predict(q[k + 1], qd[k + 1], qdd[k + 1] + change)[0] - predict(q[k + 1], qd[k + 1], qdd[k + 1])[0]
            stepped += step_shape(samples_s, states_s, step_s, states_s[k], states_s[k + 1] - states_s[k], 0.0)[:, None] * jump
        shifted = [rms_per_component(interpolate_rows(samples_s + d, states_s, predicted) - true)
                   for d in (0.0005, 0.001, 0.002)]
        f, t = rms_per_component(linear - true)
        fs, ts = rms_per_component(stepped - true)
        print(f"move {move.duration_s:.2f} s: linear {f:.4f} N {t:.5f} N·m (max {np.abs(linear - true)[:, :3].max():.3f} N, "
              f"{np.abs(linear - true)[:, 3:].max():.4f} N·m); step located {fs:.5f} N {ts:.6f} N·m; shifted 0.5/1/2 ms "
              + " / ".join(f"{a:.4f} N {b:.5f} N·m" for a, b in shifted))
    return 0


def cpu_per_read(moves: int, seed: int, state_period_s: float, runs: int, servo_lag_s: float = 0.004) -> int:
    import time
    from types import SimpleNamespace

    from benchmarks.dynamics_live import heavy_truth
    from drivers.ur_ft_input import ControllerCycle
    from ftacq.kinematics import ur_model
    from procedures.bridge import CycleStates
    from procedures.dynamic_compensation import DynamicCompensator
    from procedures.plan import home_configuration_rad
    from tests.fakes.jog import plan_targets
    from tests.fakes.ur_motion import JointMove

    truth = heavy_truth()
    calibration = replace(truth.calibration(), inertia=truth.inertia, sensor_offset=np.array(truth.sensor_offset_m))
    robot, start = ur_model("UR5e"), home_configuration_rad("floor")
    cycles, q_from, offset_s = [], start, 0.0
    for target in plan_targets(start, moves, seed, "UR5e", 1.0, 2.0):
        move = JointMove(robot, q_from, target, 1.0, 2.0)
        q_from = target
        for t in np.arange(0.0, move.duration_s + 0.1, state_period_s):
            (q, qd), (_, target_qd), qdd = move.sample(max(t - servo_lag_s, 0.0)), move.sample(t), move.acceleration(t)
            cycles.append(ControllerCycle(timestamp_s=offset_s + t, q=q, qd=qd, tcp_force=np.zeros(6), runtime_state=2,
                                          safety_status_bits=1, received_s=offset_s + t, tcp_pose=np.zeros(6),
                                          target_qd=target_qd, target_qdd=qdd[0]))
        offset_s = cycles[-1].timestamp_s + state_period_s
    spent: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(runs):  # both side by side, read by read (in turns): the same load for both
        streams = {located: CycleStates(1 << 16, frequency_hz=1.0 / state_period_s) for located in (True, False)}
        compensators = {located: DynamicCompensator(calibration, robot, streams[located], lag_s=0.0,
                                                    servo_lag_s=servo_lag_s) for located in (True, False)}
        compensators[False]._locate_steps = lambda *args: None  # type: ignore[method-assign]
        total, reads, k = {True: 0.0, False: 0.0}, 0, 0
        for first_s in np.arange(2 * state_period_s, offset_s, 0.01):
            while k < len(cycles) and cycles[k].received_s <= first_s + 0.01:
                for stream in streams.values():
                    stream.append(cycles[k])
                k += 1
            batch = SimpleNamespace(time_s=first_s + np.arange(70) / SAMPLE_RATE_HZ, wrench=np.zeros((70, 6)),
                                    device_time_s=np.full(70, np.nan))
            for located in ((True, False) if reads % 2 else (False, True)):
                before = time.thread_time()
                compensators[located].compensate(batch)
                total[located] += time.thread_time() - before
            reads += 1
        for located in (True, False):
            spent[located].append(total[located] / reads * 1e6)
    for located, label in ((True, "step located"), (False, "linear only ")):
        print(f"{label}: {np.median(spent[located]):.1f} µs per read (thread CPU; runs "
              + " ".join(f"{x:.0f}" for x in spent[located]) + ")")
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--moves", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--state-period-s", type=float, default=STATE_PERIOD_S)
    parser.add_argument("--cpu-runs", type=int, default=0)
    args = parser.parse_args()
    if args.cpu_runs:
        sys.exit(cpu_per_read(args.moves, args.seed, args.state_period_s, args.cpu_runs))
    sys.exit(main(args.moves, args.seed, args.state_period_s))
