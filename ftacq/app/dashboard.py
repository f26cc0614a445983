"""The live Rerun dashboard: one module owns the layout, the entity paths and the sink choice.

Everything is logged to a :class:`rerun.RecordingStream` handed in explicitly (never the global one), so a
test can record to memory or a file and a live run to a viewer with the same code. Time is the sensor's clock:
the ``sensor_time`` timeline holds :attr:`drivers.sensor.WrenchBatch.time_s` (seconds on the host's monotonic
clock, when each sample was received); robot state, health and procedure events are stamped on the same clock.

Entity paths (all constants below)::

    wrench/raw/force, wrench/raw/torque                    Scalars (N, 3): Fx Fy Fz [N], Tx Ty Tz [N·m]
    wrench/compensated/force, wrench/compensated/torque    the same after gravity compensation
    world                                                  robot base frame B (z up, metres)
    world/robot/links, world/robot/joints                  the arm from forward kinematics
    world/flange                                           base_T_flange (Transform3D) and its axes
    world/flange/sensor                                    flange_T_sensor (from the calibration) and its axes
    world/flange/sensor/contact_force                      the compensated contact force, sensor frame
    world/gravity                                          the tool's weight (base frame) at the flange
    world/plan/<set>, world/plan/current                   the calibration plan, the pose being worked on
    robot/joints                                           joint angles [rad]
    health/…                                               sensor rate, lost samples, status word, viewer drops
    calibration/measured/…, calibration/residuals/…        averaged wrench and residuals per pose
    log/…                                                  text log (monitor, calibration)

Strict mode (``Dashboard(recording, strict=True)``) turns Rerun API misuse into exceptions (tests); the
default is warn-only, so a visualisation problem never stops acquisition or the robot.
"""

from __future__ import annotations

import argparse
import logging
import os
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from datetime import datetime
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ftacq.kinematics import URModel
from ftacq.so3 import rotation_from_rotvec

log = logging.getLogger(__name__)

APP_ID = "ftacq"
"""Rerun application id of every ftacq recording (the viewer keys blueprints by it)."""

SENSOR_TIMELINE = "sensor_time"
"""Duration timeline, seconds on the host monotonic clock (``WrenchBatch.time_s``)."""
POSE_TIMELINE = "pose"
"""Sequence timeline: the calibration pose index (execution order)."""

RAW_FORCE = "wrench/raw/force"
RAW_TORQUE = "wrench/raw/torque"
COMPENSATED_FORCE = "wrench/compensated/force"
COMPENSATED_TORQUE = "wrench/compensated/torque"
WRENCH_PATHS = (RAW_FORCE, RAW_TORQUE, COMPENSATED_FORCE, COMPENSATED_TORQUE)

WORLD = "world"
ROBOT_LINKS = "world/robot/links"
ROBOT_JOINTS = "world/robot/joints"
FLANGE = "world/flange"
SENSOR = "world/flange/sensor"
CONTACT_FORCE = "world/flange/sensor/contact_force"
GRAVITY = "world/gravity"
PLAN = "world/plan"
CURRENT_POSE = "world/plan/current"
JOINT_ANGLES = "robot/joints"

HEALTH = "health"
HEALTH_RATE = "health/rate_hz"
HEALTH_COUNTS = "health/counts"
HEALTH_STATUS = "health/status_word"

CALIBRATION = "calibration"
MEASURED_FORCE = "calibration/measured/force"
MEASURED_TORQUE = "calibration/measured/torque"
RESIDUAL_FORCE = "calibration/residuals/force"
RESIDUAL_TORQUE = "calibration/residuals/torque"
RESIDUAL_FORCE_NORM = "calibration/residual_norm/force"
RESIDUAL_TORQUE_NORM = "calibration/residual_norm/torque"
VALIDATION_FORCE_NORM = "calibration/validation_norm/force"

LOG = "log"
MONITOR_LOG = "log/monitor"
CALIBRATION_LOG = "log/calibration"

FORCE_AXES = ("Fx", "Fy", "Fz")
TORQUE_AXES = ("Tx", "Ty", "Tz")
AXIS_COLORS = ((230, 57, 70), (42, 157, 90), (38, 103, 230))
"""x red, y green, z blue, for force and torque alike (RGB 0-255)."""
HEALTH_COUNT_NAMES = ("lost", "saturated", "status_errors", "viewer_dropped")
HEALTH_COUNT_COLORS = ((230, 57, 70), (240, 160, 30), (150, 60, 200), (120, 120, 120))
JOINT_NAMES = tuple(f"q{i}" for i in range(1, 7))
JOINT_COLORS = ((230, 57, 70), (240, 160, 30), (200, 200, 40), (42, 157, 90), (38, 103, 230), (150, 60, 200))
SET_COLORS = {"A": (38, 103, 230), "E": (240, 160, 30), "V": (42, 157, 90)}
"""Plan colours by pose set: A cube rotations blue, E random cone orange, V validation green."""
UNKNOWN_SET_COLOR = (160, 160, 160)
LINK_COLOR = (190, 195, 205)
JOINT_COLOR = (60, 60, 70)
CONTACT_COLOR = (230, 57, 70)
GRAVITY_COLOR = (140, 70, 200)
CURRENT_POSE_COLOR = (255, 255, 255)

