"""Synthesized quick-calibration recordings: the designed trajectory sampled offline through the simulated cell's own
physics (:class:`tests.fakes.world.SensorPhysics`: the rigid tool, the biases' drift, the ring-down after every
stop, noise growing with the joint speed), without sockets or clocks, many times faster than real time.

The maths of ``calibrate --quick`` (settling, drift, the verdict) is tested on these; the end-to-end tests and
``benchmarks/quick.py --offline`` use them too. The sensor samples at ``sensor_rate_hz`` on the robot's clock (the
streams' alignment is tested end to end); the holds' windows are the robot rows of each waypoint's hold.
"""

from __future__ import annotations

import numpy as np

from ftacq.dynamics import MotionRecord
from procedures.quick import QuickPlan, QuickRecording, sample_trajectory
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose

ROBOT_RATE_HZ = 500.0
SENSOR_RATE_HZ = 1000.0


def synthesize_recording(plan: QuickPlan, truth: CellTruth, robot, seed: int = 0, wrong_tool_kg: float = 0.0,
                         sensor_rate_hz: float = SENSOR_RATE_HZ) -> QuickRecording:
    """The recording ``record_quick`` would make of ``plan`` on a cell with ``truth`` (module docstring);
    ``wrong_tool_kg`` > 0 adds that mass at the tool's centre of mass during the validation holds."""
    args = (plan.start_q_rad, plan.waypoints_rad, plan.hold_s, plan.speed_rad_s, plan.acceleration_rad_s2)
    t, q, qd, qdd, index = sample_trajectory(*args, ROBOT_RATE_HZ)
    ts, qs, qds, qdds, index_s = sample_trajectory(*args, sensor_rate_hz)
    physics = SensorPhysics(truth, SettablePose(), robot=robot, seed=seed, start_time_s=0.0)
    wrench = physics.noiseless_wrench_moving(qs, qds, qdds, ts)
    if wrong_tool_kg:
        validation = np.isin(index_s, [k for k, p in enumerate(plan.purposes) if p == "validate"])
        physics.set_tool(truth.mass_kg + wrong_tool_kg, truth.center_of_mass_m)
        wrench[validation] = physics.noiseless_wrench_moving(qs[validation], qds[validation], qdds[validation],
                                                             ts[validation])
        physics.set_tool(truth.mass_kg, truth.center_of_mass_m)
    wrench += physics.ringdown_at(ts, qs, qds, qdds)
    speed = np.max(np.abs(qds), axis=1)[:, None]
    sigma = np.array(truth.force_noise_n + truth.torque_noise_nm) * (1 + truth.motion_noise_gain * speed)
    wrench += np.random.default_rng(seed).standard_normal(wrench.shape) * sigma
    holds = np.full((len(plan.waypoints_rad), 2), -1, dtype=int)
    for k in range(len(plan.waypoints_rad)):
        rows = np.flatnonzero(index == k)
        if rows.size:
            holds[k] = (rows[0], rows[-1] + 1)
    record = MotionRecord(ts, wrench, t, q, qd, qdd)
    return QuickRecording(record, holds, len(plan.waypoints_rad))


__all__ = ["synthesize_recording", "ROBOT_RATE_HZ", "SENSOR_RATE_HZ"]
