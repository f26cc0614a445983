"""A Universal Robots arm over ur-rtde: :class:`URRobot`, the procedure's :class:`drivers.robot.Robot`.

The driver is split by idea: this module moves and supervises the arm; :mod:`drivers.ur_state` reads its state
(:class:`URStateReader`, also used alone by the live monitor); :mod:`drivers.ur_dashboard_server` talks to the UR
Dashboard Server (identity, protective-stop unlock); :mod:`drivers.ur_connection` reaches the controller with
deadlines. ``URRobot``, ``URStateReader`` and ``MotionLimits`` stay importable from here. It is a little over 500
lines because :class:`URRobot` is one supervisor: connecting, guarded calls, supervised moves, forward kinematics
and recovery all share its connection state (the lost-link flag, the call lock, the stop event).

The controller facts it relies on are written in docs/protocols-ur.md. In short:

- ur-rtde's constructors hold the GIL and wait for RTDE setup replies with no timeout, so the RTDE handshake is
  walked first on a plain socket with a deadline and the script port is probed: a controller that is unreachable,
  or accepts and never answers, fails within ``connect_timeout_s`` with a message naming host and port.
- ur-rtde's blocking commands can wait up to 300 s. Moves are therefore sent asynchronously
  (``moveJ(..., asynchronous=True)``) and this module polls the RTDE state with its own deadline; every other
  control call runs on a named worker thread with a deadline (:data:`CALL_TIMEOUT_S`).
- A dropped connection shows as ``isConnected() == False`` (EOF) or a controller timestamp that stops advancing
  (silence): both are detected within :data:`drivers.ur_state.CONNECTION_STALE_S` (< 3 s).

The flange pose is computed from the joint angles, never read from ``actual_TCP_pose``, so a TCP offset held
by the controller cannot leak into the calibration: :class:`URRobot` asks the controller's calibrated kinematics
(``getForwardKinematics(q, probe_tcp)`` with the probe removed again: ur-rtde 1.6.5 treats a zero TCP argument as
"use the active TCP") and falls back to UR's nominal DH model.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import replace

import numpy as np

from drivers.robot import MotionLimits, RobotStatus
from drivers.ur_connection import (
    DASHBOARD_SERVER_PORT,
    PROBE_TIMEOUT_S,
    RTDE_PORT,
    SCRIPT_PORT,
    call_with_deadline,
    probe_port,
    probe_rtde,
)
from drivers.ur_dashboard_server import (
    DashboardServerClient,
    URControllerInfo,
    model_from_dashboard_server,
    read_controller_info,
)
from drivers.ur_state import (
    CONNECTION_STALE_S,
    DISCONNECT_TIMEOUT_S,
    ROBOT_MODE_NAMES,
    ROBOT_MODE_RUNNING,
    RUNTIME_STATE_NAMES,
    SAFETY_BIT_SAFEGUARD,
    SAFETY_MODE_NAMES,
    SAFETY_NORMAL,
    SAFETY_REDUCED,
    STEADY_JOINT_SPEED_RAD_S,
    URStateReader,
)
from ftacq.errors import (
    AbortedError,
    ConfigError,
    DeviceConnectionError,
    DeviceError,
    DeviceTimeoutError,
    EmergencyStopError,
    MotionLimitError,
    ProgramStoppedError,
    ProtectiveStopError,
    RobotError,
)
from ftacq.kinematics import UR_MODELS, URModel, flange_pose
from ftacq.so3 import angle_between_deg, rotation_from_rotvec, rotvec_from_rotation

log = logging.getLogger(__name__)

POLL_INTERVAL_S = 0.005
STREAM_CATCH_UP_S = 0.25
"""How long the receive stream may lag the control stream (separate connections, separate client threads)."""
CALL_TIMEOUT_S = 10.0
"""Deadline of one guarded ur-rtde control call (moves are asynchronous, so every call should take ms)."""
LOST_DISCONNECT_TIMEOUT_S = 1.0
SCRIPT_START_TIMEOUT_S = 8.0
SAFETY_CLEAR_TIMEOUT_S = 8.0
"""Long enough for UR's rule that a protective stop can be unlocked only 5 s after it happened."""
UNLOCK_RETRY_S = 0.5
JOINT_TARGET_TOLERANCE_RAD = 1e-3
"""A joint move has arrived when every joint is this close to its target (and the arm is steady)."""
ARRIVAL_CONFIRM_S = 0.25
"""At the target and steady this long counts as arrived even while the async progress word still says running."""
STALL_GRACE_S = 1.0
"""A move that is not running, not moving and not at its target for this long (s of the controller's clock, in the
state stream) has been stopped."""
FK_CROSS_CHECK_M, FK_CROSS_CHECK_DEG = 0.05, 5.0
"""Controller FK further than this from the nominal DH model is not trusted (wrong model or a broken reply)."""
FK_CALL_TIMEOUT_S = 2.0
FK_PROBE_TCP = (0.0, 0.0, 0.2, 0.0, 0.0, 0.0)
"""A non-zero TCP passed to ``getForwardKinematics`` and removed again (a zero one means 'use the active TCP')."""

