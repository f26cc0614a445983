"""The receive side of a UR controller: :class:`URStateReader` (RTDE receive only, never moves anything).

Joint angles, joint speeds, the controller's TCP pose, its clock and its robot / safety / runtime modes, read
from one ur-rtde ``RTDEReceiveInterface``. The mode numbers and bit positions are the RTDE output fields
described in docs/protocols-ur.md ("RTDE state the driver reads"). A lost link shows either as EOF
(``isConnected() == False``) or as a controller timestamp that stops advancing (silence); both are reported
within :data:`CONNECTION_STALE_S`.

The flange pose here is UR's nominal DH forward kinematics of ``actual_q`` (:func:`ftacq.kinematics.flange_pose`, through
Pinocchio), never ``actual_TCP_pose``, so a TCP offset held by the controller cannot leak in.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from drivers.robot import RobotStatus
from drivers.ur_connection import PROBE_TIMEOUT_S, RTDE_PORT, call_with_deadline, probe_rtde
from drivers.ur_dashboard_server import read_controller_info
from ftacq.errors import ConfigError, DeviceConnectionError, DeviceError, DeviceTimeoutError, RobotError
from ftacq.kinematics import FlangeRotation, URModel, ur_model

log = logging.getLogger(__name__)

CONNECTION_STALE_S = 1.5
"""No new RTDE data package for this long means the connection is lost (ur-rtde itself waits 2.5 s)."""
DISCONNECT_TIMEOUT_S = 3.0
STEADY_JOINT_SPEED_RAD_S = 5e-3
"""The arm is steady when every |actual_qd| is below this."""

ROBOT_MODE_RUNNING = 7
RUNTIME_PLAYING = 2
SAFETY_NORMAL, SAFETY_REDUCED, SAFETY_PROTECTIVE_STOP = 1, 2, 3
SAFETY_EMERGENCY_MODES = (6, 7)  # SYSTEM_/ROBOT_EMERGENCY_STOP
SAFETY_BIT_PROTECTIVE, SAFETY_BIT_SAFEGUARD, SAFETY_BIT_SYSTEM_ESTOP, SAFETY_BIT_ROBOT_ESTOP, SAFETY_BIT_ESTOP = 2, 4, 5, 6, 7
ROBOT_MODE_NAMES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
                    4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE"}
SAFETY_MODE_NAMES = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
                     6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT",
                     10: "VALIDATE_JOINT_ID", 11: "UNDEFINED", 12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
                     13: "SYSTEM_THREE_POSITION_ENABLING_STOP"}
RUNTIME_STATE_NAMES = {0: "STOPPING", 1: "STOPPED", 2: "PLAYING", 3: "PAUSING", 4: "PAUSED", 5: "RESUMING"}

RECEIVE_VARIABLES = ["timestamp", "actual_q", "actual_qd", "actual_TCP_pose", "robot_mode", "safety_mode",
                     "runtime_state", "safety_status_bits"]
"""The receive recipe: only what ftacq reads (all in ur-rtde's decode table and in every controller's default
output list, docs/protocols-ur.md). A controller answering NOT_FOUND for one of them gets ur-rtde's default list."""

def _resolve_model(model: str | URModel | None) -> URModel | None:
    if model is None or isinstance(model, URModel):
        return model
    try:
        return ur_model(model)
    except ValueError as error:
        raise ConfigError(f"robot model {model!r}: {error}") from error


