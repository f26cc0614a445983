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
        angular_acceleration_rad_s2 (S, 3); velocity_m_s (S, 3) and acceleration_m_s2 (S, 3) of the flange origin;
        base_T_flange (S, 4, 4): the frames themselves (:func:`ftacq.kinematics.forward_kinematics`'s products, in
        its order, so the same bits).
    """

    base_R_flange: np.ndarray
    position_m: np.ndarray
    angular_velocity_rad_s: np.ndarray
    angular_acceleration_rad_s2: np.ndarray
    velocity_m_s: np.ndarray
    acceleration_m_s2: np.ndarray
    base_T_flange: np.ndarray | None = None

    def point_velocity(self, offset_base_m: np.ndarray) -> np.ndarray:
        """Velocity (S, 3) of the points ``position_m + offset_base_m`` fixed to the flange (offset in the base frame)."""
        return self.velocity_m_s + _cross(self.angular_velocity_rad_s, offset_base_m)

    def point_acceleration(self, offset_base_m: np.ndarray) -> np.ndarray:
        """Acceleration (S, 3) of the points ``position_m + offset_base_m`` fixed to the flange."""
        w = self.angular_velocity_rad_s
        return (self.acceleration_m_s2 + _cross(self.angular_acceleration_rad_s2, offset_base_m)
                + _cross(w, _cross(w, offset_base_m)))


_NEXT, _AFTER = np.array([1, 2, 0]), np.array([2, 0, 1])
_EYE4 = np.eye(4)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b over the last axis, component by component as the definition writes it (np.cross costs ~10× more on
    the small arrays used here)."""
    return a[..., _NEXT] * b[..., _AFTER] - a[..., _AFTER] * b[..., _NEXT]


def _skew(v) -> np.ndarray:
    """The (3, 3) matrix K of a constant vector v with x @ K = x × v for row vectors x (one matmul per cross)."""
    x, y, z = (float(c) for c in np.asarray(v, dtype=float).reshape(3))
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


@lru_cache(maxsize=16)
def _dh_steps(model: URModel) -> np.ndarray:
    return np.stack([dh_step(model, i) for i in range(6)])


def dh_frames(model: URModel, q: np.ndarray) -> np.ndarray:
    """base_T_frame_i (S, 7, 4, 4) for configurations q (S, 6), i = 0 (the base itself) .. 6: Rz(q_i) then the fixed
    DH step, composed (few numpy calls: this runs per controller tick and per sensor chunk); frame 6 is
    :func:`ftacq.kinematics.forward_kinematics`'s base_T_flange, the same products in the same order."""
    n = q.shape[0]
    fixed = _dh_steps(model)  # (6, 4, 4)
    c, s = np.cos(q)[..., None], np.sin(q)[..., None]
    steps = np.empty((n, 6, 4, 4))
    steps[:, :, 0] = c * fixed[:, 0] - s * fixed[:, 1]  # Rz(q) @ fixed: rows 0 and 1 turn, rows 2 and 3 stay
    steps[:, :, 1] = s * fixed[:, 0] + c * fixed[:, 1]
    steps[:, :, 2:] = fixed[:, 2:]
    frames = np.empty((n, 7, 4, 4))
    frames[:, 0] = _EYE4
    frames[:, 1] = steps[:, 0]
    for i in range(1, 6):
        np.matmul(frames[:, i], steps[:, i], out=frames[:, i + 1])
    return frames