FORCE_ARROW_SCALE_M_PER_N = 0.01
"""Length of force arrows in the 3-D view: 10 N draws 0.1 m."""
FRAME_AXIS_LENGTH_M = 0.08
PLAN_AXIS_LENGTH_M = 0.04
WRENCH_WINDOW_S = 10.0
"""The wrench plots follow the time cursor over the last this-many seconds."""
EYE_POSITION_M = (1.3, -1.8, 1.1)
EYE_TARGET_M = (0.05, -0.3, 0.3)
"""Initial camera of the 3-D view (base frame, m): in front of and above a floor-mounted arm."""

DEFAULT_VIEWER_PORT = 9876
DEFAULT_WEB_PORT = 9090
LOCALHOST = "127.0.0.1"
VIEWER_START_TIMEOUT_S = 10.0
RECORDING_FLUSH_TIMEOUT_S = 5.0


# ----------------------------------------------------------------------------------------------------------------
# Layout
# ----------------------------------------------------------------------------------------------------------------


def blueprint():
    """Return the dashboard layout: four wrench plots left; the 3-D view and a tab strip (log, health, joints,
    calibration) right. Axis names and colours are fixed per entity by :class:`Dashboard` (static SeriesLines)."""
    import rerun.blueprint as rrb

    window = rrb.VisibleTimeRange(
        SENSOR_TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-WRENCH_WINDOW_S),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )

    def plot(origin: str, name: str) -> Any:
        return rrb.TimeSeriesView(origin=origin, name=name, time_ranges=window,
                                  plot_legend=rrb.PlotLegend(visible=True))

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                plot(RAW_FORCE, "raw force [N]"),
                plot(RAW_TORQUE, "raw torque [N·m]"),
                plot(COMPENSATED_FORCE, "compensated force [N]"),
                plot(COMPENSATED_TORQUE, "compensated torque [N·m]"),
            ),
            rrb.Vertical(
                rrb.Spatial3DView(origin=WORLD, name="robot (base frame)", eye_controls=rrb.EyeControls3D(
                    position=EYE_POSITION_M, look_target=EYE_TARGET_M, eye_up=(0.0, 0.0, 1.0))),
                rrb.Tabs(
                    rrb.TextLogView(origin=LOG, name="log"),
                    rrb.TimeSeriesView(origin=HEALTH, name="sensor health"),
                    rrb.TimeSeriesView(origin=JOINT_ANGLES, name="joints [rad]"),
                    rrb.TimeSeriesView(origin="calibration/measured", name="averaged wrench per pose"),
                    rrb.BarChartView(origin=RESIDUAL_FORCE_NORM, name="|force residual| per pose [N]"),
                    rrb.BarChartView(origin=RESIDUAL_TORQUE_NORM, name="|torque residual| per pose [N·m]"),
                    rrb.BarChartView(origin=VALIDATION_FORCE_NORM, name="|validation error| per V pose [N]"),
                ),
                row_shares=[3, 2],
            ),
            column_shares=[1, 1],
        ),
        rrb.TimePanel(state="collapsed", timeline=SENSOR_TIMELINE, play_state="following"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
    )


@lru_cache(maxsize=8)
def _pinocchio(model: URModel):
    from ftacq.kinematics import pinocchio_model

    pin_model = pinocchio_model(model)
    return pin_model, pin_model.createData()


def arm_polyline(model: URModel, q_rad: np.ndarray) -> np.ndarray:
    """Return the arm's skeleton (13, 3) in the base frame, m, from Pinocchio forward kinematics.

    For each DH step ``Rz(q_i) Tz(d_i) Tx(a_i) Rx(α_i)`` the polyline visits the origin of frame i-1, the point
    ``d_i`` along its z axis, then the origin of frame i: the UR's shoulder and elbow offsets show as bends.
    """
    from ftacq.kinematics import pinocchio_dh_frames

    pin_model, pin_data = _pinocchio(model)
    base_T_dh = pinocchio_dh_frames(pin_model, pin_data, np.asarray(q_rad, dtype=float))
    points = [np.zeros(3)]
    previous = np.eye(4)
    for i in range(6):
        points.append(previous[:3, 3] + model.d[i] * previous[:3, 2])
        points.append(base_T_dh[i][:3, 3])
        previous = base_T_dh[i]
    return np.array(points)


# ----------------------------------------------------------------------------------------------------------------
# The dashboard
# ----------------------------------------------------------------------------------------------------------------