# ur-rtde's own client-side ranges (docs/protocols-ur.md): limits above these could never be sent.
UR_RTDE_MAX_JOINT_SPEED_RAD_S, UR_RTDE_MAX_JOINT_ACCELERATION_RAD_S2 = 3.14, 40.0
UR_RTDE_MAX_TOOL_SPEED_M_S, UR_RTDE_MAX_TOOL_ACCELERATION_M_S2 = 3.0, 150.0


PROTECTIVE_STOP_MESSAGE = (
    "the robot is in a PROTECTIVE STOP (it hit something, or a joint/speed limit was exceeded). Look at the "
    "cell and the pendant's message, remove the cause, then unlock the protective stop on the teach pendant "
    "(or `unlock_protective_stop()`) and start again")
EMERGENCY_STOP_MESSAGE = (
    "an EMERGENCY STOP is active on the robot. Make the cell safe, release the e-stop button, close the safety "
    "pop-up, power on and release the brakes on the teach pendant, then start again")
PROGRAM_STOPPED_MESSAGE = (
    "the control program on the robot is not running (Stop was pressed on the teach pendant, another program "
    "was started, or the robot was powered off). Check the pendant, then start again")


def _pose_matrix(pose: np.ndarray) -> np.ndarray:
    """4×4 transform of a pose [x, y, z, rx, ry, rz]."""
    matrix = np.eye(4)
    matrix[:3, :3] = rotation_from_rotvec(pose[3:6])
    matrix[:3, 3] = pose[:3]
    return matrix


def _check_limit(value: float, limit: float, what: str, unit: str, key: str) -> float:
    value = float(value)
    if not math.isfinite(value) or value <= 0.0:
        raise MotionLimitError(f"{what} must be a positive number, got {value!r} {unit}")
    if value > limit:
        raise MotionLimitError(f"{what} {value:g} {unit} exceeds the configured limit {limit:g} {unit} "
                               f"({key}); refusing the move (speeds are never clamped)")
    return value


def validate_limits(limits: MotionLimits) -> MotionLimits:
    """Raise ConfigError if a limit is not positive or above what ur-rtde can send."""
    for key, value, ceiling in (("joint_speed_rad_s", limits.joint_speed_rad_s, UR_RTDE_MAX_JOINT_SPEED_RAD_S),
                                ("joint_acceleration_rad_s2", limits.joint_acceleration_rad_s2,
                                 UR_RTDE_MAX_JOINT_ACCELERATION_RAD_S2),
                                ("tool_speed_m_s", limits.tool_speed_m_s, UR_RTDE_MAX_TOOL_SPEED_M_S),
                                ("tool_acceleration_m_s2", limits.tool_acceleration_m_s2,
                                 UR_RTDE_MAX_TOOL_ACCELERATION_M_S2)):
        if not (math.isfinite(value) and 0.0 < value <= ceiling):
            raise ConfigError(f"motion limit {key} = {value!r}: must be > 0 and ≤ {ceiling:g}")
    return limits


