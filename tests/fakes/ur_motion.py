"""Motion model of the simulated UR controller: trapezoidal moveJ / moveL profiles and decelerating stops.

A move is a 1-D profile ``s(t)`` along a straight path (joint space for moveJ, Cartesian position with slerped
orientation for moveL). ``speed`` and ``acceleration`` bound the leading axis (moveJ, rad/s and rad/s²) or the
tool path (moveL, m/s and m/s²), as URScript's ``movej``/``movel`` do. Joint angles along a moveL come from a
damped Newton step on the DH forward kinematics of :mod:`ftacq.kinematics`, seeded with the previous angles.
"""

from __future__ import annotations

import functools

import numpy as np

from ftacq.kinematics import URModel, dh_transforms, flange_pose
from ftacq.kinematics.trapezoid import Trapezoid as TimeLaw
from ftacq.so3 import rotation_from_rotvec, rotvec_from_rotation

MAX_SWITCHES = 3
"""A trapezoid changes its acceleration at most three times (end of acceleration, of cruise, of deceleration)."""
IK_TOLERANCE_M = 1e-12
"""Newton iterations stop when the pose error (m / rad) is below this."""
IK_MAX_ITERATIONS = 8
IK_DAMPING = 1e-9
IK_STEP_LIMIT_RAD = 0.5
"""A Newton step larger than this means the target is out of reach (singular or beyond the workspace)."""