class Dashboard:
    """Logs ftacq's data to a Rerun recording with the layout of :func:`blueprint`.

    The constructor sends the blueprint and the static styles (axis names and colours) once. Every method is
    thread-safe (one lock) and stamps data explicitly on the ``sensor_time`` timeline.

    Args:
        recording: the stream to log to (from :func:`open_recording`, or a test's own).
        strict: raise on Rerun API misuse (tests) instead of warning (live).
        send_blueprint: send the layout now (False when the sink already carries it).
    """

    def __init__(self, recording, *, strict: bool = False, send_blueprint: bool = True) -> None:
        import rerun as rr

        self._rr = rr
        self.recording = recording
        self.strict = strict
        self._lock = threading.Lock()
        self._sensor_rotation: np.ndarray | None = None  # sensor_R_flange
        self._gravity_base: np.ndarray | None = None
        if send_blueprint:
            recording.send_blueprint(blueprint())
        self._log_static_styles()

    # -- helpers ---------------------------------------------------------------------------------------------

    def _static(self, path: str, *archetypes: Any) -> None:
        self.recording.log(path, *archetypes, static=True, strict=self.strict)

    def _at(self, time_s: float, path: str, *archetypes: Any) -> None:
        """Log ``archetypes`` at ``time_s`` (s, sensor clock). Caller holds the lock (time is per thread)."""
        self.recording.set_time(SENSOR_TIMELINE, duration=float(time_s))
        self.recording.log(path, *archetypes, strict=self.strict)

    def _columns(self, path: str, time_s: np.ndarray, values: np.ndarray, pose_index: np.ndarray | None = None) -> None:
        rr = self._rr
        indexes = [rr.TimeColumn(SENSOR_TIMELINE, duration=np.asarray(time_s, dtype=np.float64))]
        if pose_index is not None:
            indexes.append(rr.TimeColumn(POSE_TIMELINE, sequence=np.asarray(pose_index, dtype=np.int64)))
        self.recording.send_columns(path, indexes=indexes,
                                    columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)),
                                    strict=self.strict)

    def _log_static_styles(self) -> None:
        rr = self._rr
        for path in WRENCH_PATHS:
            names = FORCE_AXES if path.endswith("force") else TORQUE_AXES
            self._static(path, rr.SeriesLines(colors=AXIS_COLORS, names=names))
        for path in (MEASURED_FORCE, MEASURED_TORQUE, RESIDUAL_FORCE, RESIDUAL_TORQUE):
            names = FORCE_AXES if path.endswith("force") else TORQUE_AXES
            self._static(path, rr.SeriesPoints(colors=AXIS_COLORS, names=names, marker_sizes=[3.0] * 3))
        self._static(HEALTH_RATE, rr.SeriesLines(colors=[(38, 103, 230)], names=["rate [Hz]"]))
        self._static(HEALTH_COUNTS, rr.SeriesLines(colors=HEALTH_COUNT_COLORS, names=HEALTH_COUNT_NAMES))
        self._static(HEALTH_STATUS, rr.SeriesLines(colors=[(60, 60, 70)], names=["status word"]))
        self._static(JOINT_ANGLES, rr.SeriesLines(colors=JOINT_COLORS, names=JOINT_NAMES))
        self._static(WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP)
        self._static(f"{WORLD}/base", rr.TransformAxes3D(FRAME_AXIS_LENGTH_M * 1.5))
        self._static(FLANGE, rr.TransformAxes3D(FRAME_AXIS_LENGTH_M))
        self._static(SENSOR, rr.TransformAxes3D(FRAME_AXIS_LENGTH_M * 0.75))

    # -- calibration -----------------------------------------------------------------------------------------

    def set_calibration(self, calibration) -> None:
        """Show the sensor frame (``flange_R_sensor`` = sensor_rotationᵀ) and remember the tool's weight.

        ``calibration`` is an :class:`ftacq.calibration.Calibration`, or None (sensor frame = flange frame).
        """
        rr = self._rr
        with self._lock:
            if calibration is None:
                self._sensor_rotation, self._gravity_base = None, None
                flange_R_sensor = np.eye(3)
            else:
                self._sensor_rotation = np.array(calibration.sensor_rotation)
                self._gravity_base = np.array(calibration.gravity_base)
                flange_R_sensor = self._sensor_rotation.T
            self._static(SENSOR, rr.Transform3D(mat3x3=flange_R_sensor))

    # -- streams ---------------------------------------------------------------------------------------------

    def log_wrench_batch(self, batch_time_s: np.ndarray, raw: np.ndarray, compensated: np.ndarray | None) -> None:
        """Log N samples: ``batch_time_s`` (N,) s on the sensor clock, ``raw`` and ``compensated`` (N, 6)
        [N, N·m] sensor frame (``compensated`` None without a calibration). One ``send_columns`` per plot;
        the last compensated force is drawn as the contact-force arrow at the sensor."""
        rr = self._rr
        time_s = np.asarray(batch_time_s, dtype=np.float64)
        if time_s.shape[0] == 0:
            return
        raw = np.asarray(raw, dtype=np.float64)
        with self._lock:
            self._columns(RAW_FORCE, time_s, raw[:, :3])
            self._columns(RAW_TORQUE, time_s, raw[:, 3:])
            if compensated is not None:
                compensated = np.asarray(compensated, dtype=np.float64)
                self._columns(COMPENSATED_FORCE, time_s, compensated[:, :3])
                self._columns(COMPENSATED_TORQUE, time_s, compensated[:, 3:])
                force = compensated[-1, :3]
                self._at(time_s[-1], CONTACT_FORCE, rr.Arrows3D(
                    vectors=[force * FORCE_ARROW_SCALE_M_PER_N], colors=[CONTACT_COLOR],
                    labels=[f"{np.linalg.norm(force):.1f} N"], radii=[0.004]))

    def log_robot(self, time_s: float, q_rad: np.ndarray, flange_pose: np.ndarray, model: URModel) -> None:
        """Log the arm at ``time_s`` (s, sensor clock): links from forward kinematics of ``q_rad`` (6,) rad,
        the flange frame from ``flange_pose`` [x, y, z (m), rx, ry, rz (rad)] (base frame, as the controller
        reports it), the joint angles, and the tool's weight as an arrow at the flange."""
        rr = self._rr
        q_rad = np.asarray(q_rad, dtype=np.float64)
        flange_pose = np.asarray(flange_pose, dtype=np.float64)
        skeleton = arm_polyline(model, q_rad)
        base_R_flange = rotation_from_rotvec(flange_pose[3:6])
        with self._lock:
            self._at(time_s, ROBOT_LINKS, rr.LineStrips3D([skeleton], radii=[model.link_radius_m * 0.4],
                                                          colors=[LINK_COLOR]))
            self._at(time_s, ROBOT_JOINTS, rr.Points3D(skeleton[2::2], radii=[model.link_radius_m * 0.6],
                                                       colors=[JOINT_COLOR]))
            self._at(time_s, FLANGE, rr.Transform3D(translation=flange_pose[:3], mat3x3=base_R_flange))
            if self._gravity_base is not None:
                self._at(time_s, GRAVITY, rr.Arrows3D(
                    origins=[flange_pose[:3]], vectors=[self._gravity_base * FORCE_ARROW_SCALE_M_PER_N],
                    colors=[GRAVITY_COLOR], labels=["tool weight"], radii=[0.004]))
            self._columns(JOINT_ANGLES, np.array([time_s]), q_rad[None, :])

    def log_flange(self, time_s: float, flange_pose: np.ndarray) -> None:
        """Log only the flange frame at ``time_s`` from ``flange_pose`` [x, y, z (m), rx, ry, rz (rad)] (no model)."""
        rr = self._rr
        flange_pose = np.asarray(flange_pose, dtype=np.float64)
        with self._lock:
            self._at(time_s, FLANGE, rr.Transform3D(translation=flange_pose[:3],
                                                    mat3x3=rotation_from_rotvec(flange_pose[3:6])))

    def log_health(self, time_s: float, health, viewer_dropped: int = 0) -> None:
        """Log a :class:`drivers.sensor.SensorHealth` snapshot at ``time_s`` (s, sensor clock): receive rate [Hz],
        lost / saturated / status-error counts, the last status word, and batches the viewer dropped."""
        counts = np.array([[health.lost, health.saturated, health.status_errors, viewer_dropped]], dtype=np.float64)
        with self._lock:
            t = np.array([time_s])
            self._columns(HEALTH_RATE, t, np.array([[health.rate_hz]]))
            self._columns(HEALTH_COUNTS, t, counts)
            self._columns(HEALTH_STATUS, t, np.array([[float(health.last_status)]]))

    def log_text(self, text: str, *, level: str = "INFO", time_s: float | None = None, path: str = MONITOR_LOG) -> None:
        """Append a line to the text log (``path`` under ``log/``) at ``time_s`` (s, sensor clock; default now)."""
        rr = self._rr
        with self._lock:
            self._at(time.monotonic() if time_s is None else time_s, path, rr.TextLog(text, level=level))

    # -- calibration procedure -------------------------------------------------------------------------------

    def log_plan(self, time_s: float, poses: np.ndarray, labels: Sequence[str], set_names: Sequence[str]) -> None:
        """Draw every planned flange pose (N, 6) as a small frame coloured by its set (A, E, V)."""
        rr = self._rr
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 6)
        rotations = rotation_from_rotvec(poses[:, 3:6])  # base_R_flange (N, 3, 3)
        with self._lock:
            for set_name in sorted(set(set_names)):
                mask = np.array([s == set_name for s in set_names])
                color = SET_COLORS.get(set_name, UNKNOWN_SET_COLOR)
                origins = np.repeat(poses[mask, :3], 3, axis=0)
                vectors = np.concatenate([rotations[mask][:, :, k] for k in range(3)], axis=1).reshape(-1, 3)
                shades = np.array([1.0, 0.75, 0.5])[None, :, None] * np.array(color)[None, None, :]
                colors = np.repeat(shades, int(mask.sum()), axis=0).reshape(-1, 3).astype(np.uint8)
                self._at(time_s, f"{PLAN}/{set_name}", rr.Arrows3D(
                    origins=origins, vectors=vectors * PLAN_AXIS_LENGTH_M, colors=colors, radii=[0.002]))
                self._at(time_s, f"{PLAN}/{set_name}/labels", rr.Points3D(
                    poses[mask, :3], radii=[0.006], colors=[color],
                    labels=[label for label, keep in zip(labels, mask) if keep], show_labels=False))

    def log_current_pose(self, time_s: float, pose: np.ndarray, text: str) -> None:
        """Highlight the pose the procedure is working on ([x, y, z, rx, ry, rz], base frame)."""
        rr = self._rr
        pose = np.asarray(pose, dtype=np.float64)
        with self._lock:
            self._at(time_s, CURRENT_POSE, rr.Points3D([pose[:3]], radii=[0.015], colors=[CURRENT_POSE_COLOR],
                                                       labels=[text], show_labels=True))

    def log_pose_measured(self, time_s: float, index: int, mean: np.ndarray) -> None:
        """Log the averaged wrench (6,) [N, N·m] of pose ``index`` on both timelines."""
        mean = np.asarray(mean, dtype=np.float64)
        with self._lock:
            self._columns(MEASURED_FORCE, np.array([time_s]), mean[None, :3], np.array([index]))
            self._columns(MEASURED_TORQUE, np.array([time_s]), mean[None, 3:], np.array([index]))

    def log_residuals(self, time_s: float, residuals: np.ndarray, pose_indices: np.ndarray | None = None) -> None:
        """Log identification residuals (N, 6) [N, N·m] per pose: per axis on the ``pose`` timeline and as bar
        charts of their norms."""
        rr = self._rr
        residuals = np.asarray(residuals, dtype=np.float64).reshape(-1, 6)
        n = residuals.shape[0]
        indices = np.arange(n) if pose_indices is None else np.asarray(pose_indices)
        with self._lock:
            if n:
                times = np.full(n, float(time_s))
                self._columns(RESIDUAL_FORCE, times, residuals[:, :3], indices)
                self._columns(RESIDUAL_TORQUE, times, residuals[:, 3:], indices)
            self._at(time_s, RESIDUAL_FORCE_NORM, rr.BarChart(np.linalg.norm(residuals[:, :3], axis=1),
                                                              color=AXIS_COLORS[2]))
            self._at(time_s, RESIDUAL_TORQUE_NORM, rr.BarChart(np.linalg.norm(residuals[:, 3:], axis=1),
                                                               color=AXIS_COLORS[0]))

    def log_validation(self, time_s: float, errors: np.ndarray) -> None:
        """Log the compensation errors (M, 6) on the validation poses as a bar chart of force-error norms."""
        rr = self._rr
        errors = np.asarray(errors, dtype=np.float64).reshape(-1, 6)
        with self._lock:
            self._at(time_s, VALIDATION_FORCE_NORM, rr.BarChart(np.linalg.norm(errors[:, :3], axis=1),
                                                                color=SET_COLORS["V"]))

    def flush(self, timeout_s: float = RECORDING_FLUSH_TIMEOUT_S) -> None:
        """Push everything logged so far to the sink, waiting at most ``timeout_s`` seconds."""
        self.recording.flush(timeout_sec=timeout_s)


