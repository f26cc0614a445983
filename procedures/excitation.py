"""The excitation stage: a short motion that makes the tool's inertia visible, planned and checked like the poses,
recorded with the robot's state, then identified (:mod:`ftacq.dynamics.identify`).

Plan: a chain of moveJs from the start configuration to random joint targets around it and back — small
amplitudes on the base, shoulder and elbow (the tool stays near where the poses were), large ones on the three
wrist joints (they turn the tool about every axis: that is what identifies the inertia) — each at the CELL.toml
joint speed and acceleration. Every segment is checked as the calibration's moves are
(:func:`procedures.plan.check_path`: joint limits and collisions along the whole path, tool cylinder and table
included); a target whose segment is not clear is drawn again. The plan states its duration; the robot moves only
after the operator confirmed it (as for the poses).

Recording: :func:`procedures.motion_runner.run_waypoints` (the quick calibration's runner too): the sensor in its
own thread, every RTDE state, both on the host clock through the devices' own clocks; Ctrl-C stops the robot and
keeps what was recorded. The residual lag is measured by the identification.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ftacq.dynamics.identify import MotionRecord
from ftacq.errors import PlanError
from ftacq.kinematics.trapezoid import trapezoid_duration_s
from procedures import events
from procedures.motion_runner import run_waypoints

log = logging.getLogger(__name__)

AMPLITUDE_RAD = (0.25, 0.2, 0.25, 1.0, 1.0, 1.5)
"""Largest excursion of each joint from the start configuration (base … wrist 3), rad."""
DEFAULT_MOVES = 10
"""Segments before the return to the start (≈ 2 s each at 1 rad/s, 2 rad/s²)."""
MAX_DRAWS = 200
"""Random targets tried per segment before the plan gives up."""


@dataclass(frozen=True)
class ExcitationPlan:
    """A checked excitation: moveJ joint targets (K, 6) rad from ``start_q_rad`` (the last one is the start again),
    at ``speed_rad_s`` and ``acceleration_rad_s2``; ``estimated_duration_s`` on a real robot."""

    start_q_rad: np.ndarray
    targets_rad: np.ndarray
    speed_rad_s: float
    acceleration_rad_s2: float
    estimated_duration_s: float
    seed: int = 0

    def to_json(self) -> dict:
        return {"start_q_rad": self.start_q_rad.tolist(), "targets_rad": self.targets_rad.tolist(),
                "speed_rad_s": self.speed_rad_s, "acceleration_rad_s2": self.acceleration_rad_s2,
                "estimated_duration_s": self.estimated_duration_s, "seed": self.seed}


def plan_excitation(settings, start_q_rad: np.ndarray, moves: int = DEFAULT_MOVES, seed: int = 0,
                    amplitude_rad: tuple[float, ...] = AMPLITUDE_RAD) -> ExcitationPlan:
    """Plan and check an excitation from ``start_q_rad`` with the plan settings' joint speed and acceleration.

    Raises PlanError when no clear segment is found (a cramped cell: reduce the amplitudes or move the start)."""
    from procedures.plan import check_path

    rng = np.random.default_rng(seed)
    start = np.asarray(start_q_rad, dtype=float).reshape(6)
    amplitude = np.asarray(amplitude_rad, dtype=float)
    speed, acceleration = float(settings.joint_speed_rad_s), float(settings.joint_acceleration_rad_s2)
    targets, q, problems = [], start, []
    for index in range(moves + 1):
        for _ in range(MAX_DRAWS):
            if index == moves:
                candidate = start
            else:  # a random excursion of every joint, each with a random sign
                candidate = start + amplitude * rng.uniform(0.4, 1.0, 6) * rng.choice((-1.0, 1.0), 6)
            problems = check_path(settings, q, candidate)
            if not problems or index == moves:
                break
        if problems:
            raise PlanError(f"excitation segment {index + 1}: no clear path found ({problems[0]}); move the robot to "
                            "a freer start configuration or reduce the excitation")
        targets.append(candidate)
        q = candidate
    targets_array = np.array(targets)
    path = np.vstack([start, targets_array])
    duration = sum(trapezoid_duration_s(float(np.max(np.abs(b - a))), speed, acceleration)
                   for a, b in zip(path[:-1], path[1:]))
    return ExcitationPlan(start, targets_array, speed, acceleration, float(duration), seed)


def format_excitation(plan: ExcitationPlan) -> str:
    """A few lines for the operator: what will move, how fast, how long."""
    span = np.ptp(np.vstack([plan.start_q_rad, plan.targets_rad]), axis=0)
    return (f"Excitation plan: {len(plan.targets_rad)} moveJ segments around the current configuration, "
            f"joint speed {plan.speed_rad_s:g} rad/s, acceleration {plan.acceleration_rad_s2:g} rad/s²\n"
            f"  joint ranges (rad): " + " ".join(f"{v:.2f}" for v in span) + "\n"
            f"  every segment checked for joint limits and collisions along its path: clear\n"
            f"  estimated duration: {plan.estimated_duration_s:.1f} s (ends where it started)")


def record_excitation(plan: ExcitationPlan, robot, sensor, stream, move_timeout_s: float = 60.0,
                      listeners: Sequence[events.Listener] = ()) -> MotionRecord:
    """Run the plan (moveJ after moveJ) while recording sensor and robot (:func:`procedures.motion_runner.
    run_waypoints`, which publishes the run's events to ``listeners``); return the record (host clock).
    Ctrl-C or a fault stops the robot; the recording made so far is attached to the raised exception as
    ``error.motion_record``."""
    try:
        return run_waypoints(robot, sensor, stream, plan.targets_rad, plan.speed_rad_s, plan.acceleration_rad_s2,
                             move_timeout_s=move_timeout_s, listeners=listeners).record
    except BaseException as error:
        run = getattr(error, "motion_run", None)
        if run is not None:
            error.motion_record = run.record  # type: ignore[attr-defined]
        raise


