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

import numpy as np

from ftacq.kinematics import URModel, dh_transforms_batch


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
        return self.velocity_m_s + np.cross(self.angular_velocity_rad_s, offset_base_m)

    def point_acceleration(self, offset_base_m: np.ndarray) -> np.ndarray:
        """Acceleration (S, 3) of the points ``position_m + offset_base_m`` fixed to the flange."""
        w = self.angular_velocity_rad_s
        return (self.acceleration_m_s2 + np.cross(self.angular_acceleration_rad_s2, offset_base_m)
                + np.cross(w, np.cross(w, offset_base_m)))


def flange_motion(model: URModel, q_rad: np.ndarray, qd_rad_s: np.ndarray, qdd_rad_s2: np.ndarray) -> FlangeMotion:
    """Return the flange's motion for joint positions, speeds and accelerations (each (S, 6) or (6,))."""
    q = np.asarray(q_rad, dtype=float).reshape(-1, 6)
    qd = np.broadcast_to(np.asarray(qd_rad_s, dtype=float).reshape(-1, 6), q.shape)
    qdd = np.broadcast_to(np.asarray(qdd_rad_s2, dtype=float).reshape(-1, 6), q.shape)
    frames = dh_transforms_batch(model, q)
    n = q.shape[0]
    z = np.tile([0.0, 0.0, 1.0], (n, 1))
    origin = np.zeros((n, 3))
    w = np.zeros((n, 3))
    dw = np.zeros((n, 3))
    a = np.zeros((n, 3))
    v = np.zeros((n, 3))
    for i in range(6):
        joint_rate = z * qd[:, i:i + 1]
        dw = dw + z * qdd[:, i:i + 1] + np.cross(w, joint_rate)
        w = w + joint_rate
        next_origin = frames[:, i, :3, 3]
        r = next_origin - origin
        v = v + np.cross(w, r)
        a = a + np.cross(dw, r) + np.cross(w, np.cross(w, r))
        origin, z = next_origin, frames[:, i, :3, 2]
    return FlangeMotion(frames[:, 5, :3, :3], origin, w, dw, v, a)


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
    spin = np.einsum("sij,sj->si", inertia_base, dw) + np.cross(w, np.einsum("sij,sj->si", inertia_base, w))
    torque = np.cross(com_offset, force) - spin
    to_sensor = np.swapaxes(base_R_sensor, 1, 2)
    return np.concatenate([np.einsum("sij,sj->si", to_sensor, force), np.einsum("sij,sj->si", to_sensor, torque)],
                          axis=1)
