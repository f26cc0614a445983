"""The recorder: ftacq's data as Rerun logs, with the layout of :mod:`ftacq.app.dashboard.layout`.

Everything is logged to a :class:`rerun.RecordingStream` handed in explicitly (never the global one), so a
test records to a file and a live run to a viewer with the same code. Streams go as numpy columns
(``send_columns``: one call per plot per batch, never one Python object per sample); fixed things are logged
once, static (axis names and colours, the arm's link shapes, frame axes), so a recording shows them whatever
the time cursor, as recorded. No entity of the 3-D view mixes static and temporal data: a file written live showed
such entities only after ``rerun rrd optimize`` (the arrows and labels, in a 20 s recording viewed with rerun
0.41), so an arrow's colour and radius go with every row and frame axes sit on a child entity of their frame.

Streams are sent in columns of at least :data:`LIVE_SEND_PERIOD_S` of data (:data:`FILE_SEND_PERIOD_S` into a
saved file), not one chunk per sensor read: every ``send_columns`` is one chunk, and a 25 s monitor file written
per read held 3 200 chunks, which the viewer took so long to take in that a screenshot 5 s after opening it (and a
user in those seconds) saw the arm in an old pose and neither the tool-weight arrow nor the labels (the same file
after ``rerun rrd optimize``, 65 chunks, showed them at once; so did the unoptimized file 30 s after opening). What
is still held is sent by :meth:`Dashboard.flush`, and by ``close_recording`` (the dashboard attaches itself).

Time is the run's time: every timeline value is seconds since the run's first data (``origin_s``, host monotonic
clock; or an origin given), so the viewer's axes read "+12.5 s", not the machine's uptime; the origin is a
recording property (``ftacq_time``: the monotonic origin and the wall-clock time it corresponds to).

Strict mode (``Dashboard(recording, strict=True)``) turns Rerun API misuse into exceptions (tests); the
default is warn-only, so a visualisation problem never stops acquisition or the robot.
"""

from __future__ import annotations

import threading
import time
from datetime import datetime, timezone
from typing import Any, Sequence

import numpy as np
import rerun as rr

from ftacq.app.dashboard.arm import label_anchors, link_frames, link_shapes
from ftacq.app.dashboard.layout import (
    ARROW_RADIUS_M, AXIS_COLORS, BASE_AXES, BIAS_DRIFT_FORCE, BIAS_DRIFT_TORQUE, CONTACT_COLOR, CONTACT_FORCE, CURRENT_POSE, CURRENT_POSE_COLOR,
    FED_FORCE, FED_TORQUE, FLANGE, FLANGE_AXES, FORCE_ARROW_SCALE_M_PER_N, FORCE_AXES, FRAME_AXIS_LENGTH_M, GRAVITY,
    GRAVITY_COLOR, HEALTH_COUNT_COLORS,
    HEALTH_COUNT_NAMES, HEALTH_COUNTS, HEALTH_RATE, HEALTH_STATUS, JOINT_ANGLES, JOINT_COLOR, JOINT_COLORS,
    JOINT_NAMES, LABEL_COLORS, LABEL_RADIUS_M, LABELS, LINK_COLOR, LINK_FRAMES, LINK_SHAPES, MEASURED_FORCE, MEASURED_TORQUE,
    MONITOR_LOG, PLAN, PLAN_AXIS_LENGTH_M, POSE_TIMELINE, RESIDUAL_FORCE, RESIDUAL_FORCE_NORM, RESIDUAL_TORQUE,
    RESIDUAL_TORQUE_NORM, SENSOR, SENSOR_TIMELINE, SET_COLORS, TORQUE_AXES, UNKNOWN_SET_COLOR,
    VALIDATION_FORCE_NORM, WORLD, WRENCH_PATHS, blueprint,
)
from ftacq.app.dashboard import sinks
from ftacq.app.dashboard.sinks import RECORDING_FLUSH_TIMEOUT_S
from ftacq.kinematics import URModel
from ftacq.posesets import VALIDATION_SET
from ftacq.so3 import rotation_from_rotvec

