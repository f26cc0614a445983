"""The simulated cell: a simulated UR controller (subprocess, RTDE on its own loopback address) and a simulated
ATI sensor (Net F/T on loopback, or a NETCANOEM board on python-can's virtual bus) whose wrench follows the
controller's flange pose through a known ground truth (:class:`tests.fakes.world.CellTruth`).

Used by the procedure's tests, ``ftacq calibrate --sim``, ``ftacq monitor --sim`` and the dashboard tests, as
``ophyd.sim.hw()`` builds a whole simulated beamline::

    with SimulatedCell(sensor="netft", time_scale=0.0) as cell:
        robot = URRobot(cell.robot_host, MotionLimits())     # real ur-rtde client, real RTDE bytes
        sensor = open_sensor(cell.sensor_url)                # real Net F/T or CAN driver
        ...
        cell.controller.inject("protective_stop", "move_fraction", 0.5, move=3)
        cell.controller.commands()                           # every motion command the controller executed

The controller publishes its flange pose into a :class:`~tests.fakes.world.SharedPose` (shared memory); the
sensor fake, running in this process (or in its own with ``sensor_process=True``), reads it there.

Every device keeps its own clock, as on a real cell (:class:`SimClocks`, docs/simulation.md "Simulated clocks"): the
Net F/T samples on a crystal a few ppm off the host's and sends in bursts with jitter, the controller stamps its
RTDE packages on its own clock and sends them with jitter. The defaults are modest and on, so every test of the
procedure, ``--sim`` and the benchmarks see them; ``SimClocks.ideal()`` turns them off. The CAN board's virtual bus only links buses in one
process, so the CAN driver must run in the process that built the cell.
"""

from __future__ import annotations

import contextlib
import os
import uuid
from dataclasses import dataclass, replace

import numpy as np

from ftacq.kinematics import ur_model
from tests.fakes.ur_simulator import ENCODER_NOISE_RAD, SERVO_LAG_S
from tests.fakes.world import CellTruth, SensorPhysics, SharedPose

SENSORS = ("netft", "can")
DEFAULT_SENSOR_RATE_HZ = 1000.0
WRONG_TOOL_EXTRA_MASS_KG = 0.2
"""The wrong-tool knob: a part of this mass left in the gripper at the validation poses ..."""
WRONG_TOOL_COM_SHIFT_M = (0.0, 0.0, 0.03)
"""... whose centre of mass is this far from the tool's (sensor frame), m."""


@dataclass(frozen=True)
class SimClocks:
    """The simulated devices' clocks and delivery (defaults: modest errors, on).

    Attributes:
        sensor_rate_error: the Net F/T's sample clock rate against the host's, minus one (+50e-6: 50 ppm fast;
            a real crystal is within ±100 ppm, ATI states its rates to ±0.5 %).
        sensor_burst_interval_s: mean time between the Net F/T's bursts of datagrams, s (0: each record when due).
        sensor_burst_jitter_s: a burst carries the records due up to a random delay in [0, this] before, s.
        sensor_max_backlog_s: the Net F/T skips records due longer ago than this (its sender descheduled on a
            loaded host): ``ft_sequence`` jumps, ``rdt_sequence`` does not; None: a 4096-record backlog.
        controller_rate_error: the controller's clock (RTDE ``timestamp``) rate against the host's, minus one.
        controller_send_jitter_s: the controller's packages to receive-only clients leave up to this late, s.
    """

    sensor_rate_error: float = 50e-6
    sensor_burst_interval_s: float = 0.002
    sensor_burst_jitter_s: float = 0.001
    sensor_max_backlog_s: float | None = 0.1
    controller_rate_error: float = -30e-6
    controller_send_jitter_s: float = 0.0003

    @classmethod
    def ideal(cls) -> "SimClocks":
        """Every device on the host's clock, records sent when due, packages sent at once (the old fakes)."""
        return cls(0.0, 0.0, 0.0, None, 0.0, 0.0)

    def box_settings(self) -> dict:
        """Keyword arguments of :class:`tests.fakes.netft.FakeNetFT` for the sensor's clock and delivery."""
        return {"clock_rate_error": self.sensor_rate_error, "burst_interval_s": self.sensor_burst_interval_s,
                "burst_jitter_s": self.sensor_burst_jitter_s, "max_backlog_s": self.sensor_max_backlog_s}

    def box_args(self) -> list[str]:
        """The same as ``python -m tests.fakes.netft`` options."""
        args = [f"--clock-rate-error={self.sensor_rate_error!r}", f"--burst-interval-s={self.sensor_burst_interval_s!r}",
                f"--burst-jitter-s={self.sensor_burst_jitter_s!r}"]
        if self.sensor_max_backlog_s is not None:
            args.append(f"--max-backlog-s={self.sensor_max_backlog_s!r}")
        return args

    def controller_args(self) -> list[str]:
        """``python -m tests.fakes.ur_controller`` options for the controller's clock and send jitter."""
        return [f"--clock-rate-error={self.controller_rate_error!r}", f"--send-jitter-s={self.controller_send_jitter_s!r}"]


