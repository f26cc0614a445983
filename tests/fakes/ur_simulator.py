"""State machine of the simulated UR controller: modes, registers, the ur_rtde control-script handshake,
motion, fault injection and the record of executed motion commands. No sockets here (see ur_controller.py).

Over 600 lines because the control script's registers, modes and motion share one lock and one tick; the
external F/T input (ur_external_ft.py) and motion profiles (ur_motion.py) are already apart. Next split: payload
and gravity commands into their own module.

All public methods take ``self.lock``; the network threads call them, the tick thread calls :meth:`step`.
The control script is emulated as docs/protocols-ur.md ("ur-rtde's control program") describes: ``input_int_register_(0+off)``
carries the command id, ``output_int_register_(0+off)`` is 1 (ready) / 2 (done), results go to
``output_int_register_(1+off)`` / ``output_double_register_(0..5+off)``, the async progress word to
``output_int_register_(2+off)``.
"""

from __future__ import annotations

import functools
import math
import re
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ftacq.kinematics import URModel, flange_pose, forward_kinematics, pose_of_transform
from ftacq.mounts import mount_of
from ftacq.so3 import rotation_from_rotvec, rotvec_from_rotation
from tests.fakes.rigid_body import FlangeMotion, cross3, dh_frames, flange_motion
from tests.fakes.rtde_protocol import REGISTER_COUNT
from tests.fakes.ur_external_ft import ExternalFTInput
from tests.fakes.ur_motion import JointMove, LinearMove, Motion, joint_positions_for_pose, within_joint_limits
from tests.fakes.world import JointState, any_nonzero

# robot_mode (docs/protocols-ur.md)
ROBOT_MODE_POWER_OFF, ROBOT_MODE_POWER_ON, ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING = 3, 4, 5, 7
ROBOT_MODE_NAMES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
                    4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE"}
# safety_mode
SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP, SAFETY_ROBOT_EMERGENCY_STOP = 1, 3, 7
SAFETY_MODE_NAMES = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
                     6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT"}
# runtime_state
RUNTIME_STOPPED, RUNTIME_PLAYING, RUNTIME_PAUSED = 1, 2, 4

# command ids (docs/protocols-ur.md)
CMD_CLEAR, CMD_MOVEJ, CMD_MOVEJ_IK, CMD_MOVEL, CMD_MOVEL_FK = 0, 1, 2, 3, 4
CMD_SET_PAYLOAD, CMD_SET_TCP, CMD_PROTECTIVE_STOP, CMD_STOPL, CMD_STOPJ = 17, 29, 31, 33, 34
CMD_GET_TCP_OFFSET, CMD_FK_DEFAULT, CMD_FK_ARGS, CMD_MOVE_PATH, CMD_IS_STEADY = 40, 43, 44, 45, 47
CMD_GET_FLANGE_POSE, CMD_STOP_SCRIPT = 58, 255
CMD_SET_EXTERNAL_FORCE_TORQUE, CMD_FT_RTDE_INPUT_ENABLE, CMD_ENABLE_EXTERNAL_FT_SENSOR = 55, 56, 57
CMD_SET_GRAVITY, CMD_SET_TARGET_PAYLOAD = 59, 65
SET_TARGET_PAYLOAD_SINCE = (5, 10)
"""ur-rtde's script calls set_target_payload only on controllers from 5.10 (``$5.10`` lines); older ones ignore it."""
FT_RTDE_INPUT_ENABLE_SINCE = (5, 9)
"""ur-rtde's script calls ft_rtde_input_enable only on controllers from 5.9 (a ``$5.9`` line)."""
REALTIME_COMMANDS = frozenset({6, 9, 10, 11, 24, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})
REALTIME_NAMES = {9: "speedj", 10: "speedl", 11: "servoj", 24: "servol", 66: "direct_torque"}

SCRIPT_COMPILE_DELAY_S = 0.05
"""Delay between receiving a script and running it (also orders the client's 'clear' before the start, §7)."""
E_SERIES_CYCLE_S, CB3_CYCLE_S = 0.002, 0.008
"""A real controller's cycle, s: 500 Hz on e-Series (software 5 and later), 125 Hz on a CB3 (software 3). It is
the RTDE stream's fastest rate (UR's RTDE guide) and the step of its ``timestamp``."""
MIN_SETTLE_S = 0.012
"""'Done' is signalled at least this long (and 2.5 stream periods) after the final state is published (§7.11)."""
STEADY_SPEED_RAD_S = 1e-6
ENCODER_NOISE_RAD = 1e-6
"""1σ of the Gaussian jitter on the reported joint angles (``actual_q``), rad: what a real UR5e's encoders show at
rest, independent per joint and per cycle. The motion itself (``q``, ``target_q``, the flange pose the sensor sees)
stays exact. The simulated cell (:class:`tests.fakes.cell.SimulatedCell`: the procedure's tests, ``--sim``) turns
it on by default; a bare controller (the protocol tests, which compare angles exactly) reports exact angles unless
given ``encoder_noise_rad``."""
SERVO_LAG_S = 0.004
"""How far the physical arm follows the controller's target, s (motion time): a real UR's joints track
``target_q`` a few ms late (servo tracking). ``actual_q``, ``actual_qd``, the actual TCP pose and speed, the tool
accelerometer and the tool's physics the simulated sensor feels are the target's of this long ago; ``target_*``
are the profile's now. The simulated cell (``--sim``, the tests, the benchmarks) turns it on by default; a bare
controller (the protocol tests) has none unless given ``servo_lag_s``."""
STANDARD_GRAVITY_M_S2 = 9.81
MOUNT_GRAVITY_M_S2 = {"floor": (0.0, 0.0, -STANDARD_GRAVITY_M_S2), "wall": (-STANDARD_GRAVITY_M_S2, 0.0, 0.0),
                      "ceiling": (0.0, 0.0, STANDARD_GRAVITY_M_S2)}
"""The gravity vector in the base frame the controller assumes for each nominal mount (RTDE ``target_gravity``),
m/s²; any other mount spec: :func:`mount_gravity_m_s2`."""