def flange_motion(model: URModel, q_rad: np.ndarray, qd_rad_s: np.ndarray, qdd_rad_s2: np.ndarray) -> FlangeMotion:
    """Return the flange's motion for joint positions, speeds and accelerations (each (S, 6) or (6,)).

    The recursion of the module docstring, unrolled over the six joints at once (cumulative sums)."""
    q = np.asarray(q_rad, dtype=float).reshape(-1, 6)
    qd = np.asarray(qd_rad_s, dtype=float).reshape(-1, 6, 1)
    qdd = np.asarray(qdd_rad_s2, dtype=float).reshape(-1, 6, 1)
    frames = dh_frames(model, q)  # (S, 7, 4, 4): the base, base_T_frame_1 .. base_T_frame_6
    if len(q) <= FEW_SAMPLES:
        return _flange_motion_few(frames, qd, qdd)
    axes = frames[:, :6, :3, 2]  # z_0 .. z_5: joint i+1 turns about z_i through o_i
    origins = frames[:, :, :3, 3]  # o_0 .. o_6
    joint_rates = axes * qd
    pairs = np.empty((2, 2) + joint_rates.shape)  # two cross products per call: [[a, b], [c, d]] → a × b, c × d
    w = np.cumsum(joint_rates, axis=1, out=pairs[1, 0])  # ω of links 1..6
    np.subtract(w, joint_rates, out=pairs[0, 0])
    pairs[0, 1] = joint_rates
    r = np.subtract(origins[:, 1:], origins[:, :-1], out=pairs[1, 1])
    carried, wr = _cross(pairs[:, 0], pairs[:, 1])  # (ω − q̇ z) × q̇ z, ω × r
    dw = np.cumsum(axes * qdd + carried, axis=1, out=pairs[0, 0])
    pairs[0, 1], pairs[1, 1] = r, wr
    v = wr.sum(axis=1)
    a = _cross(pairs[:, 0], pairs[:, 1]).sum(axis=0).sum(axis=1)  # α × r + ω × (ω × r), summed over the links
    return FlangeMotion(frames[:, 6, :3, :3], origins[:, 6], w[:, 5], dw[:, 5], v, a, frames[:, 6])


FEW_SAMPLES = 2
"""Up to this many samples (the controller's tick: the arm, its target) the recursion runs on floats: numpy's calls
cost more than the arithmetic there."""


