"""The moveJ time law, in one place: the leading joint on a rest-to-rest trapezoid (a triangle when the move is too
short to reach the speed), the other joints in proportion, as a UR controller synchronises them.

Used by the planner's duration estimates (:mod:`procedures.plan`), the excitation and quick trajectories
(:mod:`procedures.excitation`, :mod:`procedures.quick`) and the simulated technician's jog; the simulated arm's
stateful profile (``tests/fakes/ur_motion.Trapezoid``, which also starts from a speed for stops) follows the same law.
Speeds in rad/s, accelerations in rad/s², times in s.
"""

from __future__ import annotations

import numpy as np


def trapezoid_duration_s(distance_rad: float, speed_rad_s: float, acceleration_rad_s2: float) -> float:
    """Return the duration of a rest-to-rest trapezoidal (or triangular) profile over ``distance_rad``, s."""
    distance_rad = abs(float(distance_rad))
    if distance_rad == 0.0:
        return 0.0
    if distance_rad >= speed_rad_s**2 / acceleration_rad_s2:
        return distance_rad / speed_rad_s + speed_rad_s / acceleration_rad_s2
    return float(2.0 * np.sqrt(distance_rad / acceleration_rad_s2))


def move_duration_s(q_from: np.ndarray, q_to: np.ndarray, speed_rad_s: float, acceleration_rad_s2: float) -> float:
    """Return the duration of a moveJ q_from → q_to (6,): the leading joint's trapezoid, s."""
    delta = float(np.max(np.abs(np.asarray(q_to, dtype=float) - np.asarray(q_from, dtype=float))))
    return trapezoid_duration_s(delta, speed_rad_s, acceleration_rad_s2)


def move_profile(q_from: np.ndarray, q_to: np.ndarray, speed_rad_s: float, acceleration_rad_s2: float,
                 t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (q, q̇, q̈) (len(t), 6) of a moveJ at times ``t`` (s from its start; held at the ends outside
    [0, :func:`move_duration_s`])."""
    speed, acceleration = speed_rad_s, acceleration_rad_s2
    delta = np.asarray(q_to, dtype=float) - np.asarray(q_from, dtype=float)
    length = float(np.max(np.abs(delta)))
    t = np.asarray(t, dtype=float)
    if length == 0.0:
        return np.tile(q_from, (t.size, 1)), np.zeros((t.size, 6)), np.zeros((t.size, 6))
    direction = delta / length
    if length >= speed * speed / acceleration:
        t_acc, peak = speed / acceleration, speed
        t_cruise = length / speed - speed / acceleration
    else:
        t_acc = float(np.sqrt(length / acceleration))
        peak, t_cruise = acceleration * t_acc, 0.0
    total = 2 * t_acc + t_cruise
    tc = np.clip(t, 0.0, total)
    s = np.where(tc < t_acc, 0.5 * acceleration * tc ** 2,
                 np.where(tc < t_acc + t_cruise, 0.5 * acceleration * t_acc ** 2 + peak * (tc - t_acc),
                          length - 0.5 * acceleration * (total - tc) ** 2))
    v = np.where(tc < t_acc, acceleration * tc, np.where(tc < t_acc + t_cruise, peak, acceleration * (total - tc)))
    a = np.where(tc < t_acc, acceleration, np.where(tc < t_acc + t_cruise, 0.0, -acceleration))
    a = np.where((t <= 0) | (t >= total), 0.0, a)
    return np.asarray(q_from) + np.outer(s, direction), np.outer(v, direction), np.outer(a, direction)


__all__ = ["trapezoid_duration_s", "move_duration_s", "move_profile"]