class DashboardListener:
    """A :data:`procedures.events.Listener` that draws the calibration procedure on a :class:`Dashboard`.

    Plan → every pose as a frame coloured by set; state changes → the current pose and a log line; each
    measured pose → its averaged wrench and the arm where it was measured (the flange frame only without
    ``model``, a :class:`ftacq.kinematics.URModel`); identification → residuals per pose; validation → errors per
    V pose. It never raises into the procedure unless the dashboard is strict (tests).
    """

    def __init__(self, dashboard: Dashboard, model: URModel | None = None,
                 clock_s: Callable[[], float] = time.monotonic) -> None:
        self.dashboard = dashboard
        self.model = model
        self._clock_s = clock_s
        self._poses: np.ndarray | None = None
        self._labels: tuple[str, ...] = ()
        self._set_names: tuple[str, ...] = ()

    def __call__(self, event) -> None:
        try:
            self._handle(event)
        except Exception:  # noqa: BLE001 - a broken viewer must never stop the robot
            if self.dashboard.strict:
                raise
            log.warning("dashboard listener failed on %s", type(event).__name__, exc_info=True)

    def _handle(self, event) -> None:
        from procedures import events

        now = self._clock_s()
        dash = self.dashboard
        if isinstance(event, events.PlanReady):
            self._poses = np.asarray(event.poses, dtype=float)
            self._labels, self._set_names = tuple(event.labels), tuple(event.set_names)
            dash.log_plan(now, self._poses, self._labels, self._set_names)
            counts = {s: self._set_names.count(s) for s in sorted(set(self._set_names))}
            dash.log_text(
                f"plan: {len(self._labels)} poses {counts}, about {event.estimated_duration_s:.0f} s, "
                f"joint travel {event.joint_travel_rad:.1f} rad", time_s=now, path=CALIBRATION_LOG)
        elif isinstance(event, events.StateChanged):
            where = ""
            if event.index is not None and self._poses is not None and 0 <= event.index < len(self._poses):
                where = f" pose {event.index} {self._labels[event.index]} ({self._set_names[event.index]})"
                dash.log_current_pose(now, self._poses[event.index], f"{event.index} {self._labels[event.index]}: "
                                                                      f"{event.state}")
            level = {"failed": "ERROR", "stopped": "WARN"}.get(event.state, "INFO")
            message = f": {event.message}" if event.message else ""
            dash.log_text(f"{event.state}{where}{message}", level=level, time_s=now, path=CALIBRATION_LOG)
        elif isinstance(event, events.PoseMeasured):
            dash.log_pose_measured(now, event.index, event.mean)
            if self.model is not None:
                dash.log_robot(now, event.joint_positions_rad, event.pose, self.model)
            else:
                dash.log_flange(now, event.pose)
            if event.saturated or event.lost:
                dash.log_text(f"pose {event.index} {event.label}: {event.saturated} saturated, {event.lost} lost",
                              level="WARN", time_s=now, path=CALIBRATION_LOG)
        elif isinstance(event, events.Identified):
            indices = np.array([self._labels.index(label) if label in self._labels else i
                                for i, label in enumerate(event.labels)], dtype=np.int64)
            dash.set_calibration(event.calibration)
            dash.log_residuals(now, event.residuals, indices)
            calibration = event.calibration
            outliers = f", outliers {', '.join(event.outliers)}" if event.outliers else ""
            dash.log_text(f"identified: tool mass {calibration.mass_kg:.3f} kg, base tilt "
                          f"({calibration.base_tilt_deg[0]:.2f}°, {calibration.base_tilt_deg[1]:.2f}°){outliers}",
                          time_s=now, path=CALIBRATION_LOG)
        elif isinstance(event, events.Validated):
            dash.log_validation(now, event.errors)
            rms = np.asarray(event.rms)
            dash.log_text(f"validated on {len(event.labels)} poses: rms force {np.linalg.norm(rms[:3]):.3f} N, "
                          f"rms torque {np.linalg.norm(rms[3:]):.4f} N·m", time_s=now, path=CALIBRATION_LOG)


