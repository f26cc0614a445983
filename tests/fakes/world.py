"""The simulated cell's physics: a known ground truth from which every simulated device reads.

One :class:`CellTruth` (sensor rotation and offset, biases, the tool as a rigid body, base tilt) and a
:class:`PoseSource` (where the flange is now) define what a simulated sensor measures. At rest:

    F = sensor_R_flange @ flange_R_base @ gravity_base + force_bias + drift(t) + contact_force + noise
    T = center_of_mass × (sensor_R_flange @ flange_R_base @ gravity_base) + torque_bias + drift(t)
        + contact_torque + noise

with drift(t) linear plus a thermal-like exponential step (:meth:`SensorPhysics.bias_at`); the tool can be swapped
behind the software's back (:meth:`SensorPhysics.set_tool`).

While the arm moves, and when the pose source also gives the joint state (q, q̇, q̈: :class:`SharedPose`) and the
physics knows the arm's model, the gravity wrench is replaced by the full wrench of the rigid tool
(:mod:`tests.fakes.rigid_body`: F = m (g − a_c), T = c × F − (I_c α + ω × I_c ω)), which is the same at rest.

The simulated UR controller runs in its own process (ur-rtde's constructors hold the GIL), so the state it
reports is published through :class:`SharedPose` (a seqlock over ``multiprocessing.shared_memory``); a
simulated sensor in another process (the CAN board on python-can's in-process virtual bus) reads it there.
Both processes stamp with ``time.monotonic()`` (one clock per machine), so the sensor evaluates the motion at
each of its own sample times: the controller publishes, each 2 ms tick, q, q̇, q̈ of its (piecewise constant
acceleration) motion profile and when q̈ changes next; the sensor extrapolates exactly within that.
With a time scale s ≠ 1 the simulated cell is a time-lapse of a real-time cell: motion time runs s times as fast
as the clocks, and the physics (and the controller's reported q̇, q̈) are those of the real-time motion.

Over 500 lines because the truth, the published joint state and the sensor's physics are read together per sample
chunk; the rigid-body maths is apart (rigid_body.py). :meth:`JointState.at` and :meth:`JointState.at_time` (per
chunk, per tick) are written for speed; tests/test_fakes_replay.py checks them against the plain stepping.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field, replace
from multiprocessing import shared_memory
from typing import Protocol

import numpy as np

from ftacq import STANDARD_GRAVITY_M_S2
from ftacq.calibration import Calibration
from ftacq.kinematics import URModel
from ftacq.so3 import rotation_from_rotvec, rotation_zyx_deg
from tests.fakes.rigid_body import ToolOnSensor, flange_motion

TIMELINE_SLACK_S, TIMELINE_GAP_S = 0.01, 1.0
"""A stream's next chunk continues the sample timeline when drawn at most this early or this late (s)."""
MAX_EXTRAPOLATION_S = 2.0
"""The sensor follows the controller's last published move at most this far (motion time, s): through a stall of
the controller process (a loaded machine) the arm goes on along its profile, as a real one would."""
BAD_SENSOR_GAIN_ERROR = ((-0.015, 0.0, 0.0, 0.0, 0.0, 0.0), (0.02, 0.0, 0.0, 0.0, 0.0, 0.0),
                         (0.0, 0.0, 0.04, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.02, 0.0, 0.0),
                         (0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
"""``CellTruth.sensor_gain_error`` of ``--sim-bad-sensor``: Fz reads 4 % high, Fx 1.5 % low, 2 % of Fx appears on
Fy, Tx reads 2 % high: a sensor out of its certificate (1.25 %), as after an overload."""


def gravity_base_from_tilt(mass_kg: float, alpha_deg: float, beta_deg: float) -> np.ndarray:
    """Return gravity_base = −m g [cos α sin β, −sin α, cos α cos β] in N (paper eq. 47)."""
    a, b = np.radians(alpha_deg), np.radians(beta_deg)
    return -mass_kg * STANDARD_GRAVITY_M_S2 * np.array([np.cos(a) * np.sin(b), -np.sin(a), np.cos(a) * np.cos(b)])


@dataclass(frozen=True)
class CellTruth:
    """Ground truth of a simulated cell (SI units; sensor frame unless stated).

    Attributes:
        sensor_rotation_zyx_deg: sensor_R_flange as Z-Y-X Euler angles (deg), as in the paper's Table I.
        force_bias_n, torque_bias_nm: sensor biases.
        mass_kg: tool mass. center_of_mass_m: tool centre of mass in the sensor frame.
        inertia_kg_m2: the tool's inertia about its centre of mass, sensor frame (3×3, row by row).
        sensor_offset_m: the sensor origin in the flange frame (the adapter plate's thickness along z, mostly).
        base_tilt_deg: (α, β) of the robot base against gravity (0, 0 = level floor; see gravity_base_from_tilt).
        force_noise_n, torque_noise_nm: per-channel 1σ white noise of one sample.
        drift_n_per_s, drift_nm_per_s: slow linear bias drift per channel (thermal).
        thermal_step_n, thermal_step_nm: a thermal-like exponential step of the biases, per channel: the bias moves
            by step × (1 − exp(−(t − thermal_step_at_s) / thermal_time_constant_s)) after thermal_step_at_s.
        motion_noise_gain: extra noise factor per rad/s of joint speed while the arm moves.
        sensor_gain_error: the sensor's own calibration off by E (6×6, rows and columns Fx Fy Fz Tx Ty Tz): it
            reports (I + E) @ the applied wrench, plus the biases (E[2, 2] = 0.01: Fz reads 1 % high; E[1, 0] =
            0.007: 0.7 % of Fx appears on Fy). None: a perfect sensor.
        ringdown_force_n, ringdown_torque_nm: amplitude of the tool's ring-down after every stop of the arm (the
            tool on its compliant mount oscillating after the deceleration), along the stop's inertial wrench:
            A exp(−u/τ) sin(2π f u), u the time since the stop (:func:`ringdown`); 0 turns it off.
        ringdown_time_constant_s, ringdown_frequency_hz: its τ and f.
    """

    sensor_rotation_zyx_deg: tuple[float, float, float] = (30.0, -20.0, 75.0)
    force_bias_n: tuple[float, float, float] = (3.2, -1.5, 7.8)
    torque_bias_nm: tuple[float, float, float] = (0.12, -0.31, 0.05)
    mass_kg: float = 1.35
    center_of_mass_m: tuple[float, float, float] = (0.004, -0.012, 0.065)
    inertia_kg_m2: tuple[tuple[float, float, float], ...] = ((0.0042, 0.0001, -0.0002),
                                                            (0.0001, 0.0038, 0.00015),
                                                            (-0.0002, 0.00015, 0.0019))
    sensor_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.035)
    base_tilt_deg: tuple[float, float] = (0.0, 0.0)
    force_noise_n: tuple[float, float, float] = (0.05, 0.05, 0.08)
    torque_noise_nm: tuple[float, float, float] = (0.002, 0.002, 0.0015)
    drift_n_per_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    drift_nm_per_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    thermal_step_n: tuple[float, float, float] = (0.0, 0.0, 0.0)
    thermal_step_nm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    thermal_step_at_s: float = 0.0
    thermal_time_constant_s: float = 600.0
    motion_noise_gain: float = 2.0
    sensor_gain_error: tuple[tuple[float, ...], ...] | None = None

    @property
    def sensor_gain(self) -> np.ndarray:
        """The sensor's gain matrix K = I + sensor_gain_error (6, 6): it reports K @ the applied wrench."""
        if self.sensor_gain_error is None:
            return np.eye(6)
        return np.eye(6) + np.asarray(self.sensor_gain_error, dtype=float).reshape(6, 6)

    def measured(self, wrench: np.ndarray, bias: np.ndarray | None = None) -> np.ndarray:
        """Return what the sensor reports (…, 6) for an applied ``wrench`` (…, 6) whose last axis already holds the
        ``bias`` (6,) (default the truth's): the bias stays, the load goes through :attr:`sensor_gain`."""
        if self.sensor_gain_error is None:
            return wrench
        bias = np.array(self.force_bias_n + self.torque_bias_nm) if bias is None else bias
        return (np.asarray(wrench, dtype=float) - bias) @ self.sensor_gain.T + bias
    ringdown_force_n: float = 0.5
    ringdown_torque_nm: float = 0.03
    ringdown_time_constant_s: float = 0.1
    ringdown_frequency_hz: float = 9.0

    @property
    def sensor_rotation(self) -> np.ndarray:
        """sensor_R_flange (3×3)."""
        return rotation_zyx_deg(*self.sensor_rotation_zyx_deg)

    @property
    def gravity_base(self) -> np.ndarray:
        """The tool's weight in the base frame, N."""
        return gravity_base_from_tilt(self.mass_kg, *self.base_tilt_deg)

    @property
    def gravity_base_m_s2(self) -> np.ndarray:
        """The gravity vector in the base frame, m/s² (gravity_base / mass)."""
        return gravity_base_from_tilt(1.0, *self.base_tilt_deg)

    @property
    def inertia(self) -> np.ndarray:
        """The tool's inertia about its centre of mass, sensor frame (3, 3), kg·m²."""
        return np.array(self.inertia_kg_m2, dtype=float)

    def calibration(self) -> Calibration:
        """Return the true calibration (at time zero, before any drift)."""
        return Calibration(
            sensor_rotation=self.sensor_rotation,
            force_bias=self.force_bias_n,
            torque_bias=self.torque_bias_nm,
            gravity_base=self.gravity_base,
            center_of_mass=self.center_of_mass_m,
            metadata={"source": "simulated cell ground truth"},
        )

    def with_mount(self, mount: str) -> "CellTruth":
        """Return this truth with the base tilt of a mount: floor (0, 0), wall (0, 90), ceiling (0, 180), or a spec
        of ftacq.mounts (``tilted:ALPHA,BETA``, ``gravity:X,Y,Z``)."""
        from ftacq.mounts import mount_of

        return replace(self, base_tilt_deg=tuple(mount_of(mount).tilt_deg))


RINGDOWN_SPAN = 10.0
"""A ring-down is followed for this many time constants after its stop (then below 5e-5 of its amplitude)."""


def ringdown(truth: CellTruth, since_stop_s: np.ndarray, force_direction: np.ndarray,
             torque_direction: np.ndarray) -> np.ndarray:
    """The tool's ring-down (S, 6) [N, N·m] at ``since_stop_s`` (S,) after a stop (0 before it): the amplitudes of
    the truth along the unit directions (3,) each, times exp(−u/τ) sin(2π f u)."""
    u = np.asarray(since_stop_s, dtype=float)
    tau = max(float(truth.ringdown_time_constant_s), 1e-9)
    shape = np.where((u >= 0.0) & (u < RINGDOWN_SPAN * tau),
                     np.exp(-np.clip(u, 0.0, None) / tau) * np.sin(2 * np.pi * truth.ringdown_frequency_hz * u), 0.0)
    amplitude = np.concatenate([truth.ringdown_force_n * np.asarray(force_direction, dtype=float),
                                truth.ringdown_torque_nm * np.asarray(torque_direction, dtype=float)])
    return shape[:, None] * amplitude


def _unit(v: np.ndarray) -> np.ndarray:
    norm = float(np.linalg.norm(v))
    return v / norm if norm > 0 else np.zeros_like(v)


class PoseSource(Protocol):
    """Where the flange is: ``read()`` returns (pose [x,y,z,rx,ry,rz], joint speed norm rad/s)."""

    def read(self) -> tuple[np.ndarray, float]: ...


class SettablePose:
    """A pose set by the test (thread-safe); the default is tool-down at the origin."""

    def __init__(self, pose: np.ndarray | None = None) -> None:
        self._lock = threading.Lock()
        self._pose = np.array(pose if pose is not None else [0.4, 0.0, 0.4, np.pi, 0.0, 0.0], dtype=float)
        self._speed = 0.0

    def set(self, pose: np.ndarray, joint_speed_rad_s: float = 0.0) -> None:
        """Set the flange pose [x, y, z (m), rx, ry, rz (rad)] and the current joint speed norm (rad/s)."""
        with self._lock:
            self._pose = np.array(pose, dtype=float)
            self._speed = float(joint_speed_rad_s)

    def read(self) -> tuple[np.ndarray, float]:
        with self._lock:
            return self._pose.copy(), self._speed


def any_nonzero(values) -> bool:
    """Whether any value is non-zero, as ``np.any`` (``np.count_nonzero`` costs a tenth of it: this runs per tick)."""
    return np.count_nonzero(values) > 0


@dataclass(frozen=True)
class JointState:
    """The controller's joint state at one tick, as published for the sensor (SI units).

    Attributes:
        stamp_s: ``time.monotonic()`` of the tick. time_scale: motion seconds per clock second (0 = instant moves).
        q, qd, qdd: joint positions (rad), speeds (rad/s), accelerations (rad/s²) of the motion profile.
        switch_in_s (3,): motion time from the tick to each later change of q̈ (inf when none); qdd_next (3, 6):
            q̈ after each. A trapezoidal move has at most three, so the sensor follows the move exactly even while
            the controller process is descheduled.
        switched_ago_s: motion time from the last change of q̈ to the tick (inf: none known); qdd_before (6,): q̈
            before it. A sensor that generates its samples late (its process was descheduled) gets the samples
            from before that change right too.
    """

    stamp_s: float
    time_scale: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    switch_in_s: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))
    qdd_next: np.ndarray = field(default_factory=lambda: np.zeros((3, 6)))
    switched_ago_s: float = np.inf
    qdd_before: np.ndarray = field(default_factory=lambda: np.zeros(6))

    @property
    def at_rest(self) -> bool:
        recently_moving = self.switched_ago_s < MAX_EXTRAPOLATION_S and any_nonzero(self.qdd_before)
        return not (any_nonzero(self.qd) or any_nonzero(self.qdd) or any_nonzero(self.qdd_next) or recently_moving)

    def at(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return (q, q̇, q̈), each (S, 6), at clock times ``times_s`` (S,): exact for the piecewise constant q̈
        of the controller's profiles (ahead of the stamp through every change of q̈; behind it through the current
        phase and the one before; at most :data:`MAX_EXTRAPOLATION_S` either way)."""
        # few numpy calls (this runs per sample chunk of the sensor); the same arithmetic, operation for operation,
        # as stepping (S, 6) copies of q, q̇, q̈ in place, less the steps that are zero for every sample (they add
        # nothing but the sign of a zero)
        tau = np.maximum((np.asarray(times_s, dtype=float) - self.stamp_s) * self.time_scale, -MAX_EXTRAPOLATION_S)
        tau = np.minimum(tau, MAX_EXTRAPOLATION_S)[:, None]
        qd0, qdd0 = np.asarray(self.qd, dtype=float), np.asarray(self.qdd, dtype=float)
        behind = np.minimum(tau, 0.0)  # before the stamp: the current phase backwards, then the one before
        within = np.maximum(behind, -float(self.switched_ago_s))
        q = np.asarray(self.q, dtype=float) + (qd0 * within + 0.5 * qdd0 * within ** 2)
        qd = qd0 + qdd0 * within
        beyond = behind - within
        if beyond.min() < 0.0:  # samples before the last change of q̈
            qdd_before = np.asarray(self.qdd_before, dtype=float)
            q += qd * beyond + 0.5 * qdd_before * beyond ** 2
            qd += qdd_before * beyond
            qdd = np.where(beyond < 0.0, qdd_before, qdd0)
        else:
            qdd = np.repeat(qdd0[None], len(q), axis=0)
        latest = float(tau.max())
        if latest <= 0.0:  # no sample after the stamp
            return q, qd, qdd
        done = np.zeros_like(tau)
        after = np.asarray(self.qdd_next, dtype=float).reshape(-1, 6)
        for boundary, acceleration in zip([*np.asarray(self.switch_in_s, dtype=float).reshape(-1).tolist(), math.inf],
                                          [*after, None]):
            step = np.maximum(np.minimum(tau, boundary) - done, 0.0)
            q += qd * step + 0.5 * qdd * step ** 2
            qd += qdd * step
            done += step
            if acceleration is None or not math.isfinite(boundary) or boundary > latest:
                break
            qdd = np.where(tau >= boundary, acceleration, qdd)
        return q, qd, qdd

    def at_time(self, time_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`at` of one clock time ``time_s``: (q, q̇, q̈), each (6,), by the same arithmetic operation for
        operation, on floats (the controller asks for one time per 2 ms tick: numpy's calls cost more there)."""
        tau = min(max((time_s - self.stamp_s) * self.time_scale, -MAX_EXTRAPOLATION_S), MAX_EXTRAPOLATION_S)
        qd0, qdd0 = np.asarray(self.qd, dtype=float).tolist(), np.asarray(self.qdd, dtype=float).tolist()
        behind = min(tau, 0.0)
        within = max(behind, -float(self.switched_ago_s))
        square = within * within
        q = [p + (v * within + 0.5 * a * square) for p, v, a in zip(np.asarray(self.q, dtype=float).tolist(), qd0, qdd0)]
        qd = [v + a * within for v, a in zip(qd0, qdd0)]
        beyond = behind - within
        qdd_before = np.asarray(self.qdd_before, dtype=float).tolist()
        square = beyond * beyond
        q = [p + (v * beyond + 0.5 * a * square) for p, v, a in zip(q, qd, qdd_before)]
        qd = [v + a * beyond for v, a in zip(qd, qdd_before)]
        qdd = qdd_before if beyond < 0.0 else qdd0
        done = 0.0
        after = np.asarray(self.qdd_next, dtype=float).reshape(-1, 6).tolist()
        for boundary, acceleration in zip([*np.asarray(self.switch_in_s, dtype=float).reshape(-1).tolist(), math.inf],
                                          [*after, None]):
            step = max(min(tau, boundary) - done, 0.0)
            square = step * step
            q = [p + (v * step + 0.5 * a * square) for p, v, a in zip(q, qd, qdd)]
            qd = [v + a * step for v, a in zip(qd, qdd)]
            done += step
            if acceleration is None or not math.isfinite(boundary):
                break
            if tau >= boundary:
                qdd = acceleration
        return np.array(q), np.array(qd), np.array(qdd)