@functools.lru_cache(maxsize=32)
def mount_gravity_m_s2(mount: str) -> tuple[float, float, float]:
    """The gravity vector (RTDE ``target_gravity``, m/s²) in the base frame for a mount name or spec."""
    down = np.array(mount_of(mount).down_base)
    return (float(STANDARD_GRAVITY_M_S2 * down[0]), float(STANDARD_GRAVITY_M_S2 * down[1]),
            float(STANDARD_GRAVITY_M_S2 * down[2]))

_PATH_LINE = re.compile(
    r"^\s*(movej|movel|movep)\(\s*(p?)\[([-+0-9.eE,\s]+)\]\s*,\s*a\s*=\s*([-+0-9.eE]+)\s*,\s*v\s*=\s*([-+0-9.eE]+)"
    r"\s*,\s*r\s*=\s*([-+0-9.eE]+)\s*\)", re.MULTILINE)
_INT_OFFSET = re.compile(r"#\s*int register offset\s*\n\s*(\d+)")
_WRITE_OUT_INT = re.compile(r"write_output_integer_register\(\s*(\d+)\s*(?:\+\s*(\d+))?\s*,\s*(-?\d+)\s*\)")


@dataclass
class ScriptProgram:
    """An uploaded URScript program as the fake understands it."""

    is_control_script: bool
    int_offset: int = 0
    path: list[tuple[str, np.ndarray, float, float, float]] = field(default_factory=list)
    output_writes: list[tuple[int, int]] = field(default_factory=list)
    name: str = "rtde_control"

    @classmethod
    def parse(cls, text: str) -> "ScriptProgram":
        """Recognise ur_rtde's control script (``def rtde_control():``), its register offset and path lines."""
        head = re.search(r"def\s+([A-Za-z_][A-Za-z0-9_]*)\s*\(", text)
        name = head.group(1) if head else "script"
        if name != "rtde_control":
            writes = [(int(m.group(1)) + int(m.group(2) or 0), int(m.group(3))) for m in _WRITE_OUT_INT.finditer(text)]
            return cls(False, name=name, output_writes=writes)
        offset_match = _INT_OFFSET.search(text)
        path = []
        for m in _PATH_LINE.finditer(text):
            values = np.array([float(v) for v in m.group(3).split(",")])
            kind = "movej" if m.group(1) == "movej" else "movel"
            path.append((kind, values, float(m.group(4)), float(m.group(5)), float(m.group(6))))
        return cls(True, int(offset_match.group(1)) if offset_match else 0, path)


@dataclass
class Fault:
    """A fault to inject: kind in {protective_stop, emergency_stop, program_stop, drop, freeze}.

    trigger: "now", "after" (``value`` wall seconds after injection), "move_after" (``value`` wall seconds into
    move ``move``), "move_fraction" (at fraction ``value`` of move ``move``'s duration). ``move`` is the 1-based
    number of the motion command as counted in the record; None means the next move.
    """

    kind: str
    trigger: str = "now"
    value: float = 0.0
    move: int | None = None
    created_s: float = 0.0