def cross3(a: list[float], b: list[float]) -> list[float]:
    """a × b of two 3-vectors given as lists of floats (the controller's one or two samples per tick)."""
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _flange_motion_few(frames: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> FlangeMotion:
    """:func:`flange_motion`'s recursion on floats, sample by sample, operation for operation as its arrays do it
    (cumulative sums in joint order)."""
    n = frames.shape[0]
    qd = (qd if qd.shape[0] == n else np.broadcast_to(qd, (n, 6, 1)))[:, :, 0].tolist()
    qdd = (qdd if qdd.shape[0] == n else np.broadcast_to(qdd, (n, 6, 1)))[:, :, 0].tolist()
    out = np.empty((4, n, 3))  # ω, α, v, a of the flange
    for k in range(n):
        axes, origins = frames[k, :6, :3, 2].tolist(), frames[k, :, :3, 3].tolist()
        w = dw = v = a = None
        for i in range(6):
            z, rate, acceleration = axes[i], qd[k][i], qdd[k][i]
            joint_rate = [z[0] * rate, z[1] * rate, z[2] * rate]
            w_before = w
            w = joint_rate if w is None else [w[0] + joint_rate[0], w[1] + joint_rate[1], w[2] + joint_rate[2]]
            carried = cross3([w[0] - joint_rate[0], w[1] - joint_rate[1], w[2] - joint_rate[2]], joint_rate)
            term = [z[0] * acceleration + carried[0], z[1] * acceleration + carried[1], z[2] * acceleration + carried[2]]
            dw = term if w_before is None else [dw[0] + term[0], dw[1] + term[1], dw[2] + term[2]]
            o, o_next = origins[i], origins[i + 1]
            r = [o_next[0] - o[0], o_next[1] - o[1], o_next[2] - o[2]]
            wr = cross3(w, r)
            dwr, wwr = cross3(dw, r), cross3(w, wr)
            link = [dwr[0] + wwr[0], dwr[1] + wwr[1], dwr[2] + wwr[2]]
            v = wr if v is None else [v[0] + wr[0], v[1] + wr[1], v[2] + wr[2]]
            a = link if a is None else [a[0] + link[0], a[1] + link[1], a[2] + link[2]]
        out[0, k], out[1, k], out[2, k], out[3, k] = w, dw, v, a
    return FlangeMotion(frames[:, 6, :3, :3], frames[:, 6, :3, 3], out[0], out[1], out[2], out[3], frames[:, 6])


@dataclass(frozen=True)
class ToolOnSensor:
    """A rigid tool on the sensor, in the sensor frame, where its centre of mass, its offset from the flange origin
    and its inertia are constant (computed once per tool, not per sample chunk): :meth:`wrench`.

    Attributes:
        flange_R_sensor (3, 3); mass_kg; to_com (3, 3): x @ to_com = x × d, d the flange origin → centre of mass;
        com_cross (3, 3): F @ com_cross = c × F, c the centre of mass (from the sensor origin); inertia_t (3, 3):
        the inertia about the centre of mass, transposed (row vectors: ω @ Iᵀ = (I ω)ᵀ).
    """

    flange_R_sensor: np.ndarray
    mass_kg: float
    to_com: np.ndarray
    com_cross: np.ndarray
    inertia_t: np.ndarray

    @classmethod
    def of(cls, sensor_R_flange, flange_p_sensor_m, mass_kg: float, center_of_mass_m, inertia_kg_m2) -> "ToolOnSensor":
        """The tool of ``center_of_mass_m`` and ``inertia_kg_m2`` (sensor frame) on a sensor at ``flange_p_sensor_m``
        (flange frame) turned by ``sensor_R_flange``."""
        sensor_R_flange = np.asarray(sensor_R_flange, dtype=float)
        com = np.asarray(center_of_mass_m, dtype=float).reshape(3)
        flange_to_com = sensor_R_flange @ np.asarray(flange_p_sensor_m, dtype=float).reshape(3) + com  # sensor frame
        return cls(sensor_R_flange.T, float(mass_kg), _skew(flange_to_com), -_skew(com),
                   np.asarray(inertia_kg_m2, dtype=float).T)

    def wrench(self, motion: FlangeMotion, gravity_base_m_s2) -> np.ndarray:
        """The wrench (S, 6) [F (N), T about the sensor origin (N·m)] the tool exerts on the sensor, sensor frame:
        g, a_E, ω and α turned into the sensor frame together (one product), the rest a few (S, 3) operations."""
        n = motion.base_R_flange.shape[0]
        in_base = np.empty((n, 4, 3))  # rows: g, a_E, ω, α (base frame)
        in_base[:, 0] = gravity_base_m_s2
        in_base[:, 1], in_base[:, 2], in_base[:, 3] = (motion.acceleration_m_s2, motion.angular_velocity_rad_s,
                                                       motion.angular_acceleration_rad_s2)
        in_sensor = in_base @ motion.base_R_flange @ self.flange_R_sensor  # row vectors: xᵀ base_R_flange flange_R_sensor
        g, a_flange, w, dw = in_sensor[:, 0], in_sensor[:, 1], in_sensor[:, 2], in_sensor[:, 3]
        a_com = a_flange + dw @ self.to_com + _cross(w, w @ self.to_com)
        force = self.mass_kg * (g - a_com)
        spin = in_sensor[:, 2:] @ self.inertia_t  # I ω, I α
        torque = force @ self.com_cross - (spin[:, 1] + _cross(w, spin[:, 0]))  # c × F − (I α + ω × I ω)
        return np.concatenate([force, torque], axis=1)


def tool_wrench_on_sensor(motion: FlangeMotion, gravity_base_m_s2: np.ndarray, sensor_R_flange: np.ndarray,
                          flange_p_sensor_m: np.ndarray, mass_kg: float, center_of_mass_m: np.ndarray,
                          inertia_kg_m2: np.ndarray) -> np.ndarray:
    """Return the wrench (S, 6) [F (N), T about the sensor origin (N·m)] the tool exerts on the sensor, sensor frame.

    ``center_of_mass_m`` and ``inertia_kg_m2`` (about the centre of mass) are in the sensor frame;
    ``flange_p_sensor_m`` is the sensor origin in the flange frame; ``gravity_base_m_s2`` the gravity vector (m/s²).
    """
    return ToolOnSensor.of(sensor_R_flange, flange_p_sensor_m, mass_kg, center_of_mass_m, inertia_kg_m2).wrench(
        motion, gravity_base_m_s2)