class SharedPose:
    """A flange pose and the joint state shared between processes through shared memory, guarded by a seqlock.

    Layout (float64): [sequence, x, y, z, rx, ry, rz, joint_speed_rad_s, stamp_s, time_scale, q (6), q̇ (6),
    q̈ (6), switch_in_s (3), q̈ after each switch (3 × 6), switched_ago_s, q̈ before it (6)]. The writer makes the sequence odd while writing; readers retry
    until they see the same even sequence before and after copying.
    """

    _SLOTS = 56

    def __init__(self, name: str | None = None, create: bool = False) -> None:
        if create:
            self._shm = shared_memory.SharedMemory(name=name, create=True, size=8 * self._SLOTS)
        else:
            self._shm = shared_memory.SharedMemory(name=name)
        self._owner = create
        self._array = np.ndarray((self._SLOTS,), dtype=np.float64, buffer=self._shm.buf)
        if create:
            self._array[:] = 0.0
            self._array[1:7] = [0.4, 0.0, 0.4, np.pi, 0.0, 0.0]
            self._array[28:31] = np.inf
            self._array[49] = np.inf

    @property
    def name(self) -> str:
        """The shared-memory block's name, to hand to another process."""
        return self._shm.name

    def set(self, pose: np.ndarray, joint_speed_rad_s: float = 0.0, state: JointState | None = None) -> None:
        """Publish a pose and optionally the joint state (writer side; one writer only)."""
        seq = self._array[0]
        self._array[0] = seq + 1.0
        self._array[1:7] = pose
        self._array[7] = joint_speed_rad_s
        if state is None:
            self._array[8:56] = 0.0
            self._array[28:31] = np.inf
            self._array[49] = np.inf
        else:
            self._array[8], self._array[9] = state.stamp_s, state.time_scale
            self._array[10:16], self._array[16:22], self._array[22:28] = state.q, state.qd, state.qdd
            self._array[28:31], self._array[31:49] = state.switch_in_s, np.ravel(state.qdd_next)
            self._array[49], self._array[50:56] = state.switched_ago_s, state.qdd_before
        self._array[0] = seq + 2.0

    def _copy(self) -> np.ndarray:
        while True:
            before = self._array[0]
            values = self._array.copy()
            if before == self._array[0] and int(before) % 2 == 0:
                return values

    def read(self) -> tuple[np.ndarray, float]:
        values = self._copy()
        return values[1:7], float(values[7])

    def read_state(self) -> tuple[np.ndarray, float, JointState | None]:
        """Return (pose, joint speed norm, joint state or None when the writer published none)."""
        v = self._copy()
        state = None
        if v[8] > 0.0:
            state = JointState(float(v[8]), float(v[9]), v[10:16], v[16:22], v[22:28], v[28:31], v[31:49].reshape(3, 6),
                               float(v[49]), v[50:56])
        return v[1:7], float(v[7]), state

    def close(self) -> None:
        """Detach (and unlink, if this instance created the block). Safe to call twice."""
        if self._shm is None:
            return
        del self._array
        self._shm.close()
        if self._owner:
            self._shm.unlink()
        self._shm = None