# ----------------------------------------------------------------------------------------------------------------
# Sinks
# ----------------------------------------------------------------------------------------------------------------


def add_sink_args(parser: argparse.ArgumentParser) -> None:
    """Add the viewer flags (one of --spawn, --connect, --serve, --save) as Rerun's example scripts do.

    Without a flag: spawn a native viewer when a display is available, else save an .rrd under ``runs/``.
    """
    group = parser.add_argument_group("Rerun viewer (pick one; default: --spawn with a display, else --save)")
    sinks = group.add_mutually_exclusive_group()
    sinks.add_argument("--spawn", action="store_true",
                       help=f"start a native Rerun viewer bound to {LOCALHOST} (or reuse one on --viewer-port)")
    sinks.add_argument("--connect", nargs="?", const=f"rerun+http://{LOCALHOST}:{DEFAULT_VIEWER_PORT}/proxy",
                       metavar="URL", help="stream to a running viewer (default URL rerun+http://127.0.0.1:9876/proxy)")
    sinks.add_argument("--serve", action="store_true",
                       help=f"serve the web viewer on http://{LOCALHOST}:WEB_PORT and the data on gRPC "
                            "(--viewer-port), both localhost only; keeps serving after the run until Ctrl-C")
    sinks.add_argument("--save", metavar="FILE.rrd", type=Path, help="write the recording to an .rrd file")
    group.add_argument("--viewer-port", type=int, default=DEFAULT_VIEWER_PORT, metavar="PORT",
                       help="gRPC port of the spawned viewer or of the --serve server (default %(default)s)")
    group.add_argument("--web-port", type=int, default=DEFAULT_WEB_PORT, metavar="PORT",
                       help="HTTP port of the --serve web viewer (default %(default)s)")
    group.add_argument("--no-browser", action="store_true", help="with --serve: do not open a browser")