class URSimulator:
    """The simulated controller's state. ``network`` hooks (drop/freeze) are set by the server."""

    def __init__(self, model: URModel, *, time_scale: float = 1.0, version: tuple[int, int, int, int] = (5, 11, 1, 108318),
                 initial_q: np.ndarray | None = None, mount: str = "floor", serial_number: str = "20235500123",
                 encoder_noise_rad: float = 0.0, seed: int | None = None, clock_rate_error: float = 0.0,
                 servo_lag_s: float = 0.0) -> None:
        self.lock = threading.RLock()
        if not 0.0 <= servo_lag_s <= 0.05:
            raise ValueError(f"servo_lag_s {servo_lag_s!r}: a servo follows its target by ms (0 to 0.05 s)")
        self.servo_lag_s = float(servo_lag_s)
        """The physical arm's lag behind the target, s of motion time (:data:`SERVO_LAG_S`)."""
        if not -0.01 < clock_rate_error < 0.01:
            raise ValueError(f"clock_rate_error {clock_rate_error!r}: a controller's clock is off by ppm, not percent")
        self.clock_rate_error = float(clock_rate_error)
        """The controller's clock rate against the host's, minus one: RTDE ``timestamp`` advances (1 + this) s per
        host second (a real controller counts its own cycles)."""
        self.model = model
        self.time_scale = float(time_scale)
        self.version = version
        self.cycle_s = CB3_CYCLE_S if version[0] < 5 else E_SERIES_CYCLE_S
        """The controller's cycle, s (:data:`CB3_CYCLE_S` for software 3, else :data:`E_SERIES_CYCLE_S`)."""
        self.mount = mount
        self.serial_number = serial_number
        if not encoder_noise_rad >= 0.0:
            raise ValueError(f"encoder_noise_rad {encoder_noise_rad!r}: must be >= 0")
        self.encoder_noise_rad = float(encoder_noise_rad)
        self._encoder_rng = np.random.default_rng(seed)
        self.start_s = time.monotonic()
        self._last_step_s = self.start_s
        self.q = np.array(initial_q if initial_q is not None else [0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0], dtype=float)
        if not within_joint_limits(model, self.q):
            raise ValueError(f"initial joint angles {self.q.tolist()} are outside the {model.name} joint limits")
        self.qd = np.zeros(6)
        self.qdd = np.zeros(6)
        self.qdd_switch_in_s = np.full(3, np.inf)  # motion time until each later change of q̈, and q̈ after each
        self.qdd_next = np.zeros((3, 6))
        self._rest_arrays: tuple[np.ndarray, ...] | None = None
        """(q̇, q̈, q̈ after each switch, switch times) as :meth:`_at_rest` set them, while they stay unchanged."""
        self.qdd_switched_at_s = -np.inf  # clock time of the last change of q̈, and q̈ before it
        self.qdd_before = np.zeros(6)
        self.tcp_offset = np.zeros(6)
        self.payload_kg, self.payload_cog, self.payload_inertia = 0.0, np.zeros(3), np.zeros(6)
        self.gravity_m_s2 = tuple(-9.82 * np.array(mount_of(mount).down_base))  # floor (0, 0, 9.82)
        """set_gravity's vector: the acceleration away from the earth's centre, base frame (the installation's)."""
        self.robot_mode = ROBOT_MODE_RUNNING
        self.safety_mode = SAFETY_NORMAL
        self.estop_pressed = False
        self.popup: str | None = None
        self.runtime_state = RUNTIME_STOPPED
        self.loaded_program: str | None = None
        self.speed_slider = 1.0
        self.in_int = [0] * REGISTER_COUNT
        self.in_dbl = [0.0] * REGISTER_COUNT
        self.out_int = [0] * REGISTER_COUNT
        self.out_dbl = [0.0] * REGISTER_COUNT
        self.in_bits = [0, 0]
        self.out_bits = [0, 0]
        self.input_seq = 0
        self._last_realtime_seq = -1
        self.last_input_double_count = 0
        # script emulation
        self.script: ScriptProgram | None = None
        self._pending_script: tuple[float, ScriptProgram] | None = None
        self._executing = False
        self._job: tuple[str, float] | None = None  # ("motion", 0) wait for rest; ("until", t) wait for time
        self._async_op_id = 0
        self._async_counter = 0
        # motion
        self.motion: Motion | None = None
        self.motion_t = 0.0
        self._motion_started_s = 0.0
        self._motion_fresh = False
        """A move started since the last cycle: its first cycle is at motion time 0."""
        self._motion_number = 0
        self._motion_finished_s = self.start_s
        self._path_queue: list[tuple[str, np.ndarray, float, float, float]] = []
        self._path_total = 0
        self.tick_seq = 0
        self.published_seq = 0  # the newest tick every streaming client has been sent (set by the server)
        self._final_state_seq = 0
        self.move_count = 0
        self.commands: list[dict] = []
        self.faults: list[Fault] = []
        self.events: list[dict] = []
        self.stream_period_s = self.cycle_s  # longest period among streaming clients; set by the server
        self.on_network_fault = None  # callable(kind) installed by the server
        self._pose_cache: dict[tuple[bytes, bytes], tuple[np.ndarray, np.ndarray]] = {}
        """(flange pose, TCP pose) by (q, TCP offset): the target's and the lagging arm's, both asked each tick."""
        self._rest_accelerometer: tuple[tuple[bytes, str], np.ndarray] | None = None
        """((q, mount), the accelerometer's reading at rest there): asked each tick while the arm stands still."""
        self.tcp_speed = np.zeros(6)
        self.tool_motion_outputs = True
        """Compute actual_TCP_speed and actual_tool_accelerometer each tick (the server clears it while no client's
        output recipe asks for them: ~0.1 ms a tick while moving)."""
        self.external_ft = ExternalFTInput()

    # ------------------------------------------------------------------ geometry
    def controller_time_s(self, now: float | None = None) -> float:
        """The controller's clock (RTDE ``timestamp``, s since start) at host time ``now`` (``time.monotonic``)."""
        return ((time.monotonic() if now is None else now) - self.start_s) * (1.0 + self.clock_rate_error)

    def flange_pose(self) -> np.ndarray:
        return flange_pose(self.model, self.q)

    def tcp_pose_for(self, q: np.ndarray, tcp: np.ndarray, base_T_flange: np.ndarray | None = None) -> np.ndarray:
        """Pose of ``base_T_flange(q) @ flange_T_tcp`` as [x, y, z, rx, ry, rz] (``base_T_flange``: q's, if known)."""
        if not np.any(tcp):
            return flange_pose(self.model, q) if base_T_flange is None else pose_of_transform(base_T_flange)
        if base_T_flange is None:
            base_T_flange = forward_kinematics(self.model, q)
        flange_T_tcp = np.eye(4)
        flange_T_tcp[:3, :3] = rotation_from_rotvec(tcp[3:6])
        flange_T_tcp[:3, 3] = tcp[:3]
        base_T_tcp = base_T_flange @ flange_T_tcp
        return np.concatenate([base_T_tcp[:3, 3], rotvec_from_rotation(base_T_tcp[:3, :3])])

    def tcp_pose(self) -> np.ndarray:
        return self.tcp_pose_for(self.q, self.tcp_offset)

    # ------------------------------------------------------------------ modes
    def safety_status_bits(self) -> int:
        if self.safety_mode == SAFETY_PROTECTIVE_STOP:
            return (1 << 2) | (1 << 10)
        if self.safety_mode == SAFETY_ROBOT_EMERGENCY_STOP or self.estop_pressed:
            return (1 << 6) | (1 << 7) | (1 << 10)
        return 1 << 0

    def robot_status_bits(self) -> int:
        powered = self.robot_mode in (ROBOT_MODE_POWER_ON, ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING)
        return (1 if powered else 0) | (2 if self.runtime_state == RUNTIME_PLAYING else 0)

    def can_move(self) -> bool:
        return (self.robot_mode == ROBOT_MODE_RUNNING and self.safety_mode == SAFETY_NORMAL
                and not self.estop_pressed)

    def _event(self, what: str, **details) -> None:
        self.events.append({"time": self.controller_time_s(), "event": what, **details})

    # ------------------------------------------------------------------ inputs
    def apply_inputs(self, values: dict[str, object], double_count: int, arrival_s: float | None = None) -> None:
        """Apply a decoded client data package (name → value) that arrived at ``arrival_s`` (monotonic; now if
        not known)."""
        arrival_s = time.monotonic() if arrival_s is None else arrival_s
        with self.lock:
            for name, value in values.items():
                if name == "external_force_torque":
                    self.external_ft.receive(value, arrival_s, self.controller_time_s(arrival_s))
                    continue
                if name.startswith("input_int_register_"):
                    self.in_int[int(name.rsplit("_", 1)[1])] = int(value)
                elif name.startswith("input_double_register_"):
                    self.in_dbl[int(name.rsplit("_", 1)[1])] = float(value)
                elif name == "speed_slider_fraction" and values.get("speed_slider_mask", 0):
                    self.speed_slider = min(max(float(value), 0.0), 1.0)
                elif name == "input_bit_registers0_to_31":
                    self.in_bits[0] = int(value)
                elif name == "input_bit_registers32_to_63":
                    self.in_bits[1] = int(value)
            if any(name in values for name in ("input_int_register_0", "input_int_register_24")):
                self.last_input_double_count = double_count  # the recipe that carried the command
                self._event("command_package", cmd=int(values.get("input_int_register_0", values.get("input_int_register_24", -1))), doubles=double_count)
            self.input_seq += 1

    # ------------------------------------------------------------------ scripts
    def receive_script(self, text: str) -> None:
        """A program arrived on port 30003: it replaces the running one after a short 'compile' delay."""
        program = ScriptProgram.parse(text)
        with self.lock:
            self._event("script_received", name=program.name, control=program.is_control_script,
                        path_points=len(program.path))
            self._pending_script = (time.monotonic() + SCRIPT_COMPILE_DELAY_S, program)

    def _start_script(self, program: ScriptProgram) -> None:
        self._halt_motion()
        if not program.is_control_script:
            for register, value in program.output_writes:
                if 0 <= register < REGISTER_COUNT:
                    self.out_int[register] = value
            self.script = None
            self.runtime_state = RUNTIME_STOPPED
            return
        if not self.can_move():
            self.popup = "Cannot start program: the robot is not ready (power on, release brakes, clear stops)"
            self._event("script_refused", reason=self.popup)
            return
        self.script = program
        off = program.int_offset
        self._executing = False
        self._job = None
        self._write_async(running=False, progress=0)
        self.out_int[off] = 1
        self.runtime_state = RUNTIME_PLAYING
        self._event("script_started", offset=off)

    def stop_program(self, reason: str) -> None:
        """Stop the running program (UR Dashboard Server ``stop``, pendant stop, script end)."""
        with self.lock:
            if self.runtime_state == RUNTIME_PLAYING:
                self._event("program_stopped", reason=reason)
            self.script = None
            self._job = None
            self.runtime_state = RUNTIME_STOPPED
            if self.motion is not None:
                self._begin_stop(4.0)

    # ------------------------------------------------------------------ faults
    def inject(self, fault: Fault) -> None:
        with self.lock:
            fault.created_s = time.monotonic()
            if fault.trigger in ("move_after", "move_fraction") and fault.move is None:
                fault.move = self.move_count + 1
            if fault.trigger == "now":
                self._fire(fault)
            else:
                self.faults.append(fault)

    def _fire(self, fault: Fault) -> None:
        self._event("fault", kind=fault.kind)
        if fault.kind == "protective_stop":
            self.safety_mode = SAFETY_PROTECTIVE_STOP
            self.popup = "Protective stop: C153A1 (simulated)"
            self._halt_motion()
        elif fault.kind == "emergency_stop":
            self.estop_pressed = True
            self.safety_mode = SAFETY_ROBOT_EMERGENCY_STOP
            self.robot_mode = ROBOT_MODE_POWER_OFF
            self.popup = "Emergency stop: the robot emergency stop button is pressed (simulated)"
            self._halt_motion()
            self.script, self._job, self.runtime_state = None, None, RUNTIME_STOPPED
        elif fault.kind == "program_stop":
            self.stop_program("program stopped on the teach pendant (simulated)")
        elif fault.kind in ("drop", "freeze"):
            if self.on_network_fault is not None:
                self.on_network_fault(fault.kind)
        else:
            raise ValueError(f"unknown fault kind {fault.kind!r}")

    def release_emergency_stop(self) -> None:
        with self.lock:
            self.estop_pressed = False
            if self.safety_mode == SAFETY_ROBOT_EMERGENCY_STOP:
                self.safety_mode = SAFETY_NORMAL
            self._event("emergency_stop_released")

    def unlock_protective_stop(self) -> bool:
        with self.lock:
            if self.safety_mode != SAFETY_PROTECTIVE_STOP:
                return False
            self.safety_mode = SAFETY_NORMAL
            self.popup = None
            self._event("protective_stop_unlocked")
            return True

    # ------------------------------------------------------------------ motion
    def _halt_motion(self) -> None:
        """Stop dead (safety stop): the arm stays where it is."""
        if self.motion is not None:
            self._event("motion_halted", move=self._motion_number)
        self.motion = None
        self._path_queue.clear()
        self._at_rest()
        self._write_async(running=False, progress=0)
        if self._job is not None:
            self._job = None
            self._executing = True  # the aborted command is not re-run; the client's clear re-arms

    def _record(self, kind: str, target, speed: float, acceleration: float, asynchronous: bool, accepted: bool,
                reason: str = "", source: str = "rtde") -> dict:
        entry = {"index": len(self.commands) + 1, "kind": kind,
                 "target": [float(v) for v in target] if target is not None else None,
                 "speed": float(speed), "acceleration": float(acceleration), "async": bool(asynchronous),
                 "time": self.controller_time_s(), "accepted": accepted, "reason": reason, "source": source,
                 "move": None}
        self.commands.append(entry)
        return entry

    def _start_move(self, kind: str, target: np.ndarray, speed: float, acceleration: float, asynchronous: bool,
                    source: str = "rtde") -> bool:
        target = np.asarray(target, dtype=float)
        reason = ""
        if target.shape != (6,) or not np.all(np.isfinite(target)):
            reason = "target is not 6 finite numbers"
        elif not (math.isfinite(speed) and math.isfinite(acceleration)) or speed <= 0 or acceleration <= 0:
            reason = "speed and acceleration must be > 0"
        elif not self.can_move():
            reason = "robot cannot move (not running or a safety stop is active)"
        elif kind == "movej" and not within_joint_limits(self.model, target):
            reason = "joint position limit violated by the target"
        entry = self._record(kind, target if target.size == 6 else None, speed, acceleration, asynchronous,
                             not reason, reason, source)
        if reason:
            self._event("move_rejected", reason=reason)
            if "limit" in reason:
                self._fire(Fault("protective_stop"))
            return False
        self.move_count += 1
        entry["move"] = self.move_count
        if kind == "movej":
            self.motion = JointMove(self.model, self.q, target, speed, acceleration)
        else:
            self.motion = LinearMove(self.model, self.q, target, speed, acceleration)
        self.motion_t = 0.0
        self._motion_fresh = True
        self._motion_number = self.move_count
        self._motion_started_s = time.monotonic()
        return True

    def _begin_stop(self, deceleration: float) -> None:
        if self.motion is not None:
            self.motion = self.motion.stopping(self.motion_t, max(deceleration, 1e-6))
            self.motion_t = 0.0
        self._path_queue.clear()

    def _at_rest(self) -> None:
        rest = self._rest_arrays
        if (rest is not None and self.qd is rest[0] and self.qdd is rest[1] and self.qdd_next is rest[2]
                and self.qdd_switch_in_s is rest[3]):
            return  # at rest since the last tick (these arrays are replaced, never changed in place)
        if any_nonzero(self.qdd):  # the motion ended (or stopped) since the last tick: q̈ changes to zero now
            self.qdd_switched_at_s, self.qdd_before = self._last_step_s, self.qdd
        self.qd, self.qdd, self.qdd_next, self.qdd_switch_in_s = np.zeros(6), np.zeros(6), np.zeros((3, 6)), np.full(3, np.inf)
        self._rest_arrays = (self.qd, self.qdd, self.qdd_next, self.qdd_switch_in_s)

    def _resting(self) -> bool:
        """Whether q̇ is :meth:`_at_rest`'s zeros (unchanged since)."""
        return self._rest_arrays is not None and self.qd is self._rest_arrays[0]

    def motion_time_scale(self) -> float:
        """Motion seconds per clock second now (the time scale times the speed slider; 0 = instant moves)."""
        return self.time_scale * self.speed_slider if self.time_scale > 0 else 0.0

    def _advance_motion(self, now: float, dt: float) -> None:
        motion = self.motion
        if motion is None:
            self._at_rest()
            return
        fresh, self._motion_fresh = self._motion_fresh, False
        if self.time_scale <= 0:
            t = motion.duration_s
        elif fresh:  # a move starts at the cycle after its command, from rest: its q̈ switches now, not a cycle ago
            t = 0.0  # (a sensor rendering the arm a servo lag behind has already shown rest up to now − lag: a start
            # dated a CB3 cycle back, 8 ms > the lag, would be one it never showed)
        else:
            t = self.motion_t + dt * self.time_scale * self.speed_slider
        fired = None
        for fault in list(self.faults):
            if fault.move != self._motion_number or fault.trigger not in ("move_after", "move_fraction"):
                continue
            if fault.trigger == "move_fraction":
                t_fault = fault.value * motion.duration_s
                if t >= t_fault:
                    t = t_fault
                    fired = fault
                    break
            elif now - self._motion_started_s >= fault.value:
                fired = fault
                break
        self.motion_t = t
        sample = motion.sample(t)
        if sample is None or not within_joint_limits(self.model, sample[0]):
            self._event("limit_reached", move=self._motion_number)
            self._fire(Fault("protective_stop"))
            return
        qd_before, dt_motion = self.qd, dt * self.motion_time_scale()
        qdd_before, switch_in_s = self.qdd, float(self.qdd_switch_in_s[0])
        self.q, self.qd = sample
        acceleration = motion.acceleration(t)
        if acceleration is None:  # moveL: no closed form; differentiate q̇
            self.qdd = (self.qd - qd_before) / dt_motion if dt_motion > 0 else np.zeros(6)
            self.qdd_switch_in_s, self.qdd_next = np.full(3, np.inf), np.zeros((3, 6))
        else:
            self.qdd, self.qdd_switch_in_s, self.qdd_next = acceleration
            if not (self.qdd == qdd_before).all():  # q̈ changed since the last tick: when, exactly
                scale = self.motion_time_scale()
                since_s = (dt_motion if fresh else min(switch_in_s, dt_motion) if np.isfinite(switch_in_s)
                           else 0.0)  # (0: a stop's deceleration, from the last cycle)
                self.qdd_switched_at_s = now - (dt_motion - since_s) / scale if scale > 0 else now
                self.qdd_before = qdd_before
        if fired is not None:
            self.faults.remove(fired)
            self._fire(fired)
            return
        if motion.done(t):
            self._at_rest()
            self.motion = None
            self._motion_finished_s = now
            if self._path_queue:
                self._next_path_point(now)
            else:
                self._write_async(running=False, progress=0)

    def _next_path_point(self, now: float) -> None:
        index = self._path_total - len(self._path_queue)
        kind, values, acceleration, speed, _blend = self._path_queue.pop(0)
        self._write_async(running=True, progress=index, new_operation=False)
        if not self._start_move(kind, values, speed, acceleration, True, source="path"):
            self._path_queue.clear()
            self._write_async(running=False, progress=0)

    # ------------------------------------------------------------------ control script
    def _write_async(self, running: bool, progress: int, new_operation: bool = False) -> None:
        if self.script is None:
            return
        if new_operation:
            self._async_op_id = (self._async_op_id + 1) % 128
        self._async_counter = (self._async_counter + 1) % 128
        word = (self._async_op_id << 24) | (self._async_counter << 16) | ((1 << 15) if running else 0) | (progress & 0x7FFF)
        self.out_int[self.script.int_offset + 2] = word

    def _settle_s(self) -> float:
        return max(MIN_SETTLE_S, 2.5 * self.stream_period_s)

    def _run_script(self, now: float) -> None:
        script = self.script
        if script is None or self.runtime_state != RUNTIME_PLAYING:
            return
        off = script.int_offset
        if self._job is not None:
            kind, until = self._job
            if kind == "motion" and self.motion is None and not self._path_queue:
                self._job = ("until", now + self._settle_s())
                self._final_state_seq = self.tick_seq  # this tick's snapshot holds the final state
            elif kind == "until" and now >= until and self.published_seq >= self._final_state_seq + 1:
                self._job = None
                self._executing = True
                self.out_int[off] = 2
                self._event("done", q=self.q.tolist())
            return
        cmd = self.in_int[off]
        if cmd == CMD_CLEAR:
            self._executing = False
            self.out_int[off] = 1
            return
        if cmd in REALTIME_COMMANDS:
            if self.input_seq != self._last_realtime_seq:
                self._last_realtime_seq = self.input_seq
                self._realtime_command(cmd, off)
            self.out_int[off] = 1
            return
        if self._executing:
            return
        if cmd == CMD_STOP_SCRIPT:
            self._event("script_stopped")
            self.script, self._job, self.runtime_state = None, None, RUNTIME_STOPPED
            return
        if not self.can_move() and cmd in (CMD_MOVEJ, CMD_MOVEJ_IK, CMD_MOVEL, CMD_MOVEL_FK, CMD_MOVE_PATH):
            self._record("movej" if cmd in (1, 2) else "movel", None, 0.0, 0.0, False, False, "safety stop active")
            self._executing = True
            return
        wait_for_motion = self._command(cmd, off)
        if wait_for_motion is None:  # refused with a safety stop: no 'done'; the client sees the stop bits
            self._executing = True
        elif wait_for_motion:
            self._job = ("motion", 0.0)
        else:
            self._executing = True
            self.out_int[off] = 2

    def _realtime_command(self, cmd: int, off: int) -> None:
        if cmd == CMD_GET_FLANGE_POSE:
            self.out_dbl[off:off + 6] = list(self.flange_pose())
        elif cmd in REALTIME_NAMES:
            values = self.in_dbl[off:off + 8]
            self._record(REALTIME_NAMES[cmd], values[:6], values[6] if len(values) > 6 else 0.0,
                         values[7] if len(values) > 7 else 0.0, True, False, "not simulated")

    def _command(self, cmd: int, off: int) -> bool | None:
        """Execute one regular command; return True when 'done' must wait for the arm to come to rest, False when
        it is done now, None when a move was refused with a safety stop (no 'done' is signalled)."""
        d = self.in_dbl
        asynchronous = bool(self.in_int[off + 1])
        if cmd in (CMD_MOVEJ, CMD_MOVEJ_IK, CMD_MOVEL, CMD_MOVEL_FK):
            target = np.array(d[off:off + 6])
            speed, acceleration = d[off + 6], d[off + 7]
            kind = "movej" if cmd in (CMD_MOVEJ, CMD_MOVEJ_IK) else "movel"
            if cmd == CMD_MOVEJ_IK:
                solved = joint_positions_for_pose(self.model, target, self.q)
                target = solved if solved is not None else np.full(6, np.nan)
            elif cmd == CMD_MOVEL_FK:
                target = flange_pose(self.model, target)
            started = self._start_move(kind, target, speed, acceleration, asynchronous)
            if started:
                self._write_async(running=True, progress=0, new_operation=True)
            elif not self.can_move():
                return None
            return started and not asynchronous
        if cmd == CMD_MOVE_PATH:
            asynchronous = bool(self.in_int[off + 1])
            self._path_queue = list(self.script.path)
            self._path_total = len(self._path_queue)
            if not self._path_queue:
                return False
            self._write_async(running=True, progress=0, new_operation=True)
            self._next_path_point(time.monotonic())
            return not asynchronous
        if cmd in (CMD_STOPJ, CMD_STOPL):
            deceleration = d[off]
            self._record("stopj" if cmd == CMD_STOPJ else "stopl", None, 0.0, deceleration, asynchronous, True)
            self._begin_stop(deceleration)
            return not asynchronous
        if cmd == CMD_IS_STEADY:
            steady = self.motion is None and float(np.max(np.abs(self.qd))) < STEADY_SPEED_RAD_S
            self.out_int[off + 1] = 1 if steady else 0
        elif cmd == CMD_FK_DEFAULT:
            self.out_dbl[off:off + 6] = list(self.tcp_pose())
        elif cmd == CMD_FK_ARGS:
            q = np.array(d[off:off + 6])
            tcp = np.array(d[off + 6:off + 12]) if self.last_input_double_count >= 12 else self.tcp_offset
            self.out_dbl[off:off + 6] = list(self.tcp_pose_for(q, tcp))
        elif cmd == CMD_GET_TCP_OFFSET:
            self.out_dbl[off:off + 6] = list(self.tcp_offset)
        elif cmd == CMD_SET_TCP:
            self.tcp_offset = np.array(d[off:off + 6])
            self._event("tcp_set", tcp=list(self.tcp_offset))
        elif cmd == CMD_SET_PAYLOAD:  # the control script keeps the current CoG when all three are 0
            cog = np.array(d[off + 1:off + 4])
            self.payload_kg = d[off]
            self.payload_cog = self.payload_cog if not np.any(cog) else cog
            self._event("set_payload", mass_kg=float(d[off]), cog_m=[float(v) for v in cog])
        elif cmd == CMD_SET_TARGET_PAYLOAD:
            cog, inertia = np.array(d[off + 1:off + 4]), np.array(d[off + 4:off + 10])
            applied = self.version[:2] >= SET_TARGET_PAYLOAD_SINCE
            if applied:
                self.payload_kg = d[off]
                self.payload_cog = self.payload_cog if not np.any(cog) else cog
                self.payload_inertia = inertia
            self._event("set_target_payload", mass_kg=float(d[off]), cog_m=[float(v) for v in cog],
                        inertia_kg_m2=[float(v) for v in inertia], applied=applied)
        elif cmd == CMD_SET_GRAVITY:
            self.gravity_m_s2 = tuple(float(v) for v in d[off:off + 3])
            self._event("set_gravity", gravity_m_s2=list(self.gravity_m_s2))
        elif cmd == CMD_PROTECTIVE_STOP:
            self._fire(Fault("protective_stop"))
        elif cmd in (CMD_FT_RTDE_INPUT_ENABLE, CMD_ENABLE_EXTERNAL_FT_SENSOR):
            self._external_ft_enable(cmd, off)
        elif cmd == CMD_SET_EXTERNAL_FORCE_TORQUE:
            # ur-rtde's control script has no branch for 55: it falls through to 'done' and nothing is applied
            self._event("unhandled_command", cmd=cmd)
        return False

    def _external_ft_enable(self, cmd: int, off: int) -> None:
        """ur-rtde's script branches 56/57: enable = int1, sensor_mass = dbl0, offset = dbl1..3, cog = dbl4..6."""
        function = "ft_rtde_input_enable" if cmd == CMD_FT_RTDE_INPUT_ENABLE else "enable_external_ft_sensor"
        if cmd == CMD_FT_RTDE_INPUT_ENABLE and tuple(self.version[:2]) < FT_RTDE_INPUT_ENABLE_SINCE:
            self._event("external_ft_not_called", function=function, reason="script line dropped below 5.9")
            return
        d, now = self.in_dbl, time.monotonic()
        self.external_ft.enable(function, self.in_int[off + 1] == 1, d[off], d[off + 1:off + 4], d[off + 4:off + 7],
                                self.controller_time_s(now), now)
        self._event("external_ft", function=function, enable=self.external_ft.enabled)

    # ------------------------------------------------------------------ tick
    def step(self, now: float | None = None) -> dict:
        """Advance the simulation to ``now`` and return the snapshot of output fields."""
        now = time.monotonic() if now is None else now
        with self.lock:
            self.tick_seq += 1
            dt = max(now - self._last_step_s, 0.0)
            self._last_step_s = now
            if self._pending_script is not None and now >= self._pending_script[0]:
                program = self._pending_script[1]
                self._pending_script = None
                self._start_script(program)
            for fault in list(self.faults):
                if fault.trigger == "after" and now - fault.created_s >= fault.value:
                    self.faults.remove(fault)
                    self._fire(fault)
            self._advance_motion(now, dt)
            self._run_script(now)
            if self.external_ft.watchdog(now, self.controller_time_s(now)):
                self.external_ft_watchdog_pause()
            return self.snapshot(now, dt)

    def external_ft_watchdog_pause(self) -> None:
        """UR's default watchdog while the external F/T input is enabled: the program pauses (called locked)."""
        self._event("external_ft_watchdog", reason="no external_force_torque input for 0.1 s")
        if self.runtime_state == RUNTIME_PLAYING:
            self._halt_motion()
            self.runtime_state = RUNTIME_PAUSED

    def _poses(self, q: np.ndarray | None = None, base_T_flange: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """(flange pose, TCP pose) of ``q`` (default the target's), cached while q and the TCP offset do not
        change. ``base_T_flange``: q's, if the caller has it (:func:`flange_motion`'s frames, which are
        :func:`forward_kinematics`'s: the same products in the same order)."""
        q = self.q if q is None else q
        key = (q.tobytes(), self.tcp_offset.tobytes())
        poses = self._pose_cache.get(key)
        if poses is None:
            if len(self._pose_cache) >= 4:
                self._pose_cache.clear()
            if base_T_flange is None:
                base_T_flange = forward_kinematics(self.model, q)
            flange = pose_of_transform(base_T_flange)
            tcp = self.tcp_pose_for(q, self.tcp_offset, base_T_flange) if any_nonzero(self.tcp_offset) else flange
            poses = self._pose_cache[key] = (flange, tcp)
        return poses

    def actual_joints(self, now: float, state: JointState | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, q̇, q̈) of the physical arm at ``now``: the target's :attr:`servo_lag_s` of motion time ago (the
        profile followed back exactly, :meth:`tests.fakes.world.JointState.at`); the target itself without a lag,
        with instant moves, or at rest. ``state``: :meth:`joint_state` at ``now``, if the caller has it."""
        if self.servo_lag_s <= 0.0 or self.motion_time_scale() <= 0.0:
            return self.q, self.qd, self.qdd
        state = self.joint_state(now) if state is None else state
        if state.at_rest:
            return self.q, self.qd, self.qdd
        return state.at_time(now)

    def tool_motion(self, joints: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Return (TCP speed [v (m/s), ω (rad/s)] in the base frame, the tool accelerometer (m/s², flange frame)).

        Both from the joint state (q, q̇, q̈) of the physical arm (``joints``, default the target's), exactly:
        v_tcp = v_E + ω × (base_R_flange t), and the accelerometer, at the flange origin, reads the specific force
        base_R_flangeᵀ (a_E − g) (+g up at rest, as an accelerometer does)."""
        gravity = np.array(mount_gravity_m_s2(self.mount))
        q, qd, qdd = (self.q, self.qd, self.qdd) if joints is None else joints
        if not (any_nonzero(qd) or any_nonzero(qdd)):
            key = (q.tobytes(), self.mount)  # at rest: the accelerometer once per pose
            if self._rest_accelerometer is None or self._rest_accelerometer[0] != key:
                base_R_flange = rotation_from_rotvec(self._poses(q)[0][3:6])
                self._rest_accelerometer = (key, base_R_flange.T @ -gravity)
            return np.zeros(6), self._rest_accelerometer[1].copy()
        return self._tool_motion_of(flange_motion(self.model, q, qd, qdd), gravity)

    def _tool_motion_of(self, motion: FlangeMotion, gravity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`tool_motion` of the first sample of a moving arm's :class:`FlangeMotion`."""
        base_R_flange, w = motion.base_R_flange[0], motion.angular_velocity_rad_s[0]
        tcp_linear = motion.velocity_m_s[0] + cross3(w.tolist(), (base_R_flange @ self.tcp_offset[:3]).tolist())
        return np.concatenate([tcp_linear, w]), base_R_flange.T @ (motion.acceleration_m_s2[0] - gravity)

    def joint_state(self, now: float) -> JointState:
        """The joint state at ``now`` for the simulated sensor (see :class:`tests.fakes.world.JointState`): the
        target's, stamped :attr:`servo_lag_s` (of motion time) later, so that the sensor feels the physical arm."""
        scale = self.motion_time_scale()
        stamp_s = now + self.servo_lag_s / scale if scale > 0.0 else now
        return JointState(stamp_s, scale, self.q.copy(), self.qd.copy(), self.qdd.copy(),
                          self.qdd_switch_in_s.copy(), self.qdd_next.copy(),
                          max(now - self.qdd_switched_at_s, 0.0) * scale, self.qdd_before.copy())

    def _tick_kinematics(self, joints: tuple[np.ndarray, np.ndarray, np.ndarray]
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(flange pose, TCP pose, target TCP pose, tool accelerometer) of a tick whose physical arm is at ``joints``;
        sets :attr:`tcp_speed`."""
        lagging = joints[0] is not self.q
        if any_nonzero(joints[1]) or any_nonzero(joints[2]):
            # moving: one kinematics call for the frames of both poses (the arm's, the target's) and the arm's motion
            if self.tool_motion_outputs:
                motion = flange_motion(self.model, *((np.array([actual, target]) if lagging else actual)
                                                     for actual, target in zip(joints, (self.q, self.qd, self.qdd))))
                frames = motion.base_T_flange
                self.tcp_speed, accelerometer = self._tool_motion_of(motion, np.array(mount_gravity_m_s2(self.mount)))
            else:
                frames = dh_frames(self.model, np.array([joints[0], self.q]) if lagging else joints[0][None])[:, 6]
                self.tcp_speed, accelerometer = np.zeros(6), np.zeros(3)
            target_tcp = self._poses(self.q, frames[1])[1] if lagging else None
            flange, tcp = self._poses(joints[0], frames[0])
        else:
            target_tcp = self._poses()[1] if lagging else None
            flange, tcp = self._poses(joints[0])
            if self.tool_motion_outputs:
                self.tcp_speed, accelerometer = self.tool_motion(joints)
            else:
                self.tcp_speed, accelerometer = np.zeros(6), np.zeros(3)
        if target_tcp is None:
            target_tcp = tcp
        return flange, tcp, target_tcp, accelerometer

    def snapshot(self, now: float, dt: float) -> dict:
        state = self.joint_state(now)
        joints = self.actual_joints(now, state)
        flange, tcp, target_tcp, accelerometer = self._tick_kinematics(joints)
        q, qd, qdd = tuple(self.q.tolist()), tuple(self.qd.tolist()), tuple(self.qdd.tolist())
        actual_q, actual_qd = tuple(joints[0].tolist()), tuple(joints[1].tolist())
        if self.encoder_noise_rad > 0.0:  # the encoders' jitter: reported angles only
            actual_q = tuple((joints[0] + self._encoder_rng.normal(0.0, self.encoder_noise_rad, 6)).tolist())
        moving = self.motion is not None
        running = self.robot_mode == ROBOT_MODE_RUNNING
        joint_mode = 253 if running else (255 if self.robot_mode == ROBOT_MODE_IDLE else 239)
        gravity = mount_gravity_m_s2(self.mount)
        safety_ok = self.safety_mode == SAFETY_NORMAL
        tcp_force = (0.0,) * 6  # the built-in sensor is not simulated
        if self.external_ft.enabled:
            tcp_force = self.external_ft.tcp_force(rotation_from_rotvec(flange[3:6]), self.tcp_offset[:3],
                                                   self.payload_kg, self.payload_cog, np.array(gravity))
        fields = {
            "timestamp": self.controller_time_s(now),
            "actual_q": actual_q, "target_q": q, "actual_qd": actual_qd, "target_qd": qd, "target_qdd": qdd,
            "actual_TCP_pose": tuple(tcp.tolist()), "target_TCP_pose": tuple(target_tcp.tolist()),
            "actual_TCP_force": tcp_force,
            "actual_TCP_speed": tuple(self.tcp_speed.tolist()), "target_TCP_speed": tuple(self.tcp_speed.tolist()),
            "tcp_offset": tuple(self.tcp_offset.tolist()),
            "joint_temperatures": (31.0, 32.0, 33.0, 34.0, 35.0, 36.0),
            "actual_execution_time": 0.2, "robot_mode": int(self.robot_mode), "safety_mode": int(self.safety_mode),
            "safety_status": int(self.safety_mode),
            "joint_mode": (joint_mode,) * 6, "actual_tool_accelerometer": tuple(accelerometer.tolist()),
            "speed_scaling": (1.0 if safety_ok and running else 0.0),
            "speed_scaling_combined": (self.speed_slider if safety_ok and running else 0.0),
            "target_speed_fraction": self.speed_slider,
            "actual_main_voltage": 48.0, "actual_robot_voltage": 48.0 if running else 0.0,
            "actual_robot_current": 0.8 if moving else 0.3,
            "actual_joint_voltage": (47.8,) * 6 if running else (0.0,) * 6,
            "runtime_state": int(self.runtime_state), "robot_status_bits": self.robot_status_bits(),
            "safety_status_bits": self.safety_status_bits(),
            "payload": float(self.payload_kg), "payload_cog": tuple(self.payload_cog.tolist()),
            "payload_inertia": tuple(self.payload_inertia.tolist()),
            "target_gravity": gravity,
        }
        return {"seq": self.tick_seq, "fields": fields, "out_int": list(self.out_int), "out_dbl": list(self.out_dbl),
                "in_int": list(self.in_int), "in_dbl": list(self.in_dbl),
                "out_bits": list(self.out_bits), "in_bits": list(self.in_bits),
                "joint_speed_norm": 0.0 if self._resting() else float(np.linalg.norm(self.qd)), "flange_pose": flange,
                "joint_state": state}

    # ------------------------------------------------------------------ control channel views
    def state_view(self) -> dict:
        with self.lock:
            return {
                "time": self.controller_time_s(), "model": self.model.name, "q": self.q.tolist(),
                "flange_pose": self.flange_pose().tolist(), "tcp_pose": self.tcp_pose().tolist(),
                "tcp_offset": self.tcp_offset.tolist(), "robot_mode": self.robot_mode,
                "safety_mode": self.safety_mode, "runtime_state": self.runtime_state,
                "estop_pressed": self.estop_pressed, "moving": self.motion is not None,
                "move_count": self.move_count, "motion_number": self._motion_number if self.motion else None,
                "time_scale": self.time_scale, "script_offset": self.script.int_offset if self.script else None,
                "pending_faults": len(self.faults), "popup": self.popup,
                "payload_kg": float(self.payload_kg), "payload_cog_m": self.payload_cog.tolist(),
                "payload_inertia_kg_m2": self.payload_inertia.tolist(), "gravity_m_s2": list(self.gravity_m_s2),
            }
