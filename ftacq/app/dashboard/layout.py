"""The dashboard's layout: timelines, entity paths, colours and sizes (declared once), and the Rerun blueprint.

Time is the sensor's clock: the ``sensor_time`` timeline holds :attr:`drivers.sensor.WrenchBatch.time_s`
(seconds on the host's monotonic clock, when each sample was received) less the run's start, so the axes read
seconds since the start; the arm, health, procedure events and log lines are stamped on the same clock. The
calibration's per-pose data also carries the ``pose`` timeline.

Entity paths::

    wrench/raw/force, wrench/raw/torque                    Scalars (N, 3): Fx Fy Fz [N], Tx Ty Tz [N·m]
    wrench/compensated/force, wrench/compensated/torque    the same after compensation (contact wrench)
    wrench/fed/force, wrench/fed/torque                    what ftacq bridge wrote to the controller
    world                                                  robot base frame B (z up, metres)
    world/robot/link1 … link6                              DH frame i: base_T_i (Transform3D, per time)
    world/robot/link1/shape … link6/shape                  the link drawn in its own frame (static)
    world/flange                                           base_T_flange (Transform3D, per time)
    world/flange/axes                                      the flange frame's axes (static)
    world/flange/sensor                                    flange_T_sensor (from the calibration) and its axes
    world/flange/sensor/contact_force                      the compensated contact force, sensor frame
    world/gravity                                          the tool's weight (base frame) at the flange
    world/labels                                           the two arrows' labels, placed clear of both arrows
    world/plan/<set>, world/plan/current                   the calibration plan, the pose being worked on
    robot/joints                                           joint angles [rad]
    health/…                                               sensor rate, lost samples, status word, drops
    calibration/measured/…, calibration/residuals/…        averaged wrench and residuals per pose
    log/…                                                  text log (monitor, calibration)
"""

from __future__ import annotations

from typing import Any

import rerun.blueprint as rrb

from ftacq.app.dashboard.sinks import APP_ID  # noqa: F401 - the recording's id, re-exported with the layout
from ftacq.channels import FORCE_AXES, TORQUE_AXES  # noqa: F401 - the series names, re-exported with the layout
from ftacq.posesets import POSE_SETS, UNKNOWN_SET_COLOUR_RGB

# ------------------------------------------------------------------------------------------------ timelines

SENSOR_TIMELINE = "sensor_time"
"""Duration timeline: seconds since the run's start (the dashboard's ``origin_s``) on the host monotonic clock, the
clock of ``WrenchBatch.time_s``."""
POSE_TIMELINE = "pose"
"""Sequence timeline: the calibration pose index (execution order)."""

# ------------------------------------------------------------------------------------------------ entity paths

RAW_FORCE = "wrench/raw/force"
RAW_TORQUE = "wrench/raw/torque"
COMPENSATED_FORCE = "wrench/compensated/force"
COMPENSATED_TORQUE = "wrench/compensated/torque"
WRENCH_PATHS = (RAW_FORCE, RAW_TORQUE, COMPENSATED_FORCE, COMPENSATED_TORQUE)
FED_FORCE = "wrench/fed/force"
FED_TORQUE = "wrench/fed/torque"
"""What ftacq bridge wrote to the controller (tool-flange axes, about the sensor's measuring point)."""

WORLD = "world"
BASE_AXES = "world/base"
ROBOT = "world/robot"
LINK_FRAMES = tuple(f"{ROBOT}/link{i}" for i in range(1, 7))
"""DH frames 1…6 of the arm, each with its per-time base_T_i."""
LINK_SHAPES = tuple(f"{frame}/shape" for frame in LINK_FRAMES)
"""Each link drawn once (static) in its own DH frame."""
FLANGE = "world/flange"
FLANGE_AXES = "world/flange/axes"
SENSOR = "world/flange/sensor"
CONTACT_FORCE = "world/flange/sensor/contact_force"
GRAVITY = "world/gravity"
LABELS = "world/labels"
PLAN = "world/plan"
CURRENT_POSE = "world/plan/current"
JOINT_ANGLES = "robot/joints"

HEALTH = "health"
HEALTH_RATE = "health/rate_hz"
HEALTH_COUNTS = "health/counts"
HEALTH_STATUS = "health/status_word"

MEASURED = "calibration/measured"
MEASURED_FORCE = "calibration/measured/force"
MEASURED_TORQUE = "calibration/measured/torque"
RESIDUAL_FORCE = "calibration/residuals/force"
RESIDUAL_TORQUE = "calibration/residuals/torque"
RESIDUAL_FORCE_NORM = "calibration/residual_norm/force"
RESIDUAL_TORQUE_NORM = "calibration/residual_norm/torque"
VALIDATION_FORCE_NORM = "calibration/validation_norm/force"

BIAS_DRIFT = "bias_drift"
BIAS_DRIFT_FORCE = "bias_drift/force"
BIAS_DRIFT_TORQUE = "bias_drift/torque"
"""The live tracker's bias offset from the calibration file (N, N·m) with ±1σ bands (ftacq monitor)."""
LOG = "log"
MONITOR_LOG = "log/monitor"
CALIBRATION_LOG = "log/calibration"
LOG_PATHS = {"monitor": MONITOR_LOG, "calibration": CALIBRATION_LOG}
"""Log entity of each :class:`procedures.events.Notice` source (others go to ``log/<source>``)."""

# ------------------------------------------------------------------------------------------------ styles