class SimulatedCell:
    """A running simulated cell (context manager; :meth:`close` is safe twice).

    Args:
        truth: the ground truth (sensor rotation, biases, tool, base tilt, noise). With ``mount`` other than
            "floor" and a level truth, the truth's base tilt is set to the mount's (wall (0, 90°), ceiling (0, 180°)).
        sensor: "netft" (UDP RDT + TCP + HTTP on 127.0.0.1) or "can" (NETCANOEM on a virtual CAN channel).
        model: UR model of the controller; version: its software ("3.15.7.106331"; default the model's, see
            tests/fakes/ur_controller.py ``default_version``: a CB3 streams at 125 Hz, an e-Series at 500). mount: "floor", "wall", "ceiling" or a spec of ftacq.mounts (tilted:A,B, gravity:X,Y,Z).
        time_scale: controller speed factor (0 = moves complete at once, 1 = real time, 10 = ten times faster).
        rate_hz: the sensor's sample rate (Net F/T streaming rate, or CAN poll rate suggested in the URL).
        seed: seed of the sensor noise. initial_q: start joint angles (rad); default the plan's home.
        encoder_noise_rad: 1σ jitter of the joint angles the controller reports, rad; default
            :data:`tests.fakes.ur_simulator.ENCODER_NOISE_RAD` (as a real arm), 0 = exact.
        servo_lag_s: how far the physical arm (actual_q, actual_qd, the tool's physics) follows the controller's
            target, s; default :data:`tests.fakes.ur_simulator.SERVO_LAG_S` (as a real arm), 0 = none.
        realtime_priority: SCHED_FIFO priority of the controller process's threads and of the Net F/T's sending
            thread (0: normal scheduling; the controller then takes the environment's,
            :func:`tests.fakes.ur_process.default_realtime_priority`). Real devices keep their cycle whatever the
            computer does; on a loaded computer the simulated ones, at normal priority, stall for 100 ms and more.
        clocks: the devices' clocks and delivery (:class:`SimClocks`; default modest errors and bursts).
        sensor_process: run the simulated Net F/T in its own process (tests/fakes/netft_process.py), so that it
            keeps its pace whatever this process does; then :meth:`set_contact`, :meth:`swap_tool` and
            :attr:`physics` are not available (the physics lives in that process).
    """

    def __init__(self, truth: CellTruth | None = None, sensor: str = "netft", model: str = "UR5e",
                 mount: str = "floor", time_scale: float = 1.0, rate_hz: float = DEFAULT_SENSOR_RATE_HZ,
                 seed: int = 0, initial_q: np.ndarray | None = None,
                 encoder_noise_rad: float = ENCODER_NOISE_RAD, realtime_priority: int = 0,
                 servo_lag_s: float = SERVO_LAG_S,
                 clocks: SimClocks | None = None, sensor_process: bool = False, version: str | None = None) -> None:
        if sensor not in SENSORS:
            raise ValueError(f"sensor {sensor!r}: must be one of {', '.join(SENSORS)}")
        truth = truth or CellTruth()
        if mount != "floor" and tuple(truth.base_tilt_deg) == (0.0, 0.0):
            truth = truth.with_mount(mount)
        self.truth = truth
        self.sensor_kind = sensor
        self.model_name = model
        self.version = version
        self.mount = mount
        self.time_scale = float(time_scale)
        self.rate_hz = float(rate_hz)
        self.seed = seed
        self.realtime_priority = int(realtime_priority)
        self.clocks = SimClocks() if clocks is None else clocks
        if sensor_process and sensor != "netft":
            raise ValueError("sensor_process: only the simulated Net F/T runs in its own process")
        self.sensor_process = bool(sensor_process)
        if initial_q is None:
            from procedures.plan import home_configuration_rad

            initial_q = home_configuration_rad(mount)
        self.initial_q = np.asarray(initial_q, dtype=float)
        self.encoder_noise_rad = float(encoder_noise_rad)
        self.servo_lag_s = float(servo_lag_s)
        self.shared_pose: SharedPose | None = None
        self.physics: SensorPhysics | None = None
        self.controller = None
        self.netft = None
        self.can_board = None
        self.sensor_url = ""
        self._stack = contextlib.ExitStack()

    @property
    def robot_host(self) -> str:
        """The controller's loopback address (RTDE 30004, dashboard 29999, script 30003)."""
        return self.controller.host

    def start(self) -> "SimulatedCell":
        """Start the controller subprocess and the sensor fake; return self."""
        from tests.fakes.ur_process import URControllerProcess

        try:
            self.shared_pose = SharedPose(name=f"ftacq-{os.getpid()}-{uuid.uuid4().hex[:8]}", create=True)
            self._stack.callback(self._close_shared_pose)
            self.controller = URControllerProcess(model=self.model_name, time_scale=self.time_scale,
                                                  pose_shm=self.shared_pose.name, initial_q=self.initial_q,
                                                  mount=self.mount, extra_args=self._controller_args(),
                                                  realtime_priority=self.realtime_priority or None,
                                                  version=self.version)
            self.controller.start()
            self._stack.callback(self.controller.stop)
            if self.sensor_process:
                from tests.fakes.netft_process import NetFTProcess

                box_args = self.clocks.box_args()
                if self.realtime_priority:
                    box_args += ["--realtime-priority", str(self.realtime_priority)]
                self.netft = NetFTProcess(self.truth, self.shared_pose.name, self.model_name, self.rate_hz,
                                          self.seed, box_args)
                self.netft.start()
                self._stack.callback(self.netft.close)
                self.sensor_url = self.netft.url
                return self
            self.physics = SensorPhysics(self.truth, self.shared_pose, seed=self.seed, robot=ur_model(self.model_name),
                                         rate_hz=self.rate_hz)
            if self.sensor_kind == "netft":
                from tests.fakes.netft import FakeNetFT

                self.netft = FakeNetFT(self.physics, host="127.0.0.1", rate_hz=self.rate_hz,
                                       realtime_priority=self.realtime_priority, seed=self.seed,
                                       **self.clocks.box_settings())
                self.netft.start()
                self._stack.callback(self.netft.close)
                self.sensor_url = self.netft.url
            else:
                from tests.fakes.netcanoem import FakeNetCanOem

                channel = f"ftacq-sim-{uuid.uuid4().hex[:12]}"
                self.can_board = FakeNetCanOem(channel, self.physics)
                self._stack.callback(self.can_board.close)
                self.sensor_url = f"can://virtual/{channel}?rate_hz={self.rate_hz:g}"
        except BaseException:
            self.close()
            raise
        return self

    def _controller_args(self) -> list[str]:
        """The controller's options beyond those URControllerProcess takes: the encoder jitter (seeded by ``seed``)."""
        return ["--seed", str(self.seed), "--encoder-noise-rad", repr(self.encoder_noise_rad),
                "--servo-lag-s", repr(self.servo_lag_s),
                *self.clocks.controller_args()]

    def _close_shared_pose(self) -> None:
        # The controller subprocess attached to the block; Python < 3.13's resource tracker of that process may
        # already have unlinked it when the process ended (bpo-39959). Nothing is left to release then.
        name = self.shared_pose.name
        try:
            self.shared_pose.close()
        except FileNotFoundError:
            from multiprocessing import resource_tracker

            with contextlib.suppress(Exception):  # this process's tracker would warn about a "leak" at exit
                resource_tracker.unregister("/" + name.lstrip("/"), "shared_memory")

    def close(self) -> None:
        """Stop the sensor fake and the controller, release the shared memory. Safe to call twice."""
        self._stack.close()

    def __enter__(self) -> "SimulatedCell":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def set_contact(self, wrench: np.ndarray) -> None:
        """Add a contact wrench (6,) [N, N·m] in the sensor frame to every later sample (0 to remove)."""
        self.physics.contact_wrench = np.asarray(wrench, dtype=float).reshape(6)

    def swap_tool(self, mass_kg: float | None = None, center_of_mass_m=None) -> None:
        """Put another tool on the simulated sensor (None keeps the true value); ``swap_tool()`` restores it."""
        self.physics.set_tool(self.truth.mass_kg if mass_kg is None else mass_kg,
                              self.truth.center_of_mass_m if center_of_mass_m is None else center_of_mass_m)

    def wrong_tool_listener(self, plan, extra_mass_kg: float = WRONG_TOOL_EXTRA_MASS_KG,
                            com_shift_m=WRONG_TOOL_COM_SHIFT_M):
        """Return a procedure listener that measures the validation poses (set V) with a wrong tool: the true one
        plus a part left in the gripper (``extra_mass_kg`` whose centre of mass sits ``com_shift_m`` from the
        tool's, sensor frame). Every other pose sees the true tool. A right verdict is FAIL."""
        from procedures import events

        mass = self.truth.mass_kg + extra_mass_kg
        part_com = np.asarray(self.truth.center_of_mass_m) + np.asarray(com_shift_m, dtype=float)
        com = (self.truth.mass_kg * np.asarray(self.truth.center_of_mass_m) + extra_mass_kg * part_com) / mass

        def listener(event) -> None:
            if isinstance(event, events.StateChanged) and event.state == "moving" and event.index is not None:
                validation = plan.set_names[event.index] == "V" and not event.label.endswith("-revisit")
                self.swap_tool(mass, com) if validation else self.swap_tool()

        return listener

    def with_truth(self, **changes) -> CellTruth:
        """Return the truth with some fields changed (for building a second cell)."""
        return replace(self.truth, **changes)


