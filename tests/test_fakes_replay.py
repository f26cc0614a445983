"""The simulated devices' fast paths change nothing on the wire: a scripted run (tests/fakes/replay.py: a moveJ
stopped midway with its ring-down, a moveL with a TCP offset, a moveJ at half speed) gives the same RTDE data packages
and RDT datagrams, byte for byte, as the same run through the straightforward implementations kept here: the
rigid-body wrench in the base frame, the joint state stepped through every phase for every time, the controller's
time law on arrays, each pose from its own forward kinematics and the tool's motion from its own call, new rest
arrays every tick, and the box's records assembled field by field."""

from __future__ import annotations

import math

import numpy as np
import pytest

import tests.fakes.ur_simulator as ur_simulator
import tests.fakes.world as world
from ftacq.kinematics import URModel, dh_transforms_batch, forward_kinematics, pose_of_transform
from ftacq.kinematics.trapezoid import Trapezoid as TimeLaw
from ftacq.so3 import rotation_from_rotvec
from tests.fakes.netft_box import NetFTBox
from tests.fakes.netft_protocol import INT32_MAX, INT32_MIN, RECORD_DTYPE, UINT32_MASK
from tests.fakes.replay import SCRIPT, replay
from tests.fakes.rigid_body import FlangeMotion
from tests.fakes.ur_motion import Trapezoid
from tests.fakes.ur_simulator import URSimulator, mount_gravity_m_s2
from tests.fakes.world import MAX_EXTRAPOLATION_S, JointState

TICKS = 1300
"""Through the stopped moveJ, its ring-down, the moveL and the start of the half-speed moveJ (2.6 simulated s)."""


def _cross(a, b):
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def flange_motion(model: URModel, q_rad, qd_rad_s, qdd_rad_s2) -> FlangeMotion:
    """The recursion of tests/fakes/rigid_body.py on the frames of :func:`dh_transforms_batch` (the controller's:
    :func:`forward_kinematics`'s)."""
    q = np.asarray(q_rad, dtype=float).reshape(-1, 6)
    qd = np.broadcast_to(np.asarray(qd_rad_s, dtype=float).reshape(-1, 6), q.shape)[..., None]
    qdd = np.broadcast_to(np.asarray(qdd_rad_s2, dtype=float).reshape(-1, 6), q.shape)[..., None]
    frames = dh_transforms_batch(model, q)
    if len(q) <= 2:  # the controller's: the frames of its reported poses
        assert all(np.array_equal(frames[k, 5], forward_kinematics(model, q[k])) for k in range(len(q)))
    axes = np.concatenate([np.broadcast_to([0.0, 0.0, 1.0], (len(q), 1, 3)), frames[:, :5, :3, 2]], axis=1)
    origins = np.concatenate([np.zeros((len(q), 1, 3)), frames[:, :, :3, 3]], axis=1)
    joint_rates = axes * qd
    w = np.cumsum(joint_rates, axis=1)
    dw = np.cumsum(axes * qdd + _cross(w - joint_rates, joint_rates), axis=1)
    r = origins[:, 1:] - origins[:, :-1]
    v = _cross(w, r).sum(axis=1)
    a = (_cross(dw, r) + _cross(w, _cross(w, r))).sum(axis=1)
    return FlangeMotion(frames[:, 5, :3, :3], origins[:, 6], w[:, 5], dw[:, 5], v, a, frames[:, 5])


def tool_wrench_on_sensor(motion, gravity_base_m_s2, sensor_R_flange, flange_p_sensor_m, mass_kg, center_of_mass_m,
                          inertia_kg_m2):
    """F = m (g − a_c), T = c × F − (I α + ω × I ω), in the base frame, then turned into the sensor's."""
    base_R_sensor = motion.base_R_flange @ np.asarray(sensor_R_flange).T
    sensor_offset = motion.base_R_flange @ np.asarray(flange_p_sensor_m)
    com_offset = base_R_sensor @ np.asarray(center_of_mass_m)
    offset = sensor_offset + com_offset
    w, dw = motion.angular_velocity_rad_s, motion.angular_acceleration_rad_s2
    a_com = motion.acceleration_m_s2 + _cross(dw, offset) + _cross(w, _cross(w, offset))
    force = mass_kg * (np.asarray(gravity_base_m_s2) - a_com)
    inertia_base = base_R_sensor @ np.asarray(inertia_kg_m2) @ np.swapaxes(base_R_sensor, 1, 2)
    spin = np.einsum("sij,sj->si", inertia_base, dw) + _cross(w, np.einsum("sij,sj->si", inertia_base, w))
    torque = _cross(com_offset, force) - spin
    to_sensor = np.swapaxes(base_R_sensor, 1, 2)
    return np.concatenate([np.einsum("sij,sj->si", to_sensor, force), np.einsum("sij,sj->si", to_sensor, torque)],
                          axis=1)


