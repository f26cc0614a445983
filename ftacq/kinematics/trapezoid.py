"""The moveJ time law, in one place: the leading joint on a trapezoidal speed profile (a triangle when the move is
too short to reach the speed), the other joints in proportion, as a UR controller synchronises them.

:class:`Trapezoid` is the profile s(t) along one path coordinate (rad for a moveJ's leading joint, m for a moveL's
tool path), from an initial speed (a stop's) to rest. Used by the planner's duration estimates
(:mod:`procedures.plan`), the excitation and quick trajectories (:mod:`procedures.excitation`,
:mod:`procedures.quick`), the simulated technician's jog and the simulated arm (``tests/fakes/ur_motion.py``).
Speeds in rad/s (m/s), accelerations in rad/s² (m/s²), times in s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Trapezoid:
    """A trapezoidal (or triangular) speed profile covering ``distance`` and ending at rest.

    ``s(t)`` starts at 0 with speed ``initial_speed`` (≥ 0, used by stops), accelerates at ``acceleration`` up to
    ``speed``, cruises, and decelerates to rest at ``distance``; ``speed`` 0 with an initial speed is a pure
    deceleration (a stop: it comes to rest at :attr:`end_distance`). Methods take a time (s from the start) or an
    array of them.
    """

    distance: float
    speed: float
    acceleration: float
    initial_speed: float = 0.0
    accelerate_s: float = field(init=False, default=0.0)
    cruise_s: float = field(init=False, default=0.0)
    decelerate_s: float = field(init=False, default=0.0)
    peak_speed: float = field(init=False, default=0.0)

    def __post_init__(self) -> None:
        d, v, a, v0 = max(self.distance, 0.0), self.speed, self.acceleration, self.initial_speed
        if d <= 0.0 or a <= 0.0:
            return
        if v0 > 0.0 and v <= 0.0:  # pure deceleration (stop)
            self.peak_speed, self.decelerate_s = v0, v0 / a
            return
        v = max(v, 1e-12)
        needed = (v * v - v0 * v0) / (2 * a) + v * v / (2 * a)  # to accelerate v0 -> v and decelerate v -> 0
        if needed <= d:
            self.peak_speed = v
            self.accelerate_s, self.decelerate_s, self.cruise_s = (v - v0) / a, v / a, (d - needed) / v
        else:
            peak = math.sqrt(max(a * d + v0 * v0 / 2.0, 0.0))
            self.peak_speed = peak
            self.accelerate_s, self.decelerate_s = max(peak - v0, 0.0) / a, peak / a

    @property
    def duration_s(self) -> float:
        return self.accelerate_s + self.cruise_s + self.decelerate_s

    @property
    def end_distance(self) -> float:
        """Where the profile comes to rest (equals ``distance`` except for pure stops)."""
        return float(self.position(self.duration_s))

    def position(self, t):
        """Return s(t) (held at the profile's ends outside [0, :attr:`duration_s`])."""
        a, v0, peak, t_acc, t_cruise = (self.acceleration, self.initial_speed, self.peak_speed, self.accelerate_s,
                                        self.cruise_s)
        t = np.clip(t, 0.0, self.duration_s)
        s_acc = v0 * t_acc + 0.5 * a * t_acc ** 2
        td = t - t_acc - t_cruise
        s = np.where(t <= t_acc, v0 * t + 0.5 * a * t * t,
                     np.where(t <= t_acc + t_cruise, s_acc + peak * (t - t_acc),
                              s_acc + peak * t_cruise + peak * td - 0.5 * a * td * td))
        return float(s) if s.ndim == 0 else s

    def speed_at(self, t):
        """Return ds/dt at t (0 outside the profile)."""
        a, v0, peak, t_acc, t_cruise = (self.acceleration, self.initial_speed, self.peak_speed, self.accelerate_s,
                                        self.cruise_s)
        t = np.asarray(t, dtype=float)
        v = np.where(t <= t_acc, v0 + a * t,
                     np.where(t <= t_acc + t_cruise, peak, np.maximum(peak - a * (t - t_acc - t_cruise), 0.0)))
        v = np.where((t < 0.0) | (t >= self.duration_s), 0.0, v)
        return float(v) if v.ndim == 0 else v

    def acceleration_at(self, t):
        """Return d²s/dt² at t: +a while accelerating, 0 cruising or at rest, −a while decelerating (phases
        half-open on the right, so the value at a phase boundary is the next phase's)."""
        t = np.asarray(t, dtype=float)
        a = np.where(t < self.accelerate_s, self.acceleration,
                     np.where(t < self.accelerate_s + self.cruise_s, 0.0, -self.acceleration))
        a = np.where((t < 0.0) | (t >= self.duration_s) | (self.peak_speed <= 0.0), 0.0, a)
        return float(a) if a.ndim == 0 else a


def trapezoid_duration_s(distance_rad: float, speed_rad_s: float, acceleration_rad_s2: float) -> float:
    """Return the duration of a rest-to-rest trapezoidal (or triangular) profile over ``distance_rad``, s."""
    return Trapezoid(abs(float(distance_rad)), speed_rad_s, acceleration_rad_s2).duration_s


def move_duration_s(q_from: np.ndarray, q_to: np.ndarray, speed_rad_s: float, acceleration_rad_s2: float) -> float:
    """Return the duration of a moveJ q_from → q_to (6,): the leading joint's trapezoid, s."""
    delta = float(np.max(np.abs(np.asarray(q_to, dtype=float) - np.asarray(q_from, dtype=float))))
    return trapezoid_duration_s(delta, speed_rad_s, acceleration_rad_s2)


def move_profile(q_from: np.ndarray, q_to: np.ndarray, speed_rad_s: float, acceleration_rad_s2: float,
                 t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (q, q̇, q̈) (len(t), 6) of a moveJ at times ``t`` (s from its start; held at the ends outside
    [0, :func:`move_duration_s`], q̈ 0 at both ends)."""
    delta = np.asarray(q_to, dtype=float) - np.asarray(q_from, dtype=float)
    length = float(np.max(np.abs(delta)))
    t = np.atleast_1d(np.asarray(t, dtype=float))
    if length == 0.0:
        return np.tile(q_from, (t.size, 1)), np.zeros((t.size, 6)), np.zeros((t.size, 6))
    direction = delta / length
    profile = Trapezoid(length, speed_rad_s, acceleration_rad_s2)
    a = np.where(t <= 0, 0.0, profile.acceleration_at(t))
    return (np.asarray(q_from) + np.outer(profile.position(t), direction), np.outer(profile.speed_at(t), direction),
            np.outer(a, direction))


__all__ = ["Trapezoid", "trapezoid_duration_s", "move_duration_s", "move_profile"]