__all__ = ["SimulatedCell", "SimClocks", "SENSORS", "fast_config", "plan_for", "run_calibration", "motion_problems"]


def fast_config(cell: SimulatedCell, random_count: int = 6, validation_count: int = 4, **sampling):
    """Return a :class:`ftacq.app.config.CellConfig` for ``cell`` with a small pose set and short sampling windows
    (tests: A 24 + E ``random_count`` + V ``validation_count`` poses, 0.1 s averaging, no settle delay)."""
    from ftacq.app.config import config_from_dict

    values = {"settle_time_s": 0.0, "settle_window_s": 0.02, "average_time_s": 0.1, "settle_timeout_s": 5.0,
              "sensor_timeout_s": 1.0}
    values.update(sampling)
    return config_from_dict({
        "robot": {"host": cell.robot_host, "model": cell.model_name, "mount": cell.mount, "move_timeout_s": 30.0},
        "sensor": {"url": cell.sensor_url},
        "poses": {"random_count": random_count, "validation_count": validation_count},
        "sampling": values,
    }, "<tests>")


def plan_for(cell: SimulatedCell, config):
    """The plan :func:`run_calibration` would make, from the controller's joint angles as the simulator holds them
    (they differ from a client's reading by the encoder noise only), so that a test can create its run folder
    first without a client connection of its own (ur-rtde's disconnects and destructors take 1.5 s)."""
    from procedures.plan import make_plan

    return make_plan(config.plan_settings(), np.asarray(cell.controller.state()["q"], dtype=float))