def tool_wrench(self: world.SensorPhysics, q, qd, qdd) -> np.ndarray:
    mass, _gravity_base, com, _tool = self._tool
    return tool_wrench_on_sensor(flange_motion(self.robot, q, qd, qdd), self._gravity_m_s2, self._sensor_rotation,
                                 self._sensor_offset, mass, com, self._inertia)


def joint_state_at(self: JointState, times_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, q̇, q̈) at each time: every phase stepped for every sample."""
    tau = np.clip((np.asarray(times_s, dtype=float) - self.stamp_s) * self.time_scale, -MAX_EXTRAPOLATION_S,
                  MAX_EXTRAPOLATION_S)[:, None]
    behind = np.minimum(tau, 0.0)
    within = np.maximum(behind, -float(self.switched_ago_s))
    q = np.asarray(self.q) + (np.asarray(self.qd) * within + 0.5 * np.asarray(self.qdd) * within ** 2)
    qd = np.asarray(self.qd) + np.asarray(self.qdd) * within
    beyond = behind - within
    q += qd * beyond + 0.5 * np.asarray(self.qdd_before) * beyond ** 2
    qd += np.asarray(self.qdd_before) * beyond
    qdd = np.where(beyond < 0.0, self.qdd_before, self.qdd)
    done = np.zeros_like(tau)
    for boundary, acceleration in zip([*np.ravel(self.switch_in_s).tolist(), math.inf],
                                      [*np.reshape(self.qdd_next, (-1, 6)), None]):
        step = np.maximum(np.minimum(tau, boundary) - done, 0.0)
        q += qd * step + 0.5 * qdd * step ** 2
        qd += qdd * step
        done += step
        if acceleration is None or not math.isfinite(boundary):
            break
        qdd = np.where(tau >= boundary, acceleration, qdd)
    return q, qd, qdd


def poses(self: URSimulator, q=None) -> tuple[np.ndarray, np.ndarray]:
    """(flange pose, TCP pose) of q from its own forward kinematics, cached as the controller caches them."""
    q = self.q if q is None else q
    key = (q.tobytes(), self.tcp_offset.tobytes())
    if key not in self._pose_cache:
        if len(self._pose_cache) >= 4:
            self._pose_cache.clear()
        base_T_flange = forward_kinematics(self.model, q)
        self._pose_cache[key] = (pose_of_transform(base_T_flange), self.tcp_pose_for(q, self.tcp_offset, base_T_flange))
    return self._pose_cache[key]


def tool_motion(self: URSimulator, joints) -> tuple[np.ndarray, np.ndarray]:
    """TCP speed and accelerometer of the arm at ``joints``, each from its own kinematics call."""
    gravity = np.array(mount_gravity_m_s2(self.mount))
    q, qd, qdd = joints
    if not (np.any(qd) or np.any(qdd)):
        return np.zeros(6), rotation_from_rotvec(poses(self, q)[0][3:6]).T @ -gravity
    motion = flange_motion(self.model, q, qd, qdd)
    base_R_flange, w = motion.base_R_flange[0], motion.angular_velocity_rad_s[0]
    tcp_linear = motion.velocity_m_s[0] + np.cross(w, base_R_flange @ self.tcp_offset[:3])
    return np.concatenate([tcp_linear, w]), base_R_flange.T @ (motion.acceleration_m_s2[0] - gravity)


def tick_kinematics(self: URSimulator, joints):
    """The tick's poses (target's, arm's) and tool motion, each computed on its own."""
    target_tcp = poses(self)[1] if joints[0] is not self.q else None
    flange, tcp = poses(self, joints[0])
    self.tcp_speed, accelerometer = tool_motion(self, joints) if self.tool_motion_outputs else (np.zeros(6), np.zeros(3))
    return flange, tcp, tcp if target_tcp is None else target_tcp, accelerometer