AXIS_COLORS = ((230, 57, 70), (42, 157, 90), (38, 103, 230))
"""x red, y green, z blue, for force and torque alike (RGB 0-255)."""
HEALTH_COUNT_NAMES = ("lost", "saturated", "status_errors", "dropped")
HEALTH_COUNT_COLORS = ((230, 57, 70), (240, 160, 30), (150, 60, 200), (120, 120, 120))
JOINT_NAMES = tuple(f"q{i}" for i in range(1, 7))
JOINT_COLORS = ((230, 57, 70), (240, 160, 30), (200, 200, 40), (42, 157, 90), (38, 103, 230), (150, 60, 200))
SET_COLORS = {name: kind.colour_rgb for name, kind in POSE_SETS.items()}
"""Plan colours by pose set (:data:`ftacq.posesets.POSE_SETS`: A blue, E orange, Q purple, V green, D red)."""
UNKNOWN_SET_COLOR = UNKNOWN_SET_COLOUR_RGB
LINK_COLOR = (190, 195, 205)
JOINT_COLOR = (60, 60, 70)
CONTACT_COLOR = (230, 57, 70)
GRAVITY_COLOR = (140, 70, 200)
LABEL_COLORS = (GRAVITY_COLOR, CONTACT_COLOR)
CURRENT_POSE_COLOR = (255, 255, 255)

FORCE_ARROW_SCALE_M_PER_N = 0.01
"""Length of force arrows in the 3-D view: 10 N draws 0.1 m."""
ARROW_RADIUS_M = 0.004
LABEL_RADIUS_M = 0.002
"""The labels' anchor points: small, the text is what shows."""
LABEL_CLEARANCE_M = 0.04
"""A label sits this far beyond its arrow's tip and at least this far from either arrow."""
LABEL_MIN_SEPARATION_M = 0.10
"""The two labels' anchors are at least this far apart."""
FRAME_AXIS_LENGTH_M = 0.08
PLAN_AXIS_LENGTH_M = 0.04
WRENCH_WINDOW_S = 10.0
"""The wrench plots follow the time cursor over the last this-many seconds."""
EYE_POSITION_M = (1.3, -1.8, 1.1)
EYE_TARGET_M = (0.05, -0.3, 0.3)
"""Initial camera of the 3-D view (base frame, m): in front of and above a floor-mounted arm."""


VIEWS = ("monitor", "calibration", "bridge")
"""The layouts :func:`blueprint` knows (the monitor's and the calibration's are one)."""


def blueprint(view: str = "monitor") -> rrb.Blueprint:
    """Return the dashboard layout of ``view`` (:data:`VIEWS`).

    monitor, calibration: four wrench plots left; the 3-D view and a tab strip (log, health, drift, joints, the
    calibration's bars) right. bridge: the wrench fed to the controller (force, torque) left; the 3-D view and the
    log and joints right (the bridge reads no raw or compensated stream for the viewer). Axis names and colours are
    fixed per entity by the recorder (static SeriesLines)."""
    if view not in VIEWS:
        raise ValueError(f"unknown dashboard view {view!r}: one of {', '.join(VIEWS)}")
    window = rrb.VisibleTimeRange(
        SENSOR_TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-WRENCH_WINDOW_S),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )

    def plot(origin: str, name: str) -> Any:
        return rrb.TimeSeriesView(origin=origin, name=name, time_ranges=window,
                                  plot_legend=rrb.PlotLegend(visible=True))

    robot = rrb.Spatial3DView(origin=WORLD, name="robot (base frame)", eye_controls=rrb.EyeControls3D(
        position=EYE_POSITION_M, look_target=EYE_TARGET_M, eye_up=(0.0, 0.0, 1.0)))
    panels = (rrb.TimePanel(state="collapsed", timeline=SENSOR_TIMELINE, play_state="following"),
              rrb.SelectionPanel(state="collapsed"), rrb.BlueprintPanel(state="collapsed"))
    if view == "bridge":
        return rrb.Blueprint(
            rrb.Horizontal(
                rrb.Vertical(plot(FED_FORCE, "fed to the controller: force [N]"),
                             plot(FED_TORQUE, "fed to the controller: torque [N·m]")),
                rrb.Vertical(robot, rrb.Tabs(rrb.TextLogView(origin=LOG, name="log"),
                                             rrb.TimeSeriesView(origin=JOINT_ANGLES, name="joints [rad]")),
                             row_shares=[3, 2]),
                column_shares=[1, 1],
            ),
            *panels,
        )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                plot(RAW_FORCE, "raw force [N]"),
                plot(RAW_TORQUE, "raw torque [N·m]"),
                plot(COMPENSATED_FORCE, "compensated force [N]"),
                plot(COMPENSATED_TORQUE, "compensated torque [N·m]"),
            ),
            rrb.Vertical(
                robot,
                rrb.Tabs(
                    rrb.TextLogView(origin=LOG, name="log"),
                    rrb.TimeSeriesView(origin=HEALTH, name="sensor health"),
                    rrb.TimeSeriesView(origin=BIAS_DRIFT, name="bias drift [N, N·m]"),
                    rrb.TimeSeriesView(origin=JOINT_ANGLES, name="joints [rad]"),
                    rrb.TimeSeriesView(origin=MEASURED, name="averaged wrench per pose"),
                    rrb.BarChartView(origin=RESIDUAL_FORCE_NORM, name="|force residual| per pose [N]"),
                    rrb.BarChartView(origin=RESIDUAL_TORQUE_NORM, name="|torque residual| per pose [N·m]"),
                    rrb.BarChartView(origin=VALIDATION_FORCE_NORM, name="|validation error| per V pose [N]"),
                ),
                row_shares=[3, 2],
            ),
            column_shares=[1, 1],
        ),
        *panels,
    )
