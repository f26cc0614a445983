"""A recorded excitation synthesised offline, as the simulated cell records it in real time but in a second: the
controller's target along a chain of moveJs, the physical arm ``servo_lag_s`` behind it (``actual_q`` with encoder
jitter, ``actual_qd``), the 7 kHz sensor feeling the physical arm (tests/fakes/world.py's physics, noise) and
stamped ``transport_lag_s`` late; the record assembled by the product's own functions
(:func:`ftacq.dynamics.acceleration.physical_acceleration`, as ``procedures/excitation.py`` does).

Also gives the true physical states at the robot's times, for an efficient (oracle) estimator beside the product's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from types import SimpleNamespace

import numpy as np

from ftacq.dynamics.acceleration import physical_acceleration
from ftacq.dynamics.identify import MotionRecord
from ftacq.kinematics import URModel
from tests.fakes.ur_motion import JointMove
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose

ROBOT_RATE_HZ = 500.0
HEAVY_TOOL_MASS_KG = 4.2
"""The heavy tool of the servo-lag tests and benchmark (an independent cell's, issue 37), kg."""


def heavy_truth() -> CellTruth:
    """The default cell with the heavy tool: its inertia scaled with its mass."""
    base = CellTruth()
    scale = HEAVY_TOOL_MASS_KG / base.mass_kg
    return CellTruth(mass_kg=HEAVY_TOOL_MASS_KG,
                     inertia_kg_m2=tuple(tuple(scale * v for v in row) for row in base.inertia_kg_m2))


def chain_of_moves(model: URModel, start_q: np.ndarray, targets: np.ndarray, speed_rad_s: float,
                   acceleration_rad_s2: float) -> list[tuple[float, JointMove]]:
    """[(start time s, moveJ)] through ``targets`` (K, 6) from ``start_q``, each from rest to rest."""
    plan, q, start = [], np.asarray(start_q, dtype=float), 0.0
    for target in np.asarray(targets, dtype=float):
        move = JointMove(model, q, target, speed_rad_s, acceleration_rad_s2)
        plan.append((start, move))
        start += move.duration_s
        q = target
    return plan


def states_along(plan: list[tuple[float, JointMove]], times_s: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, q̇, q̈) (N, 6) of the plan at ``times_s`` (N,), vectorised over each move's trapezoid; at rest before
    the first and after the last move."""
    times_s = np.asarray(times_s, dtype=float)
    starts = np.array([start for start, _ in plan])
    index = np.clip(np.searchsorted(starts, times_s, side="right") - 1, 0, len(plan) - 1)
    q, qd, qdd = np.empty((3, times_s.size, 6))
    for k, (start, move) in enumerate(plan):
        mask = index == k
        if not mask.any():
            continue
        p = move.profile
        t = np.clip(times_s[mask] - start, 0.0, p.duration_s)
        s, v, acc = p.position(t), p.speed_at(t), p.acceleration_at(t)  # the controller's time law
        done = (times_s[mask] - start) >= p.duration_s
        s, v, acc = np.where(done, move.length, s), np.where(done, 0.0, v), np.where(done, 0.0, acc)
        before = times_s[mask] < start
        acc = np.where(before, 0.0, acc)
        q[mask] = move.q_start + np.outer(s, move.direction)
        qd[mask] = np.outer(v, move.direction)
        qdd[mask] = np.outer(acc, move.direction)
    return q, qd, qdd


@dataclass(frozen=True)
class LaggingRecording:
    """record: as the product assembles it; servo_lag_s, transport_lag_s: the truth; physical_q/qd/qdd (M, 6):
    the arm's true state at the record's robot times; target_qd, target_qdd (M, 6): what the controller reported;
    sensor_noise (N, 6): the noise in the record's wrench (N, N·m)."""

    record: MotionRecord
    servo_lag_s: float
    transport_lag_s: float
    physical_q: np.ndarray
    physical_qd: np.ndarray
    physical_qdd: np.ndarray
    target_qd: np.ndarray
    target_qdd: np.ndarray
    sensor_noise: np.ndarray


def record_excitation_offline(truth: CellTruth, model: URModel, plan: list[tuple[float, JointMove]], *,
                              servo_lag_s: float = 0.004, transport_lag_s: float = 0.001, seed: int = 0,
                              sensor_rate_hz: float = 7000.0, encoder_noise_rad: float = 1e-6,
                              rest_s: float = 0.3, robot_rate_hz: float = ROBOT_RATE_HZ) -> LaggingRecording:
    """Synthesise the recording of ``plan`` (with ``rest_s`` of rest before and after) on ``truth``'s cell, the robot
    states at ``robot_rate_hz`` (125: a CB3)."""
    rng = np.random.default_rng(seed)
    end_s = plan[-1][0] + plan[-1][1].duration_s + rest_s
    robot_t = np.arange(-rest_s, end_s, 1.0 / robot_rate_hz)
    _target_q, target_qd, target_qdd = states_along(plan, robot_t)
    q, qd, qdd = states_along(plan, robot_t - servo_lag_s)
    actual_q = q + rng.normal(0.0, encoder_noise_rad, q.shape)
    sensor_t = np.arange(robot_t[0], robot_t[-1], 1.0 / sensor_rate_hz)
    physics = SensorPhysics(truth, SettablePose(), robot=model, seed=seed)
    sq, sqd, sqdd = states_along(plan, sensor_t - servo_lag_s)
    wrench = physics.noiseless_wrench_moving(sq, sqd, sqdd)
    sigma = np.array(truth.force_noise_n + truth.torque_noise_nm)
    sigma = sigma * (1.0 + truth.motion_noise_gain * np.linalg.norm(sqd, axis=1))[:, None]  # as SensorPhysics
    noise = rng.standard_normal(wrench.shape) * sigma
    wrench = wrench + noise
    record_qdd, measured_servo_lag = physical_acceleration(robot_t, qd, target_qd, target_qdd)
    record = MotionRecord(sensor_t + transport_lag_s, wrench, robot_t, actual_q, qd, record_qdd,
                          metadata={"servo_lag_s": measured_servo_lag})
    return LaggingRecording(record, servo_lag_s, transport_lag_s, q, qd, qdd, target_qd, target_qdd, noise)


def replay_live(recording: LaggingRecording, calibration, servo_lag_s: float, transport_lag_s: float,
                batch_samples: int = 70) -> np.ndarray:
    """Feed ``recording`` to the live compensator (procedures/dynamic_compensation.py) as the monitor reads it:
    RTDE states (``actual_q``, ``actual_qd``, ``target_qd``, ``target_qdd``) and sensor batches of
    ``batch_samples`` interleaved by time, with ``servo_lag_s`` and ``transport_lag_s`` as the calibration's
    measured lags. Returns the contact wrench (N, 6) of the samples compensated dynamically (NaN otherwise)."""
    from drivers.ur_ft_input import ControllerCycle
    from ftacq.kinematics import ur_model
    from procedures.bridge import CycleStates
    from procedures.dynamic_compensation import DynamicCompensator

    record = recording.record
    states = CycleStates(frequency_hz=1.0 / record.robot_period_s)
    dynamics = dict(calibration.metadata.get("dynamics", {}), servo_lag_ms=1e3 * servo_lag_s,
                    lag_ms=1e3 * transport_lag_s)
    calibration = replace(calibration, metadata=dict(calibration.metadata, dynamics=dynamics))
    compensator = DynamicCompensator(calibration, ur_model(record.metadata.get("model", "UR5e")), states)
    out = np.full_like(record.wrench, np.nan)
    host_s = 80.0
    robot_t, next_row = record.robot_time_s, 0
    for start in range(0, len(record.sensor_time_s) - batch_samples, batch_samples):
        chunk = slice(start, start + batch_samples)
        newest = record.sensor_time_s[chunk][-1]
        while next_row < len(robot_t) and robot_t[next_row] <= newest:
            k = next_row
            states.append(ControllerCycle(
                timestamp_s=float(robot_t[k]), q=record.q[k], qd=record.qd[k], tcp_force=np.zeros(6),
                runtime_state=2, safety_status_bits=1, received_s=host_s + float(robot_t[k]), tcp_pose=np.zeros(6),
                target_qd=recording.target_qd[k], target_qdd=recording.target_qdd[k]))
            next_row += 1
        batch = SimpleNamespace(time_s=host_s + record.sensor_time_s[chunk],
                                device_time_s=np.full(batch_samples, np.nan), wrench=record.wrench[chunk])
        static_before = compensator.static_batches
        got = compensator.compensate(batch, None)
        if got is not None and compensator.static_batches == static_before:
            out[chunk] = got
    return out