def at_rest(self: URSimulator) -> None:
    """Zero q̇ and q̈ every tick at rest (new arrays), noting when q̈ changed to zero."""
    if np.any(self.qdd):
        self.qdd_switched_at_s, self.qdd_before = self._last_step_s, self.qdd
    self.qd, self.qdd, self.qdd_next, self.qdd_switch_in_s = np.zeros(6), np.zeros(6), np.zeros((3, 6)), np.full(3, np.inf)


def within_joint_limits(model: URModel, q) -> bool:
    return bool((q >= np.array(model.joint_min_rad) - 1e-12).all() and (q <= np.array(model.joint_max_rad) + 1e-12).all())


def produce(self: NetFTBox, n: int) -> np.ndarray:
    """The box's records, field by field."""
    records = np.zeros(n, dtype=RECORD_DTYPE)
    index = self._stream_k0 + (self._stream_done + np.arange(n, dtype=np.int64)) * self._ft_step
    if self._restart_requested:
        self._restart_requested = False
        self._rdt_sequence, self._ft_sequence = 0, 0
        self._last_index = int(index[0]) - self._ft_step
    rdt = (self._rdt_sequence + 1 + np.arange(n, dtype=np.int64)) & UINT32_MASK
    steps = np.full(n, self._ft_step, dtype=np.int64)
    steps[0] = index[0] - self._last_index
    self._last_index = int(index[-1])
    ft = (self._ft_sequence + np.cumsum(steps)) & UINT32_MASK
    self._rdt_sequence, self._ft_sequence = int(rdt[-1]), int(ft[-1])
    due_s = self._due_s(self._stream_done) if self._target is not None else None
    counts = self._raw_counts(self._draw(n, due_s)) - self._bias_counts
    self._last_counts = counts[-1] + self._bias_counts
    records["rdt_sequence"], records["ft_sequence"], records["status"] = rdt, ft, self._status_now()
    records["counts"] = np.minimum(np.maximum(counts, INT32_MIN), INT32_MAX)
    self.records_produced += n
    return records


@pytest.fixture(scope="module")
def fast():
    return replay(ticks=TICKS, script=SCRIPT)


def test_the_script_moves_stops_and_rings(fast):
    """The run covers what the fast paths shortcut: moving ticks behind a servo lag, a stop and its ring-down, a
    moveL, a 7 kHz stream in bursts."""
    assert fast.ticks["moving"] > 1000 and fast.sim.servo_lag_s > 0.0
    assert [command["kind"] for command in fast.sim.commands] == ["movej", "movel", "movej"]
    assert fast.physics._stop is not None  # the stop at tick 520 rang
    assert len(fast.datagrams) > 0.99 * 7000 * (TICKS - 1) * 0.002


def test_fast_paths_put_the_same_bytes_on_the_wire(fast, monkeypatch):
    monkeypatch.setattr(URSimulator, "_tick_kinematics", tick_kinematics)
    monkeypatch.setattr(URSimulator, "_at_rest", at_rest)
    monkeypatch.setattr(URSimulator, "_resting", lambda self: False)
    monkeypatch.setattr(ur_simulator, "within_joint_limits", within_joint_limits)
    monkeypatch.setattr(world.SensorPhysics, "tool_wrench", tool_wrench)
    monkeypatch.setattr(JointState, "at", joint_state_at)
    monkeypatch.setattr(JointState, "at_time", lambda self, t: tuple(v[0] for v in joint_state_at(self, np.array([t]))))
    for name in ("position", "speed_at", "acceleration_at"):
        monkeypatch.setattr(Trapezoid, name, getattr(TimeLaw, name))
    monkeypatch.setattr(NetFTBox, "_produce", produce)
    reference = replay(ticks=TICKS, script=SCRIPT)
    assert len(fast.packages) == len(reference.packages) == TICKS
    assert fast.packages == reference.packages
    assert len(fast.datagrams) == len(reference.datagrams)
    assert fast.datagrams == reference.datagrams
