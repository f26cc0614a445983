"""The robot contracts, whatever the arm: :class:`Robot` (what the calibration procedure moves) and
:class:`RobotStateSource` (what the live monitor reads).

All angles in radians, lengths in metres, poses in the robot base frame as ``[x, y, z, rx, ry, rz]``
(rotation vector of ``base_R_flange``). Implemented by :class:`drivers.ur.URRobot` over ur-rtde.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class MotionLimits:
    """Upper bounds every motion command must respect (commands above them are refused, not clamped).

    Attributes:
        joint_speed_rad_s: max joint speed for moveJ, rad/s.
        joint_acceleration_rad_s2: max joint acceleration for moveJ, rad/s².
        tool_speed_m_s: max tool speed for moveL, m/s.
        tool_acceleration_m_s2: max tool acceleration for moveL, m/s².
    """

    joint_speed_rad_s: float = 1.0
    joint_acceleration_rad_s2: float = 1.4
    tool_speed_m_s: float = 0.25
    tool_acceleration_m_s2: float = 1.2


@dataclass(frozen=True)
class RobotStatus:
    """A snapshot of the controller's state.

    Attributes:
        robot_mode: RTDE robot_mode (7 = RUNNING). safety_mode: RTDE safety_mode (1 = NORMAL, 3 = PROTECTIVE_STOP).
        protective_stop, emergency_stop: from safety_status_bits. program_running: control script running.
        connected: the data stream is alive. steady: the arm is still.
    """

    robot_mode: int
    safety_mode: int
    protective_stop: bool
    emergency_stop: bool
    program_running: bool
    connected: bool
    steady: bool


@runtime_checkable
class Robot(Protocol):
    """What the procedure needs from an arm."""

    def joint_positions(self) -> np.ndarray:
        """Return the 6 actual joint angles, rad."""

    def flange_pose(self) -> np.ndarray:
        """Return the actual flange pose in the base frame, [x, y, z (m), rx, ry, rz (rad)], TCP offset excluded."""

    def move_joints(self, joint_target_rad: np.ndarray, speed_rad_s: float, acceleration_rad_s2: float,
                    timeout_s: float = 60.0) -> None:
        """Move to a joint target with moveJ and wait until it is reached. Raises RobotError subclasses,
        MotionLimitError above the limits, DeviceTimeoutError after ``timeout_s`` seconds."""

    def stop(self) -> None:
        """Decelerate to a stop now (safe to call at any time, also after a fault)."""

    def is_steady(self) -> bool:
        """Return True when the arm is still."""

    def status(self) -> RobotStatus:
        """Return the controller's state."""

    def close(self) -> None:
        """Disconnect. Safe to call twice."""


class RobotStateSource(Protocol):
    """The robot's latest state, read without blocking (implemented by :class:`drivers.ur.URStateReader`, whose
    ``joints_and_flange_pose()``, both of one state, the monitor prefers when a source has it)."""

    def joint_positions(self) -> np.ndarray:
        """Return the 6 latest joint angles, rad."""

    def flange_pose(self) -> np.ndarray:
        """Return the latest flange pose [x, y, z (m), rx, ry, rz (rad)] in the base frame."""