class URRobot:
    """A UR arm over ur-rtde implementing :class:`drivers.robot.Robot`.

    ``URRobot(host, limits, model=None)`` then :meth:`start` (or ``with URRobot(...) as robot:``). ``model`` is
    read from the UR Dashboard Server when None. Every move is checked against ``limits`` (refused, never clamped) and the
    model's joint limits, sent asynchronously and supervised here: protective stop, emergency stop, program
    stopped and lost connection raise the matching :mod:`ftacq.errors` type; nothing waits without a deadline.
    """

    def __init__(self, host: str, limits: MotionLimits, model: str | URModel | None = None,
                 connect_timeout_s: float = PROBE_TIMEOUT_S, frequency_hz: float | None = None,
                 leave_external_ft_input: bool = False) -> None:
        self.host = host
        self.leave_external_ft_input = leave_external_ft_input
        """Open the control interface with FLAG_NO_EXT_FT, so that another client (drivers/ur_ft_input.py) may
        own the RTDE input ``external_force_torque`` (ur-rtde's recipe 23 holds it otherwise)."""
        self.limits = validate_limits(limits)
        self.connect_timeout_s = connect_timeout_s
        self.frequency_hz = frequency_hz
        """RTDE rate (Hz) of ur-rtde's receive and control interfaces; None = the controller's maximum."""
        self._reader = URStateReader(host, frequency_hz, model, connect_timeout_s)
        self._control = None
        self._call_lock = threading.Lock()
        self._stop_event = threading.Event()
        self._lost: str | None = None
        self.info: URControllerInfo | None = None
        self._fk_warned = False
        self._controller_fk_usable = True

    # ------------------------------------------------------------------ life cycle
    @property
    def model(self) -> URModel | None:
        return self._reader.model

    def start(self) -> "URRobot":
        """Connect: RTDE handshake probe and script port (with deadlines), UR Dashboard Server (model, version),
        RTDE receive, RTDE control (uploads ur-rtde's control script).

        Raises DeviceConnectionError naming host and port within about ``connect_timeout_s`` per port when the
        controller is unreachable or accepts and never answers."""
        import rtde_control

        probe = probe_rtde(self.host, self.connect_timeout_s)
        probe_port(self.host, SCRIPT_PORT, self.connect_timeout_s, what="script")
        try:
            self.info = read_controller_info(self.host, self.connect_timeout_s)
        except DeviceError as error:  # PolyScope X (10.x) has no Dashboard Server
            log.warning("robot %s: no UR Dashboard Server (%s); model and serial number unknown", self.host, error)
            self.info = URControllerInfo.unknown(probe.version_text)
        if self._reader.model is None:
            self._reader.model = self.info.model
        if self._reader.model is None:
            log.warning("robot %s: unknown model %r; joint limits unchecked, flange pose from the controller only "
                        "(pass model=, e.g. 'UR5e')", self.host, self.info.model_reply)
        self._reader.start()
        try:
            interface = rtde_control.RTDEControlInterface
            flags = interface.FLAG_UPLOAD_SCRIPT | (interface.FLAG_NO_EXT_FT if self.leave_external_ft_input else 0)
            self._control = interface(self.host, float(self.frequency_hz or -1.0), flags)
        except RuntimeError as error:
            self._reader.close()
            raise DeviceConnectionError(
                f"robot controller {self.host}: cannot start ur-rtde's control program ({error}). Check that the "
                "robot is powered on, brakes released, in remote control, and no protective stop is active") from error
        return self

    def __enter__(self) -> "URRobot":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Disconnect the control and receive interfaces at once. Safe to call twice.

        ur-rtde sleeps 0.5 s in each ``disconnect()`` (the GIL released) and again in each destructor (the GIL
        held): the two connections are independent, so their disconnects overlap (1.5 s instead of 2 s)."""
        control, self._control = self._control, None
        if control is None:
            self._reader.close()
            return
        closing_reader = threading.Thread(target=self._reader.close, name="ur-rtde-receive-close", daemon=True)
        closing_reader.start()
        # after a lost connection a ur-rtde call may still be blocked inside the client: do not wait long
        timeout_s = LOST_DISCONNECT_TIMEOUT_S if self._lost else DISCONNECT_TIMEOUT_S
        try:
            call_with_deadline(control.disconnect, timeout_s=timeout_s, what="control-disconnect")
        except (RuntimeError, DeviceTimeoutError) as error:
            log.warning("RTDE control disconnect from %s: %s", self.host, error)
        finally:
            closing_reader.join()  # its disconnect has its own deadline (URStateReader.close)

    # ------------------------------------------------------------------ guarded calls
    def _ctrl(self):
        if self._lost:
            raise DeviceConnectionError(self._lost)
        if self._control is None:
            raise DeviceConnectionError(f"robot controller {self.host}: not connected (call start())")
        return self._control

    def _call(self, method_name: str, *args, timeout_s: float = CALL_TIMEOUT_S):
        control = self._ctrl()
        if not self._call_lock.acquire(timeout=timeout_s):
            raise DeviceTimeoutError(f"robot controller {self.host}: a previous command is still pending")
        try:
            return call_with_deadline(getattr(control, method_name), *args, timeout_s=timeout_s, what=method_name,
                                       watchdog=self._check_connection)
        except DeviceTimeoutError:
            self._check_connection()
            raise
        finally:
            self._call_lock.release()

    def _check_connection(self) -> None:
        try:
            self._reader.ensure_connected()
        except DeviceConnectionError as error:
            self._lost = str(error)
            raise

    # ------------------------------------------------------------------ state
    def joint_positions(self) -> np.ndarray:
        self._check_connection()
        return self._reader.joint_positions()

    def tcp_pose(self) -> np.ndarray:
        """``actual_TCP_pose`` as the controller reports it (includes its TCP offset; not used for calibration)."""
        self._check_connection()
        return self._reader.tcp_pose()

    def flange_pose(self) -> np.ndarray:
        """Flange pose in the base frame from ``actual_q`` (TCP offset excluded, whatever TCP the controller holds).

        Uses the controller's calibrated kinematics when it answers: ``getForwardKinematics(q, probe)`` with a
        non-zero probe TCP (:data:`FK_PROBE_TCP`), composed with the probe's inverse. A zero TCP cannot be asked
        for: ur-rtde 1.6.5 treats ``tcp_offset=[0]*6`` as "not given" and the controller then applies its active
        TCP. The result is cross-checked against UR's nominal DH model, which is also the fallback (faults,
        program not running, or a reply further than FK_CROSS_CHECK_M / FK_CROSS_CHECK_DEG away).
        """
        q = self.joint_positions()
        model = self.model
        nominal = flange_pose(model, q) if model is not None else None
        controller = self._controller_flange_pose(q)
        if controller is not None:
            if model is None or nominal is None or self._close_poses(controller, nominal):
                return controller
            if not self._fk_warned:
                self._fk_warned = True
                log.warning("robot %s: the controller's forward kinematics disagrees with the %s model by more than "
                            "%g m / %g deg; using the nominal model (is the model right?)", self.host,
                            model.name, FK_CROSS_CHECK_M, FK_CROSS_CHECK_DEG)
        if nominal is None:
            raise RobotError(f"robot controller {self.host}: cannot compute the flange pose (unknown robot model and "
                             "no forward kinematics from the controller); pass model=, e.g. 'UR5e'")
        return nominal

    def _controller_flange_pose(self, q: np.ndarray) -> np.ndarray | None:
        status = self._status(steady=True)
        if not status.program_running or status.protective_stop or status.emergency_stop:
            return None
        if not self._controller_fk_usable:
            return None
        try:
            reply = self._call("getForwardKinematics", [float(v) for v in q], list(FK_PROBE_TCP),
                               timeout_s=FK_CALL_TIMEOUT_S)
        except (RuntimeError, DeviceTimeoutError) as error:
            self._controller_fk_usable = False
            log.warning("robot %s: getForwardKinematics failed (%s); using the nominal model from now on",
                        self.host, error)
            return None
        if reply is None or len(reply) != 6 or not np.all(np.isfinite(reply)):
            return None
        base_T_probe = _pose_matrix(np.asarray(reply, dtype=float))
        base_T_flange = base_T_probe @ np.linalg.inv(_pose_matrix(np.asarray(FK_PROBE_TCP)))
        return np.concatenate([base_T_flange[:3, 3], rotvec_from_rotation(base_T_flange[:3, :3])])

    @staticmethod
    def _close_poses(a: np.ndarray, b: np.ndarray) -> bool:
        angle = float(angle_between_deg(rotation_from_rotvec(a[3:6]), rotation_from_rotvec(b[3:6])))
        return float(np.linalg.norm(a[:3] - b[:3])) < FK_CROSS_CHECK_M and angle < FK_CROSS_CHECK_DEG

    def is_steady(self) -> bool:
        self._check_connection()
        return bool(np.max(np.abs(self._reader.joint_speeds())) < STEADY_JOINT_SPEED_RAD_S)

    def status(self) -> RobotStatus:
        return self._status()

    def _status(self, steady: bool | None = None) -> RobotStatus:
        """The reader's status, with ``program_running`` as ur-rtde's control interface sees it (the state it
        uses itself to decide whether it can send a command)."""
        status = self._reader.status(steady=steady)
        control = self._control
        if control is None or self._lost:
            return status
        try:
            running = bool(control.isProgramRunning())
        except RuntimeError:
            return status
        if running == status.program_running:
            return status
        # the two connections are separate streams: let the receive stream catch up, so that the program state
        # and the safety state it is judged with (e-stop stops the program) come from the same package
        deadline = time.monotonic() + STREAM_CATCH_UP_S
        while time.monotonic() < deadline:
            time.sleep(POLL_INTERVAL_S)
            status = self._reader.status(steady=steady)
            if status.program_running == running:
                return status
        return replace(status, program_running=running)

    def controller_time_s(self) -> float:
        return self._reader.controller_time_s()

    def raise_if_faulted(self) -> None:
        """Raise the typed error for the controller's current state (connection, e-stop, protective stop,
        safeguard stop, power, program); return quietly when it can take a move."""
        self._check_connection()
        status = self._status(steady=True)
        self._raise_for(status)

    def _raise_for(self, status: RobotStatus) -> None:
        host = self.host
        if status.emergency_stop:
            raise EmergencyStopError(f"robot {host}: {EMERGENCY_STOP_MESSAGE}")
        if status.protective_stop:
            raise ProtectiveStopError(f"robot {host}: {PROTECTIVE_STOP_MESSAGE}")
        bits = int(self._reader.safety_status_bits())
        if status.safety_mode not in (SAFETY_NORMAL, SAFETY_REDUCED) or bits & (1 << SAFETY_BIT_SAFEGUARD):
            name = SAFETY_MODE_NAMES.get(status.safety_mode, str(status.safety_mode))
            raise RobotError(f"robot {host}: safety mode is {name} (a safeguard device, door or light curtain, or a "
                             "safety fault). Clear it on the teach pendant, then start again")
        if status.robot_mode != ROBOT_MODE_RUNNING:
            name = ROBOT_MODE_NAMES.get(status.robot_mode, str(status.robot_mode))
            raise RobotError(f"robot {host}: the arm is not running (robot mode {name}). Power it on and release "
                             "the brakes on the teach pendant, then start again")
        if not status.program_running:
            raise ProgramStoppedError(f"robot {host}: {PROGRAM_STOPPED_MESSAGE}")

    # ------------------------------------------------------------------ motion
    def _check_joint_target(self, joint_target_rad) -> np.ndarray:
        target = np.asarray(joint_target_rad, dtype=float)
        if target.shape != (6,) or not np.all(np.isfinite(target)):
            raise MotionLimitError(f"joint target must be 6 finite angles in rad, got {joint_target_rad!r}")
        if self.model is not None:
            low, high = np.array(self.model.joint_min_rad), np.array(self.model.joint_max_rad)
            outside = np.flatnonzero((target < low) | (target > high))
            if outside.size:
                j = int(outside[0])
                raise MotionLimitError(f"joint {j + 1} target {target[j]:.4f} rad is outside the {self.model.name} "
                                       f"joint limits [{low[j]:.4f}, {high[j]:.4f}] rad; refusing the move")
        return target

    def move_joints(self, joint_target_rad: np.ndarray, speed_rad_s: float, acceleration_rad_s2: float,
                    timeout_s: float = 60.0) -> None:
        """moveJ to ``joint_target_rad`` and wait until the arm is there and steady (see :class:`drivers.robot.Robot`).

        Raises MotionLimitError (before anything moves) for a speed/acceleration above the limits or a target
        outside the joint limits; ProtectiveStopError, EmergencyStopError, ProgramStoppedError, RobotError,
        DeviceConnectionError when the controller faults; AbortedError when :meth:`stop` was called;
        DeviceTimeoutError (after stopping the arm) when the move takes longer than ``timeout_s``.
        """
        target = self._check_joint_target(joint_target_rad)
        speed = _check_limit(speed_rad_s, self.limits.joint_speed_rad_s, "joint speed", "rad/s", "joint_speed_rad_s")
        acceleration = _check_limit(acceleration_rad_s2, self.limits.joint_acceleration_rad_s2, "joint acceleration",
                                    "rad/s²", "joint_acceleration_rad_s2")
        self._move("moveJ", target, speed, acceleration, timeout_s,
                   arrived=lambda: bool(np.max(np.abs(self._reader.joint_positions() - target))
                                        < JOINT_TARGET_TOLERANCE_RAD))

    def move_linear(self, tcp_pose_target: np.ndarray, speed_m_s: float, acceleration_m_s2: float,
                    timeout_s: float = 60.0, position_tolerance_m: float = 1e-4) -> None:
        """moveL the controller's TCP to ``tcp_pose_target`` [x, y, z, rx, ry, rz] (base frame, the controller's
        active TCP) and wait; bounded by the tool limits. Errors as :meth:`move_joints`."""
        target = np.asarray(tcp_pose_target, dtype=float)
        if target.shape != (6,) or not np.all(np.isfinite(target)):
            raise MotionLimitError(f"pose target must be 6 finite numbers, got {tcp_pose_target!r}")
        speed = _check_limit(speed_m_s, self.limits.tool_speed_m_s, "tool speed", "m/s", "tool_speed_m_s")
        acceleration = _check_limit(acceleration_m_s2, self.limits.tool_acceleration_m_s2, "tool acceleration",
                                    "m/s²", "tool_acceleration_m_s2")
        self._move("moveL", target, speed, acceleration, timeout_s,
                   arrived=lambda: bool(np.linalg.norm(self._reader.tcp_pose()[:3] - target[:3]) < position_tolerance_m))

    def _move(self, method: str, target: np.ndarray, speed: float, acceleration: float, timeout_s: float,
              arrived) -> None:
        self.raise_if_faulted()
        self._stop_event.clear()
        deadline = time.monotonic() + timeout_s
        for _attempt in range(2):
            # asynchronous, so this returns at once; a controller that ran it synchronously still gets the full
            # move deadline (the watchdog keeps checking the connection meanwhile)
            accepted = self._call(method, [float(v) for v in target], speed, acceleration, True,
                                  timeout_s=max(CALL_TIMEOUT_S, deadline - time.monotonic()))
            if accepted:
                break
            # the control stream may be ahead of the receive stream (a new fault) or behind it (a stop that was
            # just cleared): wait for the receive stream to show a fault; if none shows, send once more
            deadline_fault = time.monotonic() + STREAM_CATCH_UP_S
            while time.monotonic() < deadline_fault:
                self.raise_if_faulted()
                time.sleep(POLL_INTERVAL_S)
        if not accepted:
            raise RobotError(f"robot {self.host}: the controller refused {method} to {np.round(target, 5).tolist()}")
        idle_since = arrived_since = None
        while True:
            if self._stop_event.is_set():
                raise AbortedError(f"robot {self.host}: the move was stopped before reaching its target")
            self._check_connection()
            status = self._status()
            self._raise_for(status)
            now = time.monotonic()
            if status.steady and arrived():
                arrived_since = arrived_since or now
                # the async word says the move is over; a controller without it: still there after a while
                if not self._async_running() or now - arrived_since > ARRIVAL_CONFIRM_S:
                    return
            else:
                arrived_since = None
            if status.steady and not self._async_running():
                # on the controller's clock, as the state stream shows it: a stream that lags behind the control
                # connection (a loaded host) shows the arm still on its way, never a stall that did not happen
                stamp_s = self._reader.controller_time_s()
                idle_since = stamp_s if idle_since is None else idle_since
                if stamp_s - idle_since > STALL_GRACE_S:
                    raise RobotError(f"robot {self.host}: the arm stopped before reaching the {method} target "
                                     f"{np.round(target, 5).tolist()} (stopped from the pendant or another client?)")
            else:
                idle_since = None
            if now > deadline:
                self.stop()
                raise DeviceTimeoutError(f"robot {self.host}: {method} did not reach its target within "
                                         f"{timeout_s:g} s; the arm was stopped")
            time.sleep(POLL_INTERVAL_S)

    def _async_running(self) -> bool:
        try:
            return bool(self._ctrl().getAsyncOperationProgressEx().isAsyncOperationRunning())
        except (RuntimeError, AttributeError):
            return False

    def stop(self) -> None:
        """Decelerate to a stop (stopJ at the configured joint acceleration). Never raises for a faulted or
        disconnected controller (it logs instead); interrupts a :meth:`move_joints` waiting in another thread."""
        self._stop_event.set()
        if self._control is None or self._lost:
            return
        try:
            status = self._status(steady=True)
            if status.program_running and status.connected:
                self._call("stopJ", float(self.limits.joint_acceleration_rad_s2), False,
                           timeout_s=min(CALL_TIMEOUT_S, 5.0))
        except (RuntimeError, DeviceConnectionError, DeviceTimeoutError) as error:
            log.warning("robot %s: stop failed: %s", self.host, error)

    # ------------------------------------------------------------------ external F/T input and payload
    def enable_external_ft_input(self, enable: bool, function: str = "ft_rtde_input_enable", sensor_mass_kg: float = 0.0,
                                 sensor_measuring_offset_m=(0.0, 0.0, 0.0), sensor_cog_m=(0.0, 0.0, 0.0)) -> None:
        """Call URScript ``ft_rtde_input_enable`` (or the deprecated ``enable_external_ft_sensor``) through ur-rtde
        (``ftRtdeInputEnable`` / ``enableExternalFtSensor``). ur-rtde's script calls ``ft_rtde_input_enable`` only
        on 5.9 and newer: pick the function with :func:`ftacq.bridge_convention.enable_function_for`."""
        method = {"ft_rtde_input_enable": "ftRtdeInputEnable",
                  "enable_external_ft_sensor": "enableExternalFtSensor"}[function]
        if not self._call(method, bool(enable), float(sensor_mass_kg), [float(v) for v in sensor_measuring_offset_m],
                          [float(v) for v in sensor_cog_m]):
            raise RobotError(f"robot {self.host}: the controller refused {function}({enable})")

    # ------------------------------------------------------------------ recovery
    def set_payload(self, mass_kg: float, cog_m, inertia_kg_m2=None) -> str:
        """Set the payload (drivers/ur_payload.py): setTargetPayload with the inertia on PolyScope 5.10+ and X,
        setPayload (mass and centre of gravity only) before. Returns the ur-rtde method used; raises RobotError
        when the controller refuses."""
        from drivers.ur_payload import takes_target_payload

        cog = [float(v) for v in cog_m]
        if takes_target_payload(self.info.software_version if self.info else None):
            inertia = [0.0] * 6 if inertia_kg_m2 is None else [float(v) for v in inertia_kg_m2]
            method, ok = "setTargetPayload", self._call("setTargetPayload", float(mass_kg), cog, inertia)
        else:
            method, ok = "setPayload", self._call("setPayload", float(mass_kg), cog)
        if not ok:
            raise RobotError(f"robot controller {self.host}: {method} was refused")
        return method

    def set_gravity(self, gravity_m_s2) -> None:
        """Set the gravity direction: [m/s²] in the base frame, away from the earth's centre (setGravity)."""
        if not self._call("setGravity", [float(v) for v in gravity_m_s2]):
            raise RobotError(f"robot controller {self.host}: setGravity was refused")

    def _dashboard_server(self, *commands: str) -> None:
        """Run recovery commands (methods of :class:`DashboardServerClient`) on the UR Dashboard Server."""
        try:
            with DashboardServerClient(self.host, connect_timeout_s=self.connect_timeout_s) as server:
                for command in commands:
                    getattr(server, command)()
        except DeviceError as error:
            raise RobotError(f"robot {self.host}: UR Dashboard Server command failed: {error}") from error

    def _wait_until(self, predicate, timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not predicate():
            self._check_connection()
            if time.monotonic() > deadline:
                raise DeviceTimeoutError(f"robot {self.host}: {what} did not happen within {timeout_s:g} s")
            time.sleep(POLL_INTERVAL_S)

    def unlock_protective_stop(self, timeout_s: float = SAFETY_CLEAR_TIMEOUT_S) -> None:
        """Unlock a protective stop through the UR Dashboard Server (as the pendant's Unlock button), then make sure the
        control program runs again. A real controller refuses the unlock during the first 5 s after the stop:
        the request is repeated until ``timeout_s``."""
        self._check_connection()
        if self._status(steady=True).protective_stop:
            deadline = time.monotonic() + timeout_s
            while True:
                try:
                    self._dashboard_server("close_safety_popup", "unlock_protective_stop")
                    break
                except RobotError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(UNLOCK_RETRY_S)
            self._wait_until(lambda: not self._status(steady=True).protective_stop,
                             max(deadline - time.monotonic(), 1.0), "unlocking the protective stop")
        self.restart_control_script()

    def restart_control_script(self, timeout_s: float = SCRIPT_START_TIMEOUT_S) -> None:
        """(Re)upload ur-rtde's control program if it is not running, and wait until it runs."""
        self._check_connection()
        if self._status(steady=True).program_running:
            return
        self._call("reuploadScript")
        self._wait_until(lambda: self._status(steady=True).program_running, timeout_s,
                         "starting the control program")


__all__ = ["URRobot", "URStateReader", "MotionLimits", "URControllerInfo", "read_controller_info",
           "model_from_dashboard_server", "probe_port", "probe_rtde", "validate_limits", "UR_MODELS", "RTDE_PORT",
           "DASHBOARD_SERVER_PORT", "SCRIPT_PORT", "PROBE_TIMEOUT_S", "CONNECTION_STALE_S", "ROBOT_MODE_NAMES",
           "SAFETY_MODE_NAMES", "RUNTIME_STATE_NAMES"]