class Trapezoid(TimeLaw):
    """The controller's time law (:class:`ftacq.kinematics.trapezoid.Trapezoid`, the planner's too) and when its
    acceleration changes next (the simulated controller steps from switch to switch).

    A time given as a Python float is evaluated with floats (the controller asks for one time per 2 ms tick): the
    base class's arithmetic, operation for operation, without its arrays (tests/test_fakes_replay.py)."""

    def position(self, t):
        if type(t) is not float:
            return super().position(t)
        a, v0, peak, t_acc, t_cruise = (self.acceleration, self.initial_speed, self.peak_speed, self.accelerate_s,
                                        self.cruise_s)
        t = min(max(t, 0.0), self.duration_s)
        s_acc = v0 * t_acc + 0.5 * a * t_acc ** 2
        if t <= t_acc:
            return float(v0 * t + 0.5 * a * t * t)
        if t <= t_acc + t_cruise:
            return float(s_acc + peak * (t - t_acc))
        td = t - t_acc - t_cruise
        return float(s_acc + peak * t_cruise + peak * td - 0.5 * a * td * td)

    def speed_at(self, t):
        if type(t) is not float:
            return super().speed_at(t)
        if t < 0.0 or t >= self.duration_s:
            return 0.0
        a, v0, peak, t_acc, t_cruise = (self.acceleration, self.initial_speed, self.peak_speed, self.accelerate_s,
                                        self.cruise_s)
        if t <= t_acc:
            return float(v0 + a * t)
        if t <= t_acc + t_cruise:
            return float(peak)
        return float(max(peak - a * (t - t_acc - t_cruise), 0.0))

    def acceleration_at(self, t):
        if type(t) is not float:
            return super().acceleration_at(t)
        if t < 0.0 or t >= self.duration_s or self.peak_speed <= 0.0:
            return 0.0
        if t < self.accelerate_s:
            return float(self.acceleration)
        return 0.0 if t < self.accelerate_s + self.cruise_s else float(-self.acceleration)

    def switches(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Return (times from t to each later change of acceleration (3,), the acceleration after each (3,)),
        padded with inf and 0 when fewer are left."""
        times, after = np.full(MAX_SWITCHES, np.inf), np.zeros(MAX_SWITCHES)
        k = 0
        for boundary in (self.accelerate_s, self.accelerate_s + self.cruise_s, self.duration_s):
            if boundary > t and (k == 0 or boundary - t > times[k - 1]):
                times[k], after[k] = boundary - t, self.acceleration_at(boundary)
                k += 1
        return times, after


def joint_positions_for_pose(model: URModel, pose: np.ndarray, q_seed: np.ndarray) -> np.ndarray | None:
    """Return joint angles near ``q_seed`` whose flange pose is ``pose`` (damped Newton), or None if unreachable."""
    target_R = rotation_from_rotvec(pose[3:6])
    target_p = np.asarray(pose[:3], dtype=float)
    q = np.array(q_seed, dtype=float)
    for _ in range(IK_MAX_ITERATIONS):
        frames = dh_transforms(model, q)
        p_end = frames[-1][:3, 3]
        error = np.concatenate([target_p - p_end, rotvec_from_rotation(target_R @ frames[-1][:3, :3].T)])
        if np.max(np.abs(error)) < IK_TOLERANCE_M:
            return q
        jacobian = np.empty((6, 6))
        for i in range(6):
            origin, axis = (np.zeros(3), np.array([0.0, 0.0, 1.0])) if i == 0 else (frames[i - 1][:3, 3], frames[i - 1][:3, 2])
            jacobian[:3, i] = np.cross(axis, p_end - origin)
            jacobian[3:, i] = axis
        step = np.linalg.solve(jacobian.T @ jacobian + IK_DAMPING * np.eye(6), jacobian.T @ error)
        if np.max(np.abs(step)) > IK_STEP_LIMIT_RAD:
            return None
        q = q + step
    frames = dh_transforms(model, q)
    residual = np.linalg.norm(frames[-1][:3, 3] - target_p)
    return q if residual < 1e-6 else None


class Motion:
    """One active motion: ``sample(t)`` gives (q, qd) at motion time t (s); ``done(t)`` when at rest."""

    kind = "none"

    def __init__(self, model: URModel, q_start: np.ndarray) -> None:
        self.model = model
        self.q_start = np.array(q_start, dtype=float)
        self.profile = Trapezoid(0.0, 0.0, 1.0)

    @property
    def duration_s(self) -> float:
        return self.profile.duration_s

    def done(self, t: float) -> bool:
        return t >= self.profile.duration_s

    def path_speed(self, t: float) -> float:
        return self.profile.speed_at(t)

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Return (q, qd) at t, or None when the path leaves the reachable workspace."""
        raise NotImplementedError

    def acceleration(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Return (q̈ at t (rad/s²), times to the later changes of q̈ (3,) s, q̈ after each (3, 6)), or None when
        the motion has no closed form for it (moveL: the caller differentiates q̇)."""
        return None

    def stopping(self, t: float, deceleration: float) -> "Motion":
        """Return a motion that decelerates along the same path from time t at ``deceleration`` (path units/s²)."""
        return _Stopping(self, t, deceleration)


class JointMove(Motion):
    """moveJ: straight line in joint space; speed/acceleration bound the leading axis (rad/s, rad/s²)."""

    kind = "movej"

    def __init__(self, model: URModel, q_start: np.ndarray, q_target: np.ndarray, speed: float,
                 acceleration: float) -> None:
        super().__init__(model, q_start)
        self.q_target = np.array(q_target, dtype=float)
        delta = self.q_target - self.q_start
        self.length = float(np.max(np.abs(delta)))
        self.direction = delta / self.length if self.length > 0 else np.zeros(6)
        self.profile = Trapezoid(self.length, speed, acceleration)

    def at_distance(self, s: float, ds: float) -> tuple[np.ndarray, np.ndarray] | None:
        if s >= self.length:
            return self.q_target.copy(), self.direction * ds
        return self.q_start + self.direction * s, self.direction * ds

    def sample(self, t: float):
        return self.at_distance(self.profile.position(t), self.profile.speed_at(t))

    def acceleration(self, t: float):
        times, after = self.profile.switches(t)
        return self.direction * self.profile.acceleration_at(t), times, np.outer(after, self.direction)


class LinearMove(Motion):
    """moveL: straight line of the flange position, slerped orientation; speed in m/s (rad/s for pure turns)."""

    kind = "movel"

    def __init__(self, model: URModel, q_start: np.ndarray, pose_target: np.ndarray, speed: float,
                 acceleration: float) -> None:
        super().__init__(model, q_start)
        self.pose_start = flange_pose(model, self.q_start)
        self.pose_target = np.array(pose_target, dtype=float)
        self.R_start = rotation_from_rotvec(self.pose_start[3:6])
        self.turn = rotvec_from_rotation(rotation_from_rotvec(self.pose_target[3:6]) @ self.R_start.T)
        translation = float(np.linalg.norm(self.pose_target[:3] - self.pose_start[:3]))
        angle = float(np.linalg.norm(self.turn))
        self.length = translation if translation > 1e-9 else angle
        self.profile = Trapezoid(self.length, speed, acceleration)
        self._q_last = self.q_start.copy()
        self._t_last = 0.0

    def pose_at(self, s: float) -> np.ndarray:
        f = 1.0 if self.length <= 0 else min(s / self.length, 1.0)
        position = self.pose_start[:3] + f * (self.pose_target[:3] - self.pose_start[:3])
        rotation = rotation_from_rotvec(f * self.turn) @ self.R_start
        return np.concatenate([position, rotvec_from_rotation(rotation)])

    def at_distance(self, s: float, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        q = joint_positions_for_pose(self.model, self.pose_at(s), self._q_last)
        if q is None:
            return None
        dt = t - self._t_last
        qd = (q - self._q_last) / dt if dt > 0 else np.zeros(6)
        self._q_last, self._t_last = q, t
        return q, qd

    def sample(self, t: float):
        return self.at_distance(self.profile.position(t), t)


class _Stopping(Motion):
    """Deceleration along an interrupted motion's path."""

    def __init__(self, base: Motion, t_stop: float, deceleration: float) -> None:
        super().__init__(base.model, base.q_start)
        self.kind = base.kind
        self.base = base
        self.t_stop = t_stop
        self.s0 = base.profile.position(t_stop)
        v0 = base.profile.speed_at(t_stop)
        self.profile = Trapezoid(v0 * v0 / (2 * deceleration) if v0 > 0 else 0.0, 0.0, deceleration, v0)

    def sample(self, t: float):
        s = self.s0 + self.profile.position(t)
        ds = self.profile.speed_at(t)
        if isinstance(self.base, LinearMove):
            return self.base.at_distance(s, self.t_stop + t)
        return self.base.at_distance(s, ds)

    def acceleration(self, t: float):
        if not isinstance(self.base, JointMove):
            return None
        times, after = self.profile.switches(t)
        return self.base.direction * self.profile.acceleration_at(t), times, np.outer(after, self.base.direction)


@functools.lru_cache(maxsize=16)
def _joint_limits(model: URModel) -> tuple[tuple[float, ...], tuple[float, ...]]:
    return (tuple((np.array(model.joint_min_rad) - 1e-12).tolist()),
            tuple((np.array(model.joint_max_rad) + 1e-12).tolist()))


def within_joint_limits(model: URModel, q: np.ndarray) -> bool:
    """True when every joint angle is inside the model's position limits (checked per tick while moving)."""
    low, high = _joint_limits(model)
    return all(lo <= angle <= hi for lo, angle, hi in zip(low, np.asarray(q, dtype=float).tolist(), high))