def run_calibration(cell: SimulatedCell, config, listeners=(), measured=None, plan=None, on_procedure=None):
    """Plan from the controller's current configuration and run the procedure in this process with the real
    UR and sensor drivers; return (plan, result). Listeners receive every event (add a RunFolderWriter to keep
    the data). ``on_procedure(procedure)`` is called before the run (e.g. to keep ``request_stop``)."""
    from drivers.robot import MotionLimits
    from drivers.sensor import open_sensor
    from drivers.ur import URRobot
    from procedures.calibration_procedure import CalibrationProcedure, ProcedureOptions
    from procedures.plan import make_plan

    settings = config.plan_settings()
    limits = MotionLimits(joint_speed_rad_s=settings.joint_speed_rad_s,
                          joint_acceleration_rad_s2=settings.joint_acceleration_rad_s2)
    with contextlib.ExitStack() as stack:
        robot = URRobot(config.robot.host, limits, model=settings.model)
        stack.callback(robot.close)
        robot.start()
        sensor = open_sensor(config.sensor.url)
        stack.callback(sensor.close)
        sensor.start()
        if plan is None:
            plan = make_plan(settings, robot.joint_positions())
        procedure = CalibrationProcedure(plan, robot, sensor, ProcedureOptions.from_config(config), listeners,
                                         measured)
        if on_procedure is not None:
            on_procedure(procedure)
        return plan, procedure.run()


def motion_problems(commands: list[dict], plan, limits) -> list[str]:
    """Return every recorded motion command that is not a moveJ to a plan target within the limits (stops are
    allowed: they only decelerate)."""
    targets = np.asarray(plan.joint_targets_rad)
    problems = []
    for command in commands:
        kind = command["kind"]
        if kind in ("stopj", "stopl"):
            if command["acceleration"] > limits.joint_acceleration_rad_s2 * 1.000001 and kind == "stopj":
                problems.append(f"command {command['index']}: stopj deceleration {command['acceleration']} above limit")
            continue
        if kind != "movej":
            problems.append(f"command {command['index']}: {kind} is not part of a calibration plan")
            continue
        target = np.asarray(command["target"], dtype=float)
        if not np.any(np.all(np.abs(targets - target) < 1e-9, axis=1)):
            problems.append(f"command {command['index']}: moveJ target {target.round(5).tolist()} is not in the plan")
        if command["speed"] > limits.joint_speed_rad_s * 1.000001:
            problems.append(f"command {command['index']}: speed {command['speed']} above {limits.joint_speed_rad_s}")
        if command["acceleration"] > limits.joint_acceleration_rad_s2 * 1.000001:
            problems.append(f"command {command['index']}: acceleration {command['acceleration']} above "
                            f"{limits.joint_acceleration_rad_s2}")
    return problems