@dataclass
class SensorPhysics:
    """Computes the simulated sensor's true wrench from the pose source (thread-safe, seeded).

    ``contact_wrench`` (sensor frame, N and N·m) is added while set: tests use it to disturb a pose.
    ``robot`` (the arm's model) and a pose source with ``read_state`` (:class:`SharedPose`) turn on the tool's
    inertial wrench while the arm moves; ``rate_hz`` spaces the samples of one ``sample(n)`` call in time.
    """

    truth: CellTruth
    pose_source: PoseSource
    seed: int = 0
    contact_wrench: np.ndarray = field(default_factory=lambda: np.zeros(6))
    start_time_s: float = field(default_factory=time.monotonic)
    robot: URModel | None = None
    rate_hz: float = 1000.0

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._lock = threading.Lock()
        self._noise_sigma = np.array(self.truth.force_noise_n + self.truth.torque_noise_nm)
        self._drift = np.array(self.truth.drift_n_per_s + self.truth.drift_nm_per_s)
        self._bias = np.array(self.truth.force_bias_n + self.truth.torque_bias_nm)
        self._sensor_rotation = self.truth.sensor_rotation
        # the truth is frozen: its derived arrays once, not per sample chunk
        self._gain_t = self.truth.sensor_gain.T
        self._thermal_step = np.array(self.truth.thermal_step_n + self.truth.thermal_step_nm)
        self._gravity_m_s2 = self.truth.gravity_base_m_s2
        self._sensor_offset = np.array(self.truth.sensor_offset_m)
        self._inertia = self.truth.inertia
        self._ringdown_tau_s = max(float(self.truth.ringdown_time_constant_s), 1e-9)  # as ringdown() takes it
        self._constant_bias = not (any_nonzero(self._drift) or any_nonzero(self._thermal_step))
        """No drift and no thermal step: :meth:`bias_at` is the bias at every time (skipped per chunk)."""
        self._rest_load: tuple | None = None  # ((pose, contact) bytes, tool, the load through the gain) at rest
        self.set_tool(self.truth.mass_kg, self.truth.center_of_mass_m)
        self._next_sample_s: float | None = None
        self.timeline_restarts = 0
        self._last_moving: tuple[float, np.ndarray, np.ndarray] | None = None  # (time, q, q̈) of the last moving sample
        self._stop: tuple[float, np.ndarray, np.ndarray] | None = None  # (time, force, torque direction) of the last stop

    def _sample_times(self, n: int, now: float) -> np.ndarray:
        """Times of the ``n`` samples of one call: a stream's chunks (n > 1) continue one regular timeline at
        ``rate_hz`` (a real sensor samples on its own clock, however late the fake gets to drawing them); a
        single sample (a poll) or a gap re-anchors the timeline at ``now``."""
        start = now
        if n > 1 and self._next_sample_s is not None and -TIMELINE_SLACK_S <= now - self._next_sample_s <= TIMELINE_GAP_S:
            start = self._next_sample_s
        elif n > 1:
            self.timeline_restarts += 1
        self._next_sample_s = start + n / self.rate_hz
        return start + np.arange(n) / self.rate_hz

    def set_tool(self, mass_kg: float, center_of_mass_m) -> None:
        """Put another tool on the sensor (mass kg, centre of mass m in the sensor frame) without telling anyone:
        every later sample follows it. ``set_tool(truth.mass_kg, truth.center_of_mass_m)`` puts the true one back."""
        gravity_base = gravity_base_from_tilt(float(mass_kg), *self.truth.base_tilt_deg)
        com = np.array(center_of_mass_m, dtype=float).reshape(3)
        self._tool = (float(mass_kg), gravity_base, com,  # atomic
                      ToolOnSensor.of(self._sensor_rotation, self._sensor_offset, float(mass_kg), com, self._inertia))

    def bias_at(self, elapsed_s):
        """Return the true biases [N, N·m] ``elapsed_s`` seconds after start (a float: (6,); an (S, 1) array:
        (S, 6)): linear drift plus the thermal step."""
        t = self.truth
        since = np.maximum(np.asarray(elapsed_s, dtype=float) - t.thermal_step_at_s, 0.0)
        return self._bias + self._drift * elapsed_s + self._thermal_step * -np.expm1(-since / t.thermal_time_constant_s)

    def noiseless_wrench(self, pose: np.ndarray, elapsed_s: float = 0.0) -> np.ndarray:
        """Return the wrench (6,) without noise at a flange pose, at rest, ``elapsed_s`` seconds after start (drift)."""
        return self._load_at_rest(pose) + self.bias_at(elapsed_s)

    def _load_at_rest(self, pose: np.ndarray) -> np.ndarray:
        """The tool's weight and the contact at a flange pose, through the sensor's gain (6,): computed once per
        pose, tool and contact (the arm at rest)."""
        tool, pose, contact = self._tool, np.asarray(pose), self.contact_wrench
        cached = self._rest_load
        key = (pose.tobytes(), np.asarray(contact).tobytes())
        if cached is None or cached[0] != key or cached[1] is not tool:
            _mass, gravity_base, com, _wrench = tool
            base_R_flange = rotation_from_rotvec(pose[3:6])
            gravity_sensor = self._sensor_rotation @ (base_R_flange.T @ gravity_base)
            torque = np.cross(com, gravity_sensor)
            load = np.concatenate([gravity_sensor, torque]) + contact
            cached = self._rest_load = (key, tool, load @ self._gain_t)
        return cached[2]

    def tool_wrench(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Return the wrench (S, 6) of the moving tool alone (gravity and inertia; no bias, drift, contact, noise)."""
        if self.robot is None:
            raise ValueError("the tool's inertial wrench needs the robot model (SensorPhysics.robot)")
        tool = self._tool[3]  # the tool on the sensor now (set_tool)
        return tool.wrench(flange_motion(self.robot, q, qd, qdd), self._gravity_m_s2)

    def noiseless_wrench_moving(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                                elapsed_s: np.ndarray | float = 0.0) -> np.ndarray:
        """Return the wrench (S, 6) without noise for joint states (S, 6) at ``elapsed_s`` after start (drift)."""
        load = self.tool_wrench(q, qd, qdd)
        if any_nonzero(self.contact_wrench):  # adding zeros or multiplying by I changes nothing (but a zero's sign)
            load = load + self.contact_wrench
        if self.truth.sensor_gain_error is not None:
            load = load @ self._gain_t
        if self._constant_bias:
            return load + self._bias
        return load + self.bias_at(np.reshape(np.asarray(elapsed_s, dtype=float), (-1, 1)))

    def ringdown_at(self, times_s: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                    time_scale: float = 1.0) -> np.ndarray:
        """The ring-down (S, 6) at the samples of one call (times (S,) in order, joint states (S, 6)): a stop is a
        sample at rest after a moving one (remembered across calls); its directions are those of the tool's
        inertial wrench of the deceleration that ended there (:func:`ringdown`); it rings in motion time (clock
        seconds × ``time_scale``, as the physics of a time-lapse cell)."""
        out = np.zeros((len(times_s), 6))
        if self.truth.ringdown_force_n == 0.0 and self.truth.ringdown_torque_nm == 0.0 or not len(times_s):
            return out
        moving = np.max(np.abs(qd), axis=1) > 1e-9
        previous = np.concatenate([[self._last_moving is not None], moving[:-1]])
        stops = np.flatnonzero(previous & ~moving)
        segments = [0, *stops.tolist(), len(times_s)]
        for begin, end in zip(segments[:-1], segments[1:]):
            if begin in stops:
                if begin > 0:
                    self._last_moving = (float(times_s[begin - 1]), q[begin - 1], qdd[begin - 1])
                if self._last_moving is not None:
                    _t, q_stop, qdd_stop = self._last_moving
                    jolt = self.tool_wrench(q_stop[None], np.zeros((1, 6)), qdd_stop[None])[0] \
                        - self.tool_wrench(q_stop[None], np.zeros((1, 6)), np.zeros((1, 6)))[0]
                    self._stop = (float(times_s[begin]), _unit(jolt[:3]), _unit(jolt[3:]))
                    self._last_moving = None
            if self._stop is not None:
                at, force, torque = self._stop
                if (times_s[begin] - at) * time_scale < RINGDOWN_SPAN * self._ringdown_tau_s:  # else rung out: 0
                    out[begin:end] = ringdown(self.truth, (times_s[begin:end] - at) * time_scale, force, torque)
        if moving.any():
            last = int(np.flatnonzero(moving)[-1])
            if last == len(times_s) - 1:
                self._last_moving = (float(times_s[last]), q[last], qdd[last])
            else:
                self._last_moving = None
        return out

    def sample(self, n: int, start_time_s: float | None = None, period_s: float | None = None) -> np.ndarray:
        """Return ``n`` noisy samples (n, 6) at the current pose and time (the arm's motion followed per sample,
        at ``start_time_s`` + k × ``period_s`` (host seconds; default 1 / rate_hz) when the caller knows when the
        first is due — a sensor on its own clock spaces its samples by its own period —, else on the timeline of
        :meth:`_sample_times`)."""
        reader = getattr(self.pose_source, "read_state", None)
        if reader is not None:
            pose, joint_speed, state = reader()
        else:
            (pose, joint_speed), state = self.pose_source.read(), None
        now = time.monotonic()
        elapsed = now - self.start_time_s
        if start_time_s is None:
            times = self._sample_times(n, now)
        else:
            times = start_time_s + np.arange(n) * (1.0 / self.rate_hz if period_s is None else period_s)
        if state is None or self.robot is None or state.at_rest:
            self._last_moving = None
            bias = self.bias_at(elapsed)
            mean = self._load_at_rest(pose) + bias  # noiseless_wrench(pose, elapsed)
            if start_time_s is not None:  # the drift at each sample's own time (the same for all without drift)
                mean = mean - bias + (bias if self._constant_bias else self.bias_at((times - self.start_time_s)[:, None]))
        else:
            q, qd, qdd = state.at(times)
            mean = self.noiseless_wrench_moving(q, qd, qdd, times - self.start_time_s)
            mean = mean + self.ringdown_at(times, q, qd, qdd, state.time_scale)
        sigma = self._noise_sigma * (1.0 + self.truth.motion_noise_gain * joint_speed)
        with self._lock:
            noise = self._rng.standard_normal((n, 6))
        return mean + noise * sigma