def has_display() -> bool:
    """Return True when a native viewer window can open (Linux needs $DISPLAY or $WAYLAND_DISPLAY)."""
    if sys.platform.startswith("linux") or sys.platform.startswith("freebsd"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def default_rrd_path(app_id: str = APP_ID, runs_dir: Path = Path("runs")) -> Path:
    """Return ``runs/<app_id>-YYYYmmdd-HHMMSS.rrd`` (local time)."""
    return runs_dir / f"{app_id}-{datetime.now():%Y%m%d-%H%M%S}.rrd"


@dataclass(frozen=True)
class SinkChoice:
    """Where the recording goes: ``kind`` is "spawn", "connect", "serve" or "save"; ``target`` the URL or path."""

    kind: str
    target: str
    message: str
    web_url: str = ""


def _port_open(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.settimeout(0.2)
        return probe.connect_ex((host, port)) == 0


def _rerun_executable() -> str:
    executable = Path(sys.executable).with_name("rerun")
    return str(executable) if executable.exists() else "rerun"


def _wait_for_port(port: int, process: subprocess.Popen | None = None) -> bool:
    """Wait until 127.0.0.1:``port`` accepts connections (at most VIEWER_START_TIMEOUT_S); False if it never does."""
    deadline = time.monotonic() + VIEWER_START_TIMEOUT_S
    while time.monotonic() < deadline:
        if _port_open(LOCALHOST, port):
            return True
        if process is not None and process.poll() is not None:
            return False
        time.sleep(0.05)
    return False


def _spawn_viewer(port: int) -> None:
    """Start ``rerun --bind 127.0.0.1 --port PORT`` detached (unless one already listens there) and wait for it.

    Detached like ``rerun.spawn``: the window stays open after ftacq exits. Bound to localhost, unlike
    ``rerun.spawn`` (whose viewer listens on every interface).
    """
    if _port_open(LOCALHOST, port):
        return
    process = subprocess.Popen([_rerun_executable(), "--bind", LOCALHOST, "--port", str(port)],
                               stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                               start_new_session=True, env={**os.environ, "RERUN_APP_ONLY": "true"})
    if not _wait_for_port(port, process):
        log.warning("the Rerun viewer did not open port %d within %.0f s; streaming anyway", port,
                    VIEWER_START_TIMEOUT_S)


_WEB_SERVERS: dict[int, tuple[subprocess.Popen, str]] = {}
"""Web-viewer servers started by :func:`open_recording` (``--serve``), keyed by ``id(recording)``; stopped by
:func:`close_recording`."""


def _stop_process_group(process: subprocess.Popen, timeout_s: float = RECORDING_FLUSH_TIMEOUT_S) -> None:
    """Stop a process started with ``start_new_session=True`` and its children (``.venv/bin/rerun`` is a Python
    wrapper around the ``rerun_cli`` binary: terminating only the wrapper would leave the server running)."""
    import signal

    def signal_group(signum: int) -> None:
        try:
            os.killpg(process.pid, signum)
        except (AttributeError, ProcessLookupError, PermissionError):  # no process groups, or already gone
            if process.poll() is None:
                process.send_signal(signum)

    signal_group(signal.SIGTERM)
    try:
        process.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        signal_group(getattr(signal, "SIGKILL", signal.SIGTERM))
        process.wait()
    if process.stdin is not None:
        process.stdin.close()


_EXIT_WITH_PARENT = ("sh", "-c", 'exec 3<&0; "$@" 3<&- & child=$!; { read -r _ <&3; kill -TERM 0; } & '
                     'wait "$child"; kill -TERM 0', "ftacq-viewer-guard")
"""Runs a command in its process group and ends the group when ftacq dies, however (even SIGKILL): ftacq holds
the write end of the guard's stdin, the kernel closes it with the process, and the guard's read then returns."""


def _serve_web(grpc_port: int, web_port: int):
    """Start ``rerun --serve-web`` bound to 127.0.0.1 (gRPC on ``grpc_port``, HTTP on ``web_port``); return it.

    Rerun's in-process ``serve_web_viewer`` listens on every interface; the CLI honours ``--bind``. Raises
    DeviceConnectionError when the server does not come up (e.g. a port is taken).
    """
    from ftacq.errors import DeviceConnectionError

    process = subprocess.Popen(
        [*_EXIT_WITH_PARENT, _rerun_executable(), "--serve-web", "--bind", LOCALHOST, "--port", str(grpc_port),
         "--web-viewer-port", str(web_port)],
        stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,  # stdin: see _EXIT_WITH_PARENT
        start_new_session=True,  # Ctrl-C stops ftacq first; close_recording then stops the server
        env={**os.environ, "RERUN_APP_ONLY": "true"})
    if not (_wait_for_port(grpc_port, process) and _wait_for_port(web_port, process)):
        _stop_process_group(process)
        raise DeviceConnectionError(f"rerun --serve-web did not start on 127.0.0.1 ports {grpc_port} (gRPC) and "
                                    f"{web_port} (HTTP) within {VIEWER_START_TIMEOUT_S:.0f} s: are they taken? "
                                    "Pick others with --viewer-port / --web-port")
    return process


def open_recording(args: argparse.Namespace, app_id: str = APP_ID, *,
                   announce: Callable[[str], None] | None = None):
    """Return a new :class:`rerun.RecordingStream` connected to the sink the flags of :func:`add_sink_args` chose.

    ``announce`` receives one line telling the user where the data goes and how to view it (default: print to
    stderr). The layout is sent by :class:`Dashboard`; the caller owns the stream and ends with
    :func:`close_recording`.
    """
    import rerun as rr

    announce = announce or (lambda line: print(line, file=sys.stderr))
    recording = rr.RecordingStream(app_id, recording_id=None)
    choice = _choose_sink(args, app_id)
    if choice.kind == "save":
        path = Path(choice.target)
        path.parent.mkdir(parents=True, exist_ok=True)
        recording.save(path)
    elif choice.kind == "connect":
        recording.connect_grpc(choice.target)
    elif choice.kind == "spawn":
        _spawn_viewer(args.viewer_port)
        recording.connect_grpc(choice.target)
    elif choice.kind == "serve":
        process = _serve_web(args.viewer_port, args.web_port)
        _WEB_SERVERS[id(recording)] = (process, choice.web_url)
        recording.connect_grpc(choice.target)
        if not args.no_browser:
            import webbrowser

            webbrowser.open(choice.web_url)
    announce(choice.message)
    return recording


def _choose_sink(args: argparse.Namespace, app_id: str) -> SinkChoice:
    port = getattr(args, "viewer_port", DEFAULT_VIEWER_PORT)
    if getattr(args, "save", None) is not None:
        path = Path(args.save)
        return SinkChoice("save", str(path), f"rerun: saving to {path}; view it with: rerun {path}")
    if getattr(args, "connect", None):
        return SinkChoice("connect", args.connect, f"rerun: streaming to the viewer at {args.connect}")
    if getattr(args, "serve", False):
        from urllib.parse import quote

        grpc_url = f"rerun+http://{LOCALHOST}:{port}/proxy"
        web_url = f"http://{LOCALHOST}:{getattr(args, 'web_port', DEFAULT_WEB_PORT)}/?url={quote(grpc_url, safe='')}"
        return SinkChoice("serve", grpc_url, f"rerun: web viewer at {web_url} (native: rerun {grpc_url})", web_url)
    if getattr(args, "spawn", False) or has_display():
        url = f"rerun+http://{LOCALHOST}:{port}/proxy"
        return SinkChoice("spawn", url, f"rerun: streaming to a native viewer on {url}")
    path = default_rrd_path(app_id)
    return SinkChoice("save", str(path), f"rerun: no display found, saving to {path}; view it with: rerun {path} "
                                         "(or pass --serve / --connect URL)")


def close_recording(recording, timeout_s: float = RECORDING_FLUSH_TIMEOUT_S, *,
                    wait_while_serving: bool = True) -> None:
    """Flush (at most ``timeout_s`` seconds) and close the recording's sinks, finishing an .rrd file.

    A web viewer started by ``--serve`` keeps the data only while it runs: like Rerun's ``script_teardown``,
    this keeps serving until Ctrl-C (unless ``wait_while_serving`` is False), then stops the server.
    """
    try:
        recording.flush(timeout_sec=timeout_s)
    except Exception:  # noqa: BLE001 - a viewer that went away must not fail the caller's shutdown
        log.warning("rerun: flush did not finish within %.1f s", timeout_s, exc_info=True)
    recording.disconnect()
    served = _WEB_SERVERS.pop(id(recording), None)
    if served is not None:
        process, web_url = served
        try:
            if wait_while_serving and process.poll() is None:
                print(f"rerun: still serving the recording at {web_url}; Ctrl-C to stop", file=sys.stderr)
                process.wait()
        except KeyboardInterrupt:
            pass
        finally:
            _stop_process_group(process, timeout_s)


# ----------------------------------------------------------------------------------------------------------------
# Reading a recording back (tests, benchmarks)
# ----------------------------------------------------------------------------------------------------------------


def read_scalars(rrd_path: str | os.PathLike, entity_path: str) -> tuple[np.ndarray, np.ndarray]:
    """Read a Scalars entity back from an .rrd file with Rerun's own reader (:class:`rerun.chunk.RrdReader`).

    Returns ``(time_s, values)``: (N,) seconds on the ``sensor_time`` timeline and (N, k) values, in time order.
    """
    from rerun.chunk import RrdReader

    wanted = "/" + entity_path.strip("/")
    times, values = [], []
    for chunk in RrdReader(rrd_path).stream().to_chunks():
        if chunk.entity_path != wanted or chunk.is_static or chunk.num_rows == 0:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if SENSOR_TIMELINE not in names or "Scalars:scalars" not in names:
            continue
        times.append(batch.column(SENSOR_TIMELINE).cast("int64").to_numpy())
        column = batch.column("Scalars:scalars")
        values.append(column.flatten().to_numpy().reshape(len(column), -1))
    if not times:
        return np.empty(0), np.empty((0, 0))
    time_ns = np.concatenate(times)
    order = np.argsort(time_ns, kind="stable")
    return time_ns[order] * 1e-9, np.concatenate(values)[order]


def entity_paths(rrd_path: str | os.PathLike) -> set[str]:
    """Return the entity paths (without the leading "/") that hold data in an .rrd file's recording."""
    from rerun.chunk import RrdReader

    return {chunk.entity_path.lstrip("/") for chunk in RrdReader(rrd_path).stream().to_chunks()}
