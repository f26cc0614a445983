"""The simulated cell's rigid-body physics: the flange's motion from (q, q̇, q̈) and the wrench a rigid tool exerts
on the sensor, vectorised over samples.

Written independently of Pinocchio on purpose (Newton-Euler by hand on UR's DH chain), so that
``tests/test_world_dynamics.py`` can cross-check it against Pinocchio's body regressor and RNEA: the product's
dynamic model uses Pinocchio, the simulated world does not, and the two must agree.

Kinematics (base frame B, DH frames 0..6, frame 6 = flange E): joint i turns about z_{i-1} through o_{i-1}.
Link i's angular velocity and acceleration are ω_i = ω_{i-1} + z_{i-1} q̇_i and
α_i = α_{i-1} + z_{i-1} q̈_i + ω_{i-1} × z_{i-1} q̇_i; the origin o_{i-1} is a point of link i (it lies on joint
i's axis), so a_{o_i} = a_{o_{i-1}} + α_i × r + ω_i × (ω_i × r) with r = o_i − o_{i-1}.

Tool (Newton-Euler about the sensor origin S; c the centre of mass, I_c its inertia about c): the sensor feels
what the tool exerts on it, the opposite of what holds the tool up and accelerates it,

    F = m (g − a_c)
    T = (c − p_S) × m (g − a_c) − (I_c α + ω × I_c ω)

which at rest is the static model (F = m g_S, T = c_S × F) the paper and ``ftacq.calibration`` use.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ftacq.kinematics import URModel, dh_step


@dataclass(frozen=True)
class FlangeMotion:
    """The flange's motion for S samples, base frame (SI units).

    Attributes:
        base_R_flange (S, 3, 3); position_m (S, 3) of the flange origin; angular_velocity_rad_s (S, 3);
        angular_acceleration_rad_s2 (S, 3); velocity_m_s (S, 3) and acceleration_m_s2 (S, 3) of the flange origin.
    """

    base_R_flange: np.ndarray
    position_m: np.ndarray
    angular_velocity_rad_s: np.ndarray
    angular_acceleration_rad_s2: np.ndarray
    velocity_m_s: np.ndarray
    acceleration_m_s2: np.ndarray

    def point_velocity(self, offset_base_m: np.ndarray) -> np.ndarray:
        """Velocity (S, 3) of the points ``position_m + offset_base_m`` fixed to the flange (offset in the base frame)."""
        return self.velocity_m_s + _cross(self.angular_velocity_rad_s, offset_base_m)

    def point_acceleration(self, offset_base_m: np.ndarray) -> np.ndarray:
        """Acceleration (S, 3) of the points ``position_m + offset_base_m`` fixed to the flange."""
        w = self.angular_velocity_rad_s
        return (self.acceleration_m_s2 + _cross(self.angular_acceleration_rad_s2, offset_base_m)
                + _cross(w, _cross(w, offset_base_m)))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b over the last axis (np.cross costs ~10× more on the small arrays used here)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0], out[..., 1], out[..., 2] = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    return out


@lru_cache(maxsize=16)
def _dh_steps(model: URModel) -> np.ndarray:
    return np.stack([dh_step(model, i) for i in range(6)])


def _dh_frames(model: URModel, q: np.ndarray) -> np.ndarray:
    """base_T_frame_i (S, 6, 4, 4): Rz(q_i) then the fixed DH step, composed (few numpy calls: this runs per tick)."""
    n = q.shape[0]
    turns = np.zeros((n, 6, 4, 4))
    c, s = np.cos(q), np.sin(q)
    turns[..., 0, 0], turns[..., 0, 1], turns[..., 1, 0], turns[..., 1, 1] = c, -s, s, c
    turns[..., 2, 2] = turns[..., 3, 3] = 1.0
    steps = turns @ _dh_steps(model)
    frames = np.empty_like(steps)
    frames[:, 0] = steps[:, 0]
    for i in range(1, 6):
        frames[:, i] = frames[:, i - 1] @ steps[:, i]
    return frames


def flange_motion(model: URModel, q_rad: np.ndarray, qd_rad_s: np.ndarray, qdd_rad_s2: np.ndarray) -> FlangeMotion:
    """Return the flange's motion for joint positions, speeds and accelerations (each (S, 6) or (6,)).

    The recursion of the module docstring, unrolled over the six joints at once (cumulative sums)."""
    q = np.asarray(q_rad, dtype=float).reshape(-1, 6)
    qd = np.broadcast_to(np.asarray(qd_rad_s, dtype=float).reshape(-1, 6), q.shape)[..., None]
    qdd = np.broadcast_to(np.asarray(qdd_rad_s2, dtype=float).reshape(-1, 6), q.shape)[..., None]
    frames = _dh_frames(model, q)  # (S, 6, 4, 4): base_T_frame_1 .. base_T_frame_6
    n = q.shape[0]
    axes = np.empty((n, 6, 3))  # z_0 .. z_5: joint i+1 turns about z_i through o_i
    axes[:, 0] = (0.0, 0.0, 1.0)
    axes[:, 1:] = frames[:, :5, :3, 2]
    origins = np.zeros((n, 7, 3))  # o_0 .. o_6
    origins[:, 1:] = frames[:, :, :3, 3]
    joint_rates = axes * qd
    w = np.cumsum(joint_rates, axis=1)  # ω of links 1..6
    dw = np.cumsum(axes * qdd + _cross(w - joint_rates, joint_rates), axis=1)
    r = origins[:, 1:] - origins[:, :-1]
    v = _cross(w, r).sum(axis=1)
    a = (_cross(dw, r) + _cross(w, _cross(w, r))).sum(axis=1)
    return FlangeMotion(frames[:, 5, :3, :3], origins[:, 6], w[:, 5], dw[:, 5], v, a)


def tool_wrench_on_sensor(motion: FlangeMotion, gravity_base_m_s2: np.ndarray, sensor_R_flange: np.ndarray,
                          flange_p_sensor_m: np.ndarray, mass_kg: float, center_of_mass_m: np.ndarray,
                          inertia_kg_m2: np.ndarray) -> np.ndarray:
    """Return the wrench (S, 6) [F (N), T about the sensor origin (N·m)] the tool exerts on the sensor, sensor frame.

    ``center_of_mass_m`` and ``inertia_kg_m2`` (about the centre of mass) are in the sensor frame;
    ``flange_p_sensor_m`` is the sensor origin in the flange frame; ``gravity_base_m_s2`` the gravity vector (m/s²).
    """
    base_R_sensor = motion.base_R_flange @ np.asarray(sensor_R_flange, dtype=float).T  # (S, 3, 3)
    sensor_offset = motion.base_R_flange @ np.asarray(flange_p_sensor_m, dtype=float)  # (S, 3)
    com_offset = base_R_sensor @ np.asarray(center_of_mass_m, dtype=float)  # from S to c, base frame
    a_com = motion.point_acceleration(sensor_offset + com_offset)
    force = mass_kg * (np.asarray(gravity_base_m_s2, dtype=float) - a_com)
    w, dw = motion.angular_velocity_rad_s, motion.angular_acceleration_rad_s2
    inertia_base = base_R_sensor @ np.asarray(inertia_kg_m2, dtype=float) @ np.swapaxes(base_R_sensor, 1, 2)
    spin = np.einsum("sij,sj->si", inertia_base, dw) + _cross(w, np.einsum("sij,sj->si", inertia_base, w))
    torque = _cross(com_offset, force) - spin
    to_sensor = np.swapaxes(base_R_sensor, 1, 2)
    return np.concatenate([np.einsum("sij,sj->si", to_sensor, force), np.einsum("sij,sj->si", to_sensor, torque)],
                          axis=1)
