"""What the calibration procedure tells its subscribers (file writer, progress bar, Rerun dashboard).

The procedure never calls a writer or the dashboard directly: it emits these records to a list of
listeners (callables taking one event). A listener must not block and must not raise; the procedure
catches and logs listener errors so a broken viewer can never stop the robot mid-plan. Listeners should
ignore event types they do not know (new ones may be added). A listener may declare ``critical = True``
(the run-folder writer does): its error then stops the procedure, because data that cannot be recorded
must not be measured.
All poses are flange poses in the robot base frame [x, y, z (m), rx, ry, rz (rad)]; wrenches are
sensor-frame [Fx, Fy, Fz (N), Tx, Ty, Tz (N·m)].
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np


@dataclass(frozen=True)
class PlanReady:
    """The checked plan, in execution order. ``set_names[i]`` is "A" (special), "E" (random) or "V" (validation)."""

    poses: np.ndarray  # (N, 6)
    joint_targets_rad: np.ndarray  # (N, 6)
    labels: tuple[str, ...]
    set_names: tuple[str, ...]
    estimated_duration_s: float
    joint_travel_rad: float


@dataclass(frozen=True)
class StateChanged:
    """The procedure entered a state: "planning", "moving", "settling", "averaging", "identifying",
    "validating", "done", "stopped" (planned stop, data kept), "failed" (fault, data kept)."""

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
Listener = Callable[[ProcedureEvent], None]
