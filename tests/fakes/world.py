"""The simulated cell's physics: a known ground truth from which every simulated device reads.

One :class:`CellTruth` (sensor rotation, biases, tool mass and centre of mass, base tilt) and a
:class:`PoseSource` (where the flange is now) define what a simulated sensor measures:

    F = sensor_R_flange @ flange_R_base @ gravity_base + force_bias + drift(t) + contact_force + noise
    T = center_of_mass × (sensor_R_flange @ flange_R_base @ gravity_base) + torque_bias + drift(t)
        + contact_torque + noise

with drift(t) linear plus a thermal-like exponential step (:meth:`SensorPhysics.bias_at`); the tool can be swapped
behind the software's back (:meth:`SensorPhysics.swap_tool`).

The simulated UR controller runs in its own process (ur-rtde's constructors hold the GIL), so the pose it
reports is published through :class:`SharedPose` (a seqlock over ``multiprocessing.shared_memory``); a
simulated sensor in another process (the CAN board on python-can's in-process virtual bus) reads it there.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field, replace
from multiprocessing import shared_memory
from typing import Protocol

import numpy as np

from ftacq import STANDARD_GRAVITY_M_S2
from ftacq.calibration import Calibration
from ftacq.so3 import rotation_from_rotvec, rotation_zyx_deg


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
        base_tilt_deg: (α, β) of the robot base against gravity (0, 0 = level floor; see gravity_base_from_tilt).
        force_noise_n, torque_noise_nm: per-channel 1σ white noise of one sample.
        drift_n_per_s, drift_nm_per_s: slow linear bias drift per channel (thermal).
        thermal_step_n, thermal_step_nm: a thermal-like exponential step of the biases, per channel: the bias moves
            by step × (1 − exp(−(t − thermal_step_at_s) / thermal_time_constant_s)) after thermal_step_at_s.
        motion_noise_gain: extra noise factor per rad/s of joint speed while the arm moves.
    """

    sensor_rotation_zyx_deg: tuple[float, float, float] = (30.0, -20.0, 75.0)
    force_bias_n: tuple[float, float, float] = (3.2, -1.5, 7.8)
    torque_bias_nm: tuple[float, float, float] = (0.12, -0.31, 0.05)
    mass_kg: float = 1.35
    center_of_mass_m: tuple[float, float, float] = (0.004, -0.012, 0.065)
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

    @property
    def sensor_rotation(self) -> np.ndarray:
        """sensor_R_flange (3×3)."""
        return rotation_zyx_deg(*self.sensor_rotation_zyx_deg)

    @property
    def gravity_base(self) -> np.ndarray:
        """The tool's weight in the base frame, N."""
        return gravity_base_from_tilt(self.mass_kg, *self.base_tilt_deg)

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
        """Return this truth with the base tilt of a nominal mount: floor (0, 0), wall (0, 90), ceiling (0, 180)."""
        tilt = {"floor": (0.0, 0.0), "wall": (0.0, 90.0), "ceiling": (0.0, 180.0)}[mount]
        return replace(self, base_tilt_deg=tilt)


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


class SharedPose:
    """A flange pose shared between processes through shared memory, guarded by a seqlock.

    Layout (float64): [sequence, x, y, z, rx, ry, rz, joint_speed_rad_s]. The writer makes the sequence odd
    while writing; readers retry until they see the same even sequence before and after copying.
    """

    _SLOTS = 8

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

    @property
    def name(self) -> str:
        """The shared-memory block's name, to hand to another process."""
        return self._shm.name

    def set(self, pose: np.ndarray, joint_speed_rad_s: float = 0.0) -> None:
        """Publish a pose (writer side; one writer only)."""
        seq = self._array[0]
        self._array[0] = seq + 1.0
        self._array[1:7] = pose
        self._array[7] = joint_speed_rad_s
        self._array[0] = seq + 2.0

    def read(self) -> tuple[np.ndarray, float]:
        while True:
            before = self._array[0]
            values = self._array[1:8].copy()
            if before == self._array[0] and int(before) % 2 == 0:
                return values[:6], float(values[6])

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
    """

    truth: CellTruth
    pose_source: PoseSource
    seed: int = 0
    contact_wrench: np.ndarray = field(default_factory=lambda: np.zeros(6))
    start_time_s: float = field(default_factory=time.monotonic)

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._lock = threading.Lock()
        self._noise_sigma = np.array(self.truth.force_noise_n + self.truth.torque_noise_nm)
        self._drift = np.array(self.truth.drift_n_per_s + self.truth.drift_nm_per_s)
        self._bias = np.array(self.truth.force_bias_n + self.truth.torque_bias_nm)
        self._gravity_base = self.truth.gravity_base
        self._sensor_rotation = self.truth.sensor_rotation
        self._com = np.array(self.truth.center_of_mass_m)

    def bias_at(self, elapsed_s: float) -> np.ndarray:
        """Return the true biases (6,) [N, N·m] ``elapsed_s`` seconds after start: linear drift plus thermal step."""
        t = self.truth
        step = np.array(t.thermal_step_n + t.thermal_step_nm)
        since = max(elapsed_s - t.thermal_step_at_s, 0.0)
        return self._bias + self._drift * elapsed_s + step * -np.expm1(-since / t.thermal_time_constant_s)

    def swap_tool(self, mass_kg: float, center_of_mass_m) -> None:
        """Put another tool on the simulated sensor (mass, centre of mass in the sensor frame) without telling
        the software: the knob for "a calibration that no longer fits the tool"."""
        self._gravity_base = gravity_base_from_tilt(mass_kg, *self.truth.base_tilt_deg)
        self._com = np.array(center_of_mass_m, dtype=float)

    def noiseless_wrench(self, pose: np.ndarray, elapsed_s: float = 0.0) -> np.ndarray:
        """Return the wrench (6,) without noise at a flange pose, ``elapsed_s`` seconds after start (drift)."""
        base_R_flange = rotation_from_rotvec(np.asarray(pose)[3:6])
        gravity_sensor = self._sensor_rotation @ (base_R_flange.T @ self._gravity_base)
        torque = np.cross(self._com, gravity_sensor)
        return np.concatenate([gravity_sensor, torque]) + self.bias_at(elapsed_s) + self.contact_wrench

    def sample(self, n: int) -> np.ndarray:
        """Return ``n`` noisy samples (n, 6) at the current pose and time."""
        pose, joint_speed = self.pose_source.read()
        elapsed = time.monotonic() - self.start_time_s
        mean = self.noiseless_wrench(pose, elapsed)
        sigma = self._noise_sigma * (1.0 + self.truth.motion_noise_gain * joint_speed)
        with self._lock:
            noise = self._rng.standard_normal((n, 6))
        return mean + noise * sigma