LIVE_SEND_PERIOD_S = 0.2
"""A stream's rows are sent once they span this much time (s, data clock) to a live viewer …"""
FILE_SEND_PERIOD_S = 5.0
"""… and this much into a saved file (nobody watches it live; fewer, larger chunks load faster)."""
CONTACT_ARROW_RATE_HZ = 30.0
"""The contact-force arrow is drawn at most this often (the plots carry every sample)."""
TIME_PROPERTY = "ftacq_time"
"""Recording property: ``origin_monotonic_s`` (the host monotonic time of timeline value 0) and ``origin_utc``."""


class Dashboard:
    """Logs ftacq's data to a Rerun recording with the layout of :func:`~ftacq.app.dashboard.layout.blueprint`.

    The constructor sends the blueprint and the static styles once. Every method is thread-safe (one lock) and
    takes times in seconds on the host monotonic clock; they are logged on the ``sensor_time`` timeline as seconds
    since ``origin_s`` (see the module docstring).

    Args:
        recording: the stream to log to (from :func:`~ftacq.app.dashboard.sinks.open_recording`, or a test's own).
        strict: raise on Rerun API misuse (tests) instead of warning (live).
        send_blueprint: send the layout now (False when the sink already carries it).
        view: the layout, "monitor" (also the calibration's) or "bridge" (:func:`~ftacq.app.dashboard.layout.blueprint`).
        origin_s: host monotonic time of the timeline's zero (default: the time of the first data logged).
        send_period_s: the span of data a stream's column holds before it is sent (default by sink, see the module).
    """

    def __init__(self, recording: rr.RecordingStream, *, strict: bool = False, send_blueprint: bool = True,
                 view: str = "monitor", origin_s: float | None = None, send_period_s: float | None = None) -> None:
        self.recording = recording
        self.strict = strict
        self.model: URModel | None = None
        self._lock = threading.Lock()
        self._sensor_rotation: np.ndarray | None = None  # sensor_R_flange
        self._gravity_base: np.ndarray | None = None  # the tool's weight, base frame, N
        self._contact_sensor = np.zeros(3)  # the latest compensated force sent, sensor frame, N
        self.origin_s: float | None = None
        """Host monotonic time of the timeline's zero: given, or the time of the first data logged."""
        if send_period_s is None:
            send_period_s = FILE_SEND_PERIOD_S if sinks.is_saved(recording) else LIVE_SEND_PERIOD_S
        self.send_period_s = float(send_period_s)
        self.rows_logged = 0
        """Rows of temporal data logged so far (0: the recording holds only the layout and styles)."""
        self.wrench_every = 1
        """:meth:`log_wrench_batch` logs every k-th sample (:meth:`thin_wrenches`; a saved file's size budget)."""
        self._wrench_decimator: Any = None
        self._pending_scalars: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        self._pending_arm: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = []
        self._pending_contact: list[tuple[np.ndarray, np.ndarray]] = []
        self._pending_from_s: float | None = None
        if send_blueprint:
            recording.send_blueprint(blueprint(view))
        if origin_s is not None:
            self._set_origin(float(origin_s))
        self._log_static_styles()
        sinks.attach(recording, self.flush_columns, lambda: self.rows_logged > 0)

    # -- helpers ---------------------------------------------------------------------------------------------

    def start_clock(self, origin_s: float | None = None) -> None:
        """Make ``origin_s`` (s, host monotonic clock; default now) the timeline's zero, unless data was logged
        already: a command calls it as its sensor starts, so samples the first read returns are not before it."""
        with self._lock:
            if self.origin_s is None:
                self._set_origin(time.monotonic() if origin_s is None else float(origin_s))

    def _set_origin(self, origin_s: float) -> None:
        """Make ``origin_s`` (s, host monotonic clock) the timeline's zero and record it (``ftacq_time``)."""
        self.origin_s = origin_s
        unix_s = time.time() - (time.monotonic() - origin_s)
        self.recording.send_property(TIME_PROPERTY, rr.AnyValues(
            origin_monotonic_s=origin_s,
            origin_utc=datetime.fromtimestamp(unix_s, timezone.utc).isoformat(timespec="milliseconds")))

    def _since_origin(self, time_s: np.ndarray) -> np.ndarray:
        """``time_s`` (s, host monotonic clock) as seconds since the origin (the first data sets it)."""
        if self.origin_s is None:
            self._set_origin(float(np.min(time_s)))
        assert self.origin_s is not None
        return time_s - self.origin_s

    def _static(self, path: str, *archetypes: Any) -> None:
        self.recording.log(path, *archetypes, static=True, strict=self.strict)

    def _at(self, time_s: float, path: str, *archetypes: Any) -> None:
        """Log ``archetypes`` at ``time_s`` (s, host monotonic clock). Caller holds the lock (time is per thread)."""
        self.recording.set_time(SENSOR_TIMELINE, duration=float(self._since_origin(np.array([float(time_s)]))[0]))
        self.recording.log(path, *archetypes, strict=self.strict)
        self.rows_logged += 1

    def _send(self, path: str, time_s: np.ndarray, columns: Any, pose_index: np.ndarray | None = None) -> None:
        time_s = np.asarray(time_s, dtype=np.float64)
        indexes = [rr.TimeColumn(SENSOR_TIMELINE, duration=self._since_origin(time_s))]
        if pose_index is not None:
            indexes.append(rr.TimeColumn(POSE_TIMELINE, sequence=np.asarray(pose_index, dtype=np.int64)))
        self.recording.send_columns(path, indexes=indexes, columns=columns, strict=self.strict)
        self.rows_logged += time_s.shape[0]

    def _scalars(self, path: str, time_s: np.ndarray, values: np.ndarray, pose_index: np.ndarray | None = None) -> None:
        self._send(path, time_s, rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)), pose_index)

    def _hold(self, newest_s: float, oldest_s: float) -> None:
        """Note rows from ``oldest_s`` to ``newest_s`` held; send everything held once it spans the send period.
        Caller holds the lock."""
        if self.origin_s is None:
            self._set_origin(oldest_s)  # the first data held, not when it is sent
        if self._pending_from_s is None or oldest_s < self._pending_from_s:
            self._pending_from_s = oldest_s
        if newest_s - self._pending_from_s >= self.send_period_s:
            self._send_pending()

    def _hold_scalars(self, path: str, time_s: np.ndarray, values: np.ndarray) -> None:
        self._pending_scalars.setdefault(path, []).append((time_s, np.asarray(values, dtype=np.float64)))

    def _send_pending(self) -> None:
        """Send every held column (one chunk per entity). Caller holds the lock."""
        scalars, self._pending_scalars = self._pending_scalars, {}
        arm, self._pending_arm = self._pending_arm, []
        contact, self._pending_contact = self._pending_contact, []
        self._pending_from_s = None
        for path, parts in scalars.items():
            self._scalars(path, np.concatenate([t for t, _ in parts]), np.concatenate([v for _, v in parts]))
        contact_time_s = contact_sensor = None
        if contact:
            contact_time_s = np.concatenate([t for t, _ in contact])
            contact_sensor = np.concatenate([v for _, v in contact])
            n = contact_time_s.shape[0]
            self._send(CONTACT_FORCE, contact_time_s, rr.Arrows3D.columns(
                vectors=contact_sensor * FORCE_ARROW_SCALE_M_PER_N,
                colors=np.tile(np.array(CONTACT_COLOR, np.uint8), (n, 1)), radii=np.full(n, ARROW_RADIUS_M)))
        if arm:
            q_parts = [q for _, _, q in arm if q is not None]  # all or none (log_arm sends before a change)
            self._send_arm(np.concatenate([t for t, _, _ in arm]), np.concatenate([p for _, p, _ in arm]),
                           np.concatenate(q_parts) if len(q_parts) == len(arm) else None,
                           contact_time_s, contact_sensor)
        if contact_sensor is not None:
            self._contact_sensor = contact_sensor[-1].copy()

    def flush_columns(self) -> None:
        """Send the columns still held (the rows of less than one send period)."""
        with self._lock:
            self._send_pending()

    def _log_static_styles(self) -> None:
        for path in (*WRENCH_PATHS, FED_FORCE, FED_TORQUE):
            names = FORCE_AXES if path.endswith("force") else TORQUE_AXES
            self._static(path, rr.SeriesLines(colors=AXIS_COLORS, names=names))
        for path in (MEASURED_FORCE, MEASURED_TORQUE, RESIDUAL_FORCE, RESIDUAL_TORQUE):
            names = FORCE_AXES if path.endswith("force") else TORQUE_AXES
            self._static(path, rr.SeriesPoints(colors=AXIS_COLORS, names=names, marker_sizes=[3.0] * 3))
        for path, axes in ((BIAS_DRIFT_FORCE, FORCE_AXES), (BIAS_DRIFT_TORQUE, TORQUE_AXES)):
            faint = [tuple(int(c + (255 - c) * 0.6) for c in color) for color in AXIS_COLORS]
            self._static(path, rr.SeriesLines(colors=list(AXIS_COLORS) + faint + faint,
                                              names=list(axes) + [f"{a} +1σ" for a in axes] + [f"{a} −1σ" for a in axes]))
        self._static(HEALTH_RATE, rr.SeriesLines(colors=[(38, 103, 230)], names=["rate [Hz]"]))
        self._static(HEALTH_COUNTS, rr.SeriesLines(colors=HEALTH_COUNT_COLORS, names=HEALTH_COUNT_NAMES))
        self._static(HEALTH_STATUS, rr.SeriesLines(colors=[(60, 60, 70)], names=["status word"]))
        self._static(JOINT_ANGLES, rr.SeriesLines(colors=JOINT_COLORS, names=JOINT_NAMES))
        self._static(WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP)
        self._static(BASE_AXES, rr.TransformAxes3D(FRAME_AXIS_LENGTH_M * 1.5))
        self._static(FLANGE_AXES, rr.TransformAxes3D(FRAME_AXIS_LENGTH_M))
        self._static(SENSOR, rr.TransformAxes3D(FRAME_AXIS_LENGTH_M * 0.75))

    # -- what stays fixed --------------------------------------------------------------------------------------

    def set_arm(self, model: URModel) -> None:
        """Log the arm's six links once (static), each in its DH frame; :meth:`log_arm` then moves the frames."""
        shapes = link_shapes(model)
        with self._lock:
            self.model = model
            for shape_path, shape in zip(LINK_SHAPES, shapes):
                self._static(shape_path,
                             rr.LineStrips3D([shape], radii=[model.link_radius_m * 0.4], colors=[LINK_COLOR]),
                             rr.Points3D([shape[-1]], radii=[model.link_radius_m * 0.6], colors=[JOINT_COLOR]))

    def set_calibration(self, calibration) -> None:
        """Show the sensor frame (``flange_R_sensor`` = sensor_rotationᵀ) and remember the tool's weight.

        ``calibration`` is an :class:`ftacq.calibration.Calibration`, or None (sensor frame = flange frame).
        """
        with self._lock:
            self._send_pending()  # the states held so far are drawn with the calibration they were logged under
            if calibration is None:
                self._sensor_rotation, self._gravity_base = None, None
                flange_R_sensor = np.eye(3)
            else:
                self._sensor_rotation = np.array(calibration.sensor_rotation)
                self._gravity_base = np.array(calibration.gravity_base)
                flange_R_sensor = self._sensor_rotation.T
            self._static(SENSOR, rr.Transform3D(mat3x3=flange_R_sensor))

    # -- streams ---------------------------------------------------------------------------------------------

    def thin_wrenches(self, every: int) -> None:
        """Log only every ``every``-th wrench sample from now on (:class:`ftacq.decimation.Decimator`)."""
        from ftacq.decimation import Decimator

        with self._lock:
            self.wrench_every = max(1, int(every))
            self._wrench_decimator = Decimator(self.wrench_every) if self.wrench_every > 1 else None

    def log_wrench_batch(self, batch_time_s: np.ndarray, raw: np.ndarray | None,
                         compensated: np.ndarray | None) -> None:
        """Log N samples: ``batch_time_s`` (N,) s on the host monotonic clock, ``raw`` and ``compensated`` (N, 6)
        [N, N·m] sensor frame (either None when not known or already logged). Held, then one ``send_columns`` per
        plot per send period; the compensated force is also drawn as the contact-force arrow at the sensor."""
        time_s = np.asarray(batch_time_s, dtype=np.float64)
        if time_s.shape[0] == 0:
            return
        with self._lock:
            if self._wrench_decimator is not None:
                rows = self._wrench_decimator.keep(time_s.shape[0])
                if not rows.size:
                    return
                time_s = time_s[rows]
                raw = None if raw is None else np.asarray(raw)[rows]
                compensated = None if compensated is None else np.asarray(compensated)[rows]
            if raw is not None:
                raw = np.asarray(raw, dtype=np.float64)
                self._hold_scalars(WRENCH_PATHS[0], time_s, raw[:, :3])
                self._hold_scalars(WRENCH_PATHS[1], time_s, raw[:, 3:])
            if compensated is not None:
                compensated = np.asarray(compensated, dtype=np.float64)
                self._hold_scalars(WRENCH_PATHS[2], time_s, compensated[:, :3])
                self._hold_scalars(WRENCH_PATHS[3], time_s, compensated[:, 3:])
                _, keep = np.unique(np.floor(time_s * CONTACT_ARROW_RATE_HZ), return_index=True)
                keep[-1] = time_s.shape[0] - 1  # the newest sample of its tick: the arrow is as new as the plot
                self._pending_contact.append((time_s[keep], compensated[keep, :3]))
            self._hold(float(time_s.max()), float(time_s.min()))

    def break_lines(self, time_s: float, paths: Sequence[str]) -> None:
        """End the lines of the time series ``paths`` at ``time_s`` (s, host monotonic clock): the next point
        starts a new line (a row of NaN, which the viewer does not join across)."""
        with self._lock:
            for path in paths:
                self._hold_scalars(path, np.array([float(time_s)]), np.full((1, 3), np.nan))
            self._hold(float(time_s), float(time_s))

    def log_fed(self, time_s: np.ndarray, fed: np.ndarray) -> None:
        """Log what ftacq bridge wrote to the controller: ``time_s`` (N,) s (host monotonic clock), ``fed`` (N, 6)
        [N, N·m] in the frame the controller expects (docs/bridge.md)."""
        time_s = np.asarray(time_s, dtype=np.float64)
        if time_s.shape[0] == 0:
            return
        fed = np.asarray(fed, dtype=np.float64)
        with self._lock:
            self._hold_scalars(FED_FORCE, time_s, fed[:, :3])
            self._hold_scalars(FED_TORQUE, time_s, fed[:, 3:])
            self._hold(float(time_s.max()), float(time_s.min()))

    def log_arm(self, time_s: np.ndarray, flange_pose: np.ndarray, q_rad: np.ndarray | None = None) -> None:
        """Log N states of the arm: ``time_s`` (N,) s (host monotonic clock), ``flange_pose`` (N, 6)
        [x, y, z (m), rx, ry, rz (rad)] as the controller reports it, ``q_rad`` (N, 6) joint angles (None: the
        flange frame only). Held, then sent as columns: the DH frames of :meth:`set_arm`, the flange frame, the
        joint-angle plot, the tool's weight arrow (at the flange, base frame) and the two force labels."""
        time_s = np.atleast_1d(np.asarray(time_s, dtype=np.float64))
        flange_pose = np.asarray(flange_pose, dtype=np.float64).reshape(-1, 6)
        if time_s.shape[0] == 0:
            return
        with self._lock:
            if q_rad is not None:
                q_rad = np.asarray(q_rad, dtype=np.float64).reshape(-1, 6)
            if self._pending_arm and (q_rad is None) != (self._pending_arm[-1][2] is None):
                self._send_pending()  # a state without joint angles after some with them: a column each
            self._pending_arm.append((time_s, flange_pose, q_rad))
            self._hold(float(time_s.max()), float(time_s.min()))

    def _send_arm(self, time_s: np.ndarray, flange_pose: np.ndarray, q_rad: np.ndarray | None,
                  contact_time_s: np.ndarray | None, contact_sensor: np.ndarray | None) -> None:
        """Send N held arm states as columns (see :meth:`log_arm`); the contact arrows ``contact_sensor`` (M, 3)
        N at ``contact_time_s`` (M,) s, held with them, give each state's contact label. Caller holds the lock."""
        n = time_s.shape[0]
        base_R_flange = rotation_from_rotvec(flange_pose[:, 3:6]).reshape(n, 3, 3)
        if q_rad is not None:
            self._scalars(JOINT_ANGLES, time_s, q_rad)
            if self.model is not None:
                frames = link_frames(self.model, q_rad)  # (N, 6, 4, 4)
                for i, path in enumerate(LINK_FRAMES):
                    self._send(path, time_s, rr.Transform3D.columns(translation=frames[:, i, :3, 3],
                                                                     mat3x3=frames[:, i, :3, :3]))
        self._send(FLANGE, time_s, rr.Transform3D.columns(translation=flange_pose[:, :3], mat3x3=base_R_flange))
        gravity_base = self._gravity_base
        if gravity_base is not None:
            weight = np.broadcast_to(gravity_base * FORCE_ARROW_SCALE_M_PER_N, (n, 3))
            self._send(GRAVITY, time_s, rr.Arrows3D.columns(
                origins=flange_pose[:, :3], vectors=weight, colors=np.tile(np.array(GRAVITY_COLOR, np.uint8), (n, 1)),
                radii=np.full(n, ARROW_RADIUS_M)))
            contact = np.broadcast_to(self._contact_sensor, (n, 3))
            if contact_time_s is not None and contact_sensor is not None:
                newer = np.searchsorted(contact_time_s, time_s, side="right") - 1  # the contact at each state
                contact = np.where((newer >= 0)[:, None], contact_sensor[np.maximum(newer, 0)], contact)
            self._log_labels(time_s, flange_pose[:, :3], base_R_flange, gravity_base, weight, contact)

    def _log_labels(self, time_s: np.ndarray, origins: np.ndarray, base_R_flange: np.ndarray,
                    gravity_base: np.ndarray, weight: np.ndarray, contact_sensor: np.ndarray) -> None:
        """The "tool weight" and "contact" labels, placed clear of both arrows (:func:`arm.label_anchors`);
        ``gravity_base`` the tool's weight (3,) N, ``weight`` its arrows (n, 3) m, ``contact_sensor`` (n, 3) N the
        compensated force at each state, sensor frame."""
        flange_R_sensor = np.eye(3) if self._sensor_rotation is None else self._sensor_rotation.T
        weight_text = f"tool weight {np.linalg.norm(gravity_base):.1f} N"
        n = time_s.shape[0]
        anchors = np.empty((n, 2, 3))
        texts = []
        for k in range(n):  # per arm state (30 Hz), not per sample
            contact = base_R_flange[k] @ flange_R_sensor @ contact_sensor[k] * FORCE_ARROW_SCALE_M_PER_N
            anchors[k] = label_anchors(origins[k], weight[k], contact)
            texts += [weight_text, f"contact {np.linalg.norm(contact_sensor[k]):.1f} N"]
        columns = rr.Points3D.columns(positions=anchors.reshape(-1, 3), labels=texts,
                                      colors=np.tile(np.array(LABEL_COLORS, np.uint8), (n, 1)),
                                      radii=np.full(2 * n, LABEL_RADIUS_M))
        self._send(LABELS, time_s, columns.partition(np.full(n, 2)))

    def log_health(self, time_s: float, health, dropped: int = 0) -> None:
        """Log a :class:`drivers.sensor.SensorHealth` snapshot at ``time_s`` (s, sensor clock): receive rate [Hz],
        lost / saturated / status-error counts, the last status word, and samples not delivered to the viewer."""
        counts = np.array([[health.lost, health.saturated, health.status_errors, dropped]], dtype=np.float64)
        with self._lock:
            t = np.array([float(time_s)])
            self._hold_scalars(HEALTH_RATE, t, np.array([[health.rate_hz]]))
            self._hold_scalars(HEALTH_COUNTS, t, counts)
            self._hold_scalars(HEALTH_STATUS, t, np.array([[float(health.last_status)]]))
            self._hold(t[0], t[0])

    def log_bias_drift(self, time_s: float, offset: np.ndarray, sigma: np.ndarray) -> None:
        """Log the drift tracker's bias offset from the calibration file (6,) [N, N·m] with ±1σ at ``time_s``."""
        offset, sigma = np.asarray(offset, dtype=float), np.asarray(sigma, dtype=float)
        with self._lock:
            t = np.array([float(time_s)])
            for path, part in ((BIAS_DRIFT_FORCE, slice(0, 3)), (BIAS_DRIFT_TORQUE, slice(3, 6))):
                o, s = offset[part], sigma[part]
                self._hold_scalars(path, t, np.concatenate([o, o + s, o - s])[None, :])
            self._hold(t[0], t[0])

    def log_text(self, text: str, *, level: str = "INFO", time_s: float | None = None, path: str = MONITOR_LOG) -> None:
        """Append a line to the text log (``path`` under ``log/``) at ``time_s`` (s, sensor clock; default now)."""
        with self._lock:
            self._at(time.monotonic() if time_s is None else time_s, path, rr.TextLog(text, level=level))

    # -- calibration procedure -------------------------------------------------------------------------------

    def log_plan(self, time_s: float, poses: np.ndarray, labels: Sequence[str], set_names: Sequence[str]) -> None:
        """Draw every planned flange pose (N, 6) as a small frame coloured by its set (A, E, V)."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 6)
        rotations = rotation_from_rotvec(poses[:, 3:6]).reshape(-1, 3, 3)  # base_R_flange (N, 3, 3)
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
        pose = np.asarray(pose, dtype=np.float64)
        with self._lock:
            self._at(time_s, CURRENT_POSE, rr.Points3D([pose[:3]], radii=[0.015], colors=[CURRENT_POSE_COLOR],
                                                       labels=[text], show_labels=True))

    def log_pose_measured(self, time_s: float, index: int, mean: np.ndarray) -> None:
        """Log the averaged wrench (6,) [N, N·m] of pose ``index`` on both timelines."""
        mean = np.asarray(mean, dtype=np.float64)
        with self._lock:
            self._scalars(MEASURED_FORCE, np.array([time_s]), mean[None, :3], np.array([index]))
            self._scalars(MEASURED_TORQUE, np.array([time_s]), mean[None, 3:], np.array([index]))

    def log_residuals(self, time_s: float, residuals: np.ndarray, pose_indices: np.ndarray | None = None) -> None:
        """Log identification residuals (N, 6) [N, N·m] per pose: per axis on the ``pose`` timeline and as bar
        charts of their norms."""
        residuals = np.asarray(residuals, dtype=np.float64).reshape(-1, 6)
        n = residuals.shape[0]
        indices = np.arange(n) if pose_indices is None else np.asarray(pose_indices)
        with self._lock:
            if n:
                times = np.full(n, float(time_s))
                self._scalars(RESIDUAL_FORCE, times, residuals[:, :3], indices)
                self._scalars(RESIDUAL_TORQUE, times, residuals[:, 3:], indices)
            self._at(time_s, RESIDUAL_FORCE_NORM, rr.BarChart(np.linalg.norm(residuals[:, :3], axis=1),
                                                              color=AXIS_COLORS[2]))
            self._at(time_s, RESIDUAL_TORQUE_NORM, rr.BarChart(np.linalg.norm(residuals[:, 3:], axis=1),
                                                               color=AXIS_COLORS[0]))

    def log_validation(self, time_s: float, errors: np.ndarray) -> None:
        """Log the compensation errors (M, 6) on the validation poses as a bar chart of force-error norms."""
        errors = np.asarray(errors, dtype=np.float64).reshape(-1, 6)
        with self._lock:
            self._at(time_s, VALIDATION_FORCE_NORM, rr.BarChart(np.linalg.norm(errors[:, :3], axis=1),
                                                                color=SET_COLORS[VALIDATION_SET]))

    def flush(self, timeout_s: float = RECORDING_FLUSH_TIMEOUT_S) -> None:
        """Send the columns still held and push everything logged so far to the sink, waiting at most
        ``timeout_s`` seconds."""
        self.flush_columns()
        self.recording.flush(timeout_sec=timeout_s)


__all__ = ["Dashboard"]