class URStateReader:
    """Receive-only view of a UR controller (RTDEReceiveInterface only; never moves anything).

    ``flange_pose()`` is the nominal DH forward kinematics of ``actual_q`` (TCP offset excluded). ``model`` is
    read from the UR Dashboard Server when not given (None if it cannot tell: then only ``tcp_pose()``).
    ``software_version`` is the controller's version from the RTDE handshake after :meth:`start`.
    """

    def __init__(self, host: str, frequency_hz: float | None = None, model: str | URModel | None = None,
                 connect_timeout_s: float = PROBE_TIMEOUT_S) -> None:
        self.host = host
        self.frequency_hz = frequency_hz
        self.model = _resolve_model(model)
        self.connect_timeout_s = connect_timeout_s
        self._receive: Any = None  # rtde_receive.RTDEReceiveInterface once started (ur-rtde ships no type stubs)
        self._last_timestamp: float | None = None  # the controller's timestamp, s
        self._last_change_s = 0.0
        self._timestamps_advance = False
        self.software_version: str | None = None
        self._pose_of: tuple[bytes, np.ndarray] = (b"", np.zeros(6))  # (actual_q's bytes, its flange pose)
        self._flange_rotation: FlangeRotation | None = None  # the model's, once a pose is asked

    def start(self) -> "URStateReader":
        """Connect. The RTDE handshake is walked first with a deadline (:func:`drivers.ur_connection.probe_rtde`):
        ur-rtde's constructor would wait forever for a controller that accepts and never answers. Raises
        DeviceConnectionError naming host and port when the controller is unreachable or silent."""
        import rtde_receive

        self.software_version = probe_rtde(self.host, self.connect_timeout_s).version_text
        if self.model is None:
            try:
                self.model = read_controller_info(self.host, self.connect_timeout_s).model
            except DeviceError as error:
                log.warning("cannot read the robot model from the UR Dashboard Server (%s); flange pose unavailable",
                            error)
        frequency = float(self.frequency_hz) if self.frequency_hz else -1.0
        try:
            try:
                self._receive = rtde_receive.RTDEReceiveInterface(self.host, frequency, RECEIVE_VARIABLES)
            except RuntimeError as error:
                if "not found" not in str(error).lower():
                    raise
                log.warning("robot %s: %s; using ur-rtde's default RTDE recipe", self.host, error)
                self._receive = rtde_receive.RTDEReceiveInterface(self.host, frequency)
        except RuntimeError as error:
            raise DeviceConnectionError(f"robot controller {self.host} port {RTDE_PORT} (RTDE): {error}") from error
        self._last_timestamp, self._last_change_s = self._receive.getTimestamp(), time.monotonic()
        return self

    def __enter__(self) -> "URStateReader":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def _rtde(self):
        if self._receive is None:
            raise DeviceConnectionError(f"robot controller {self.host}: not connected (call start())")
        return self._receive

    @property
    def connected(self) -> bool:
        """True while data packages keep arriving (EOF and silence > CONNECTION_STALE_S both count as lost)."""
        if self._receive is None or not self._receive.isConnected():
            return False
        timestamp, now = self._receive.getTimestamp(), time.monotonic()
        if timestamp != self._last_timestamp:
            self._timestamps_advance = True
            self._last_timestamp, self._last_change_s = timestamp, now
            return True
        # a controller whose timestamp never moves: rely on ur-rtde's own 2.5 s receive timeout
        return not self._timestamps_advance or now - self._last_change_s < CONNECTION_STALE_S

    def ensure_connected(self) -> None:
        """Raise DeviceConnectionError if the data stream is lost."""
        if self.connected:
            return
        cause = ("the controller closed the connection" if self._receive is None or not self._receive.isConnected()
                 else f"no state received for {CONNECTION_STALE_S:.1f} s")
        raise DeviceConnectionError(
            f"lost the connection to the robot controller {self.host}: {cause}. Check the network cable and the "
            "robot's power; the robot may still be moving, so watch it and use the teach pendant's stop if needed")

    def joint_positions(self) -> np.ndarray:
        """The 6 actual joint angles, rad."""
        return np.array(self._rtde().getActualQ(), dtype=float)

    def joint_speeds(self) -> np.ndarray:
        """The 6 actual joint speeds, rad/s."""
        return np.array(self._rtde().getActualQd(), dtype=float)

    def tcp_pose(self) -> np.ndarray:
        """``actual_TCP_pose`` as reported (includes the controller's TCP offset)."""
        return np.array(self._rtde().getActualTCPPose(), dtype=float)

    def flange_pose(self) -> np.ndarray:
        """Flange pose [x, y, z (m), rx, ry, rz (rad)] in the base frame from the nominal FK of ``actual_q``."""
        return self.joints_and_flange_pose()[1]

    def joints_and_flange_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(:meth:`joint_positions`, :meth:`flange_pose`) of one state: ``actual_q`` read once (the monitor asks at
        every read)."""
        if self.model is None:
            raise RobotError(f"robot controller {self.host}: unknown robot model; pass model= (e.g. 'UR5e')")
        q = self.joint_positions()
        key = q.tobytes()
        if self._pose_of[0] != key:  # the forward kinematics once per state
            self._pose_of = (key, self._flange_pose(q))
        return q, self._pose_of[1].copy()

    def _flange_pose(self, q: np.ndarray) -> np.ndarray:
        """:func:`ftacq.kinematics.flange_pose` of ``q`` through Pinocchio's model of the same DH chain
        (:class:`ftacq.kinematics.FlangeRotation`, equal to 1e-12: ~20 µs against ~75 µs of numpy per read)."""
        from ftacq.so3 import rotvec_of_rotation

        assert self.model is not None
        if self._flange_rotation is None:
            self._flange_rotation = FlangeRotation(self.model)
        base_R_flange, position_m = self._flange_rotation.placement(q)
        return np.concatenate([position_m, rotvec_of_rotation(base_R_flange)])

    def controller_time_s(self) -> float:
        """The controller's timestamp (s since it started)."""
        return float(self._rtde().getTimestamp())

    def status(self, steady: bool | None = None) -> RobotStatus:
        rtde = self._rtde()
        bits = int(rtde.getSafetyStatusBits())
        safety_mode = int(rtde.getSafetyMode())
        if steady is None:
            steady = bool(np.max(np.abs(self.joint_speeds())) < STEADY_JOINT_SPEED_RAD_S)
        return RobotStatus(
            robot_mode=int(rtde.getRobotMode()), safety_mode=safety_mode,
            protective_stop=bool(bits & (1 << SAFETY_BIT_PROTECTIVE)) or safety_mode == SAFETY_PROTECTIVE_STOP,
            emergency_stop=bool(bits & (1 << SAFETY_BIT_ESTOP)) or safety_mode in SAFETY_EMERGENCY_MODES,
            program_running=int(rtde.getRuntimeState()) == RUNTIME_PLAYING,
            connected=self.connected, steady=steady)

    def close(self) -> None:
        """Disconnect (≈0.5 s inside ur-rtde). Safe to call twice."""
        receive, self._receive = self._receive, None
        if receive is not None:
            try:
                call_with_deadline(receive.disconnect, timeout_s=DISCONNECT_TIMEOUT_S, what="receive-disconnect")
            except (RuntimeError, DeviceTimeoutError) as error:
                log.warning("RTDE receive disconnect from %s: %s", self.host, error)


    def safety_status_bits(self) -> int:
        """RTDE ``safety_status_bits`` (bit 2 protective stop, bit 4 safeguard stop, bit 7 emergency stop)."""
        return int(self._rtde().getSafetyStatusBits())

    def runtime_state(self) -> int:
        """RTDE ``runtime_state`` (2 = PLAYING: a program runs)."""
        return int(self._rtde().getRuntimeState())


__all__ = ["URStateReader", "CONNECTION_STALE_S", "STEADY_JOINT_SPEED_RAD_S", "RECEIVE_VARIABLES",
           "ROBOT_MODE_NAMES", "SAFETY_MODE_NAMES", "RUNTIME_STATE_NAMES"]
