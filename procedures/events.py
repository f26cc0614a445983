"""What the procedures tell their subscribers (file writer, progress bar, Rerun dashboard, live readout).

The calibration procedure and the live monitor never call a writer or the dashboard directly: they emit these
records to a list of listeners (callables taking one event); the application decides who listens. A listener must not block and must not raise; the procedure
catches and logs listener errors so a broken viewer can never stop the robot mid-plan. Listeners should
ignore event types they do not know (new ones may be added). A listener may declare ``critical = True``
(the run-folder writer does): its error then stops the procedure, because data that cannot be recorded
must not be measured.
All poses are flange poses in the robot base frame [x, y, z (m), rx, ry, rz (rad)]; wrenches are
sensor-frame [Fx, Fy, Fz (N), Tx, Ty, Tz (N·m)]. Times named ``time_s`` are seconds on the host's monotonic clock
(``time.monotonic``, the clock of :attr:`drivers.sensor.WrenchBatch.time_s`).

Two families: the calibration's steps (:data:`ProcedureEvent`) and the sample stream (:data:`StreamEvent`: the
monitor emits all of them, the calibration procedure emits :class:`WrenchSamples` for every sensor read).
Stream events come at up to the sensor's read rate: a listener that does real work on them belongs behind a
:class:`procedures.delivery.BackgroundListener`.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from drivers.sensor import SensorHealth, WrenchBatch

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PlanReady:
    """The checked plan (or a motion's waypoints), in execution order; ``set_names[i]`` is a row of
    :data:`ftacq.posesets.POSE_SETS`."""

    poses: np.ndarray  # (N, 6)
    joint_targets_rad: np.ndarray  # (N, 6)
    labels: tuple[str, ...]
    set_names: tuple[str, ...]
    estimated_duration_s: float
    joint_travel_rad: float


@dataclass(frozen=True)
class StateChanged:
    """The procedure entered a state: "planning", "moving", "settling", "averaging", "holding" (a recorded motion
    holds still at a waypoint), "identifying", "validating", "done", "stopped" (planned stop, data kept), "failed"
    (fault, data kept)."""

    state: str
    index: int | None = None  # the pose index (execution order) the state refers to, if any
    message: str = ""
    label: str = ""  # the pose label the state refers to ("E15", "A01-revisit"), if any
    measured: int | None = None  # poses measured so far in this run, resumed ones included
    total: int | None = None  # poses the whole run measures (the plan + the drift-check revisit)


@dataclass(frozen=True)
class PoseMeasured:
    """One pose measured and recorded: the averaged wrench at a still pose."""

    index: int
    label: str
    set_name: str
    pose: np.ndarray  # (6,) actual flange pose when averaging
    joint_positions_rad: np.ndarray  # (6,)
    mean: np.ndarray  # (6,)
    std: np.ndarray  # (6,)
    count: int
    saturated: int
    lost: int
    t_start_s: float | None = None  # averaging window start, UNIX time, s
    t_end_s: float | None = None  # averaging window end, UNIX time, s


@dataclass(frozen=True)
class DriftChecked:
    """The first pose was measured again at the end: ``drift`` (6,) = revisit − first mean [N, N·m].

    At the same pose the gravity wrench is identical, so the difference is the sensor's bias drift over
    ``elapsed_s`` seconds. ``warning`` is set when the force or torque drift norm exceeds its threshold.
    """

    label: str
    drift: np.ndarray
    elapsed_s: float
    warning: str = ""


@dataclass(frozen=True)
class Identified:
    """Identification finished. ``residuals`` (N, 6) per identification pose; ``outliers`` their labels."""

    calibration: Any  # ftacq.calibration.Calibration
    labels: tuple[str, ...]
    residuals: np.ndarray
    outliers: tuple[str, ...] = ()


@dataclass(frozen=True)
class Validated:
    """Compensation errors (M, 6) on the held-out V poses (should be ≈ 0: no contact during calibration)."""

    labels: tuple[str, ...]
    errors: np.ndarray
    max_abs: np.ndarray = field(default_factory=lambda: np.zeros(6))  # (6,) per axis
    rms: np.ndarray = field(default_factory=lambda: np.zeros(6))  # (6,) per axis


ProcedureEvent = PlanReady | StateChanged | PoseMeasured | DriftChecked | Identified | Validated


# ------------------------------------------------------------------------------------------------ the sample stream


@dataclass(frozen=True)
class WrenchSamples:
    """Samples as the sensor delivered them, in time order (one read, or consecutive reads joined).

    ``compensated`` (N, 6) is the contact wrench after compensation (sensor frame), or None when it is not known
    (no calibration, no robot state). ``flange_pose`` (6,) and ``joint_positions_rad`` (6,) are the robot's latest
    state when the samples were read, or None without a robot. ``sample_flange_pose`` (N, 6), when known, is the
    flange pose at each sample's own time (what the live compensation used: procedures/flange_orientation.py).
    ``uncompensated`` says a compensator had these samples and no robot state of their time: they stay raw (a
    viewer must not compensate them with ``flange_pose``, a pose from another time). ``sample_time_s`` (N,), when
    known, is each sample's time on the host monotonic clock from the sensor's own clock
    (:class:`ftacq.timebase.SampleClock`; the record's ``sample_time_s``); ``batch.time_s`` is when it arrived.
    """

    batch: WrenchBatch
    compensated: np.ndarray | None = None
    flange_pose: np.ndarray | None = None
    joint_positions_rad: np.ndarray | None = None
    sample_flange_pose: np.ndarray | None = None
    uncompensated: bool = False
    sample_time_s: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.batch)

    @staticmethod
    def join(parts: "list[WrenchSamples]") -> "WrenchSamples":
        """Join consecutive parts that all have, or all lack, a compensated wrench; the robot state is the last's."""
        if len(parts) == 1:
            return parts[0]
        with_compensation = [part.compensated is not None for part in parts]
        if any(with_compensation) and not all(with_compensation):
            raise ValueError("cannot join samples with and without a compensated wrench")
        compensated = np.concatenate([part.compensated for part in parts]) if with_compensation[0] else None
        poses = [part.sample_flange_pose for part in parts if part.sample_flange_pose is not None]
        times = [part.sample_time_s for part in parts if part.sample_time_s is not None]
        return WrenchSamples(batch=WrenchBatch.concatenate([part.batch for part in parts]), compensated=compensated,
                             flange_pose=parts[-1].flange_pose, joint_positions_rad=parts[-1].joint_positions_rad,
                             sample_flange_pose=np.concatenate(poses) if len(poses) == len(parts) else None,
                             uncompensated=any(part.uncompensated for part in parts),
                             sample_time_s=np.concatenate(times) if len(times) == len(parts) else None)


@dataclass(frozen=True)
class RobotState:
    """The arm at ``time_s``: joint angles (6,) rad and the flange pose (6,) as the controller reports it."""

    time_s: float
    joint_positions_rad: np.ndarray
    flange_pose: np.ndarray


@dataclass(frozen=True)
class SensorStatus:
    """A snapshot of the stream's health at ``time_s``; ``dropped`` samples were not delivered to the background
    listeners so far (their queue was full: a slow viewer), never to the record; ``clock_uncertainty_s`` how well
    the samples' times on the host clock are known (s, :class:`ftacq.timebase.DeviceClock`; inf: not known,
    a sensor without its own clock)."""

    time_s: float
    health: SensorHealth
    dropped: int = 0
    clock_uncertainty_s: float = float("inf")


@dataclass(frozen=True)
class Notice:
    """A line for the operator: ``level`` "INFO", "WARN" or "ERROR"; ``source`` says who speaks ("monitor",
    "health", …); ``time_s`` None means now."""

    text: str
    level: str = "INFO"
    source: str = "monitor"
    time_s: float | None = None


@dataclass(frozen=True)
class BiasDrift:
    """The live drift tracker's estimate at ``time_s`` (sample clock, s): the biases' offset from the calibration
    file (6,) [N, N·m] and its 1σ, the drift rate (6,) [N/h, N·m/h], whether ``--auto-tare`` applies it, the rest
    windows used and refused (contact, innovation gate), and whether the at-rest warning stands
    (:mod:`procedures.bias_health`)."""

    time_s: float
    offset: np.ndarray
    sigma: np.ndarray
    rate_per_h: np.ndarray
    applied: bool
    accepted: int
    rejected_contact: int
    rejected_gate: int
    warning: bool


@dataclass(frozen=True)
class FedWrenches:
    """What ``ftacq bridge`` wrote to the controller's external F/T input since the previous event: ``time_s`` (N,)
    when each value was written, ``fed`` (N, 6) [N, N·m] in the frame the controller expects (tool-flange axes,
    about the measuring point: docs/bridge.md); ``cycles`` controller cycles passed, ``written`` of them fed;
    ``joint_positions_rad`` (N, 6) the arm's actual_q in the cycle each value answered (None: not known)."""

    time_s: np.ndarray
    fed: np.ndarray
    cycles: int
    written: int
    joint_positions_rad: np.ndarray | None = None


StreamEvent = WrenchSamples | RobotState | SensorStatus | Notice | BiasDrift | FedWrenches
Event = ProcedureEvent | StreamEvent
Listener = Callable[[Event], None]


def publish(listeners: Iterable[Listener], event: Event) -> None:
    """Give ``event`` to every listener in turn: an error is logged and the next listener gets it, unless the
    listener is ``critical`` (module docstring): then it is raised (the caller stops the robot)."""
    for listener in listeners:
        try:
            listener(event)
        except Exception:
            if getattr(listener, "critical", False):
                raise
            log.warning("listener %r failed on %s", listener, type(event).__name__, exc_info=True)
