"""The dashboard as a listener: :mod:`procedures.events` (calibration and monitor alike) → :class:`Dashboard` logs.

Calibration: plan → every pose as a frame coloured by set; state changes → the current pose and a log line; each
measured pose → its averaged wrench and the arm where it was measured; identification → residuals per pose, and
the compensated wrench of the whole run so far (see below); validation → errors per V pose.
Stream (the monitor, and every sensor read of the calibration): samples → the four wrench plots; robot states →
the arm, sent as columns about every :data:`ARM_SEND_PERIOD_S`; sensor status → health plots; notices → the log.

During a calibration the compensated wrench cannot be known before the identification: the listener keeps the
raw samples of every averaging window, thinned to at most :data:`BACKFILL_RATE_HZ` and
:data:`BACKFILL_MAX_SAMPLES`, with the pose they were measured at (PoseMeasured: window and pose), and when the
calibration is identified logs their compensated wrench on the same times (it should be ≈ 0: no contact while
calibrating); later samples are compensated as they come. Settling samples get no compensated value: the driver
may still hold samples from before the move when settling starts. The compensated lines end with each averaging
window (a NaN row after its last sample), so the plot never joins two windows across the move between them.

The bridge (FedWrenches) draws what it fed, and the arm from the joint angles of the controller cycles it fed in
(thinned to :data:`ARM_RATE_HZ`).
"""

from __future__ import annotations

import logging
import time
from typing import Callable

import numpy as np

from ftacq.app.dashboard.arm import link_frames
from ftacq.app.dashboard.layout import CALIBRATION_LOG, COMPENSATED_FORCE, COMPENSATED_TORQUE, LOG, LOG_PATHS
from ftacq.app.dashboard.recorder import Dashboard
from ftacq.kinematics import URModel
from ftacq.so3 import rotation_from_rotvec, rotvec_from_rotation
from procedures import events

log = logging.getLogger(__name__)

ARM_SEND_PERIOD_S = 0.2
"""Robot states are sent in columns of this many seconds (sensor clock), and at every sensor status."""
BACKFILL_RATE_HZ = 1000.0
"""Raw samples kept for the compensated plot of a calibration, at most this many per second."""
BACKFILL_MAX_SAMPLES = 1_500_000
"""… and at most this many in all (≈ 25 min at BACKFILL_RATE_HZ; ≈ 80 MB)."""
ARM_RATE_HZ = 30.0
"""Arm states drawn per second at most (from samples that carry a pose, or from the bridge's controller cycles)."""
LINE_BREAK_AFTER_S = 1e-6
"""The NaN row that ends a window's line sits this long after its last sample (well under a sample period)."""
COMPENSATED_PATHS = (COMPENSATED_FORCE, COMPENSATED_TORQUE)


class DashboardListener:
    """A :data:`procedures.events.Listener` that draws the procedures' events on a :class:`Dashboard`.

    ``model`` (a :class:`ftacq.kinematics.URModel`) draws the arm (without it: the flange frame only).
    ``clock_s`` stamps the calibration's events (host monotonic clock, as the samples). Call :meth:`flush` at the
    end (sends the robot states still buffered). It never raises into the caller unless the dashboard is strict.
    """

    def __init__(self, dashboard: Dashboard, model: URModel | None = None,
                 clock_s: Callable[[], float] = time.monotonic) -> None:
        self.dashboard = dashboard
        self.model = model
        if model is not None:
            dashboard.set_arm(model)
        self._clock_s = clock_s
        self._calibration = None
        self._poses: np.ndarray | None = None
        self._labels: tuple[str, ...] = ()
        self._set_names: tuple[str, ...] = ()
        self._arm: list[events.RobotState] = []
        self._last_arm_s = -np.inf
        self._robot_events = False  # RobotState events come (the monitor): the samples' robot state is not needed
        self._backfill: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]] | None = None
        """(time_s, wrench, pose, window): raw samples of the averaging windows, kept for the compensated plot."""
        self._unplaced: list[tuple[np.ndarray, np.ndarray]] = []  # (time_s, wrench) read since the last pose
        self._backfill_samples = 0
        self._window = 0  # the averaging window being read: PoseMeasured events so far
        self._fed_arm_tick = -np.inf  # the last 1/ARM_RATE_HZ tick the bridge's arm was drawn in

    def __call__(self, event: events.Event) -> None:
        try:
            self._handle(event)
        except Exception:  # noqa: BLE001 - a broken viewer must never stop the robot
            if self.dashboard.strict:
                raise
            log.warning("dashboard listener failed on %s", type(event).__name__, exc_info=True)

    def set_calibration(self, calibration) -> None:
        """Compensate (and draw the sensor frame and tool weight) with ``calibration`` from now on."""
        self._calibration = calibration
        self.dashboard.set_calibration(calibration)

    def flush(self) -> None:
        """Send the robot states still buffered."""
        self._send_arm()

    # -- the stream --------------------------------------------------------------------------------------------

    def _samples(self, event: events.WrenchSamples) -> None:
        batch = event.batch
        compensated = event.compensated
        if (compensated is None and not event.uncompensated and self._calibration is not None
                and event.flange_pose is not None):  # (not a batch the live compensation left raw: no pose of its time)
            compensated = self._calibration.compensate(
                batch.wrench, rotation_from_rotvec(np.asarray(event.flange_pose)[3:6]).T)
        self.dashboard.log_wrench_batch(batch.time_s, batch.wrench, compensated)
        backfill = self._backfill
        if compensated is None and backfill is not None:
            self._keep_for_backfill(backfill, batch.time_s, batch.wrench, event.flange_pose)
        if not self._robot_events and event.flange_pose is not None and event.joint_positions_rad is not None:
            now_s = float(batch.time_s[-1])
            if now_s - self._last_arm_s >= 1.0 / ARM_RATE_HZ:
                self._robot(events.RobotState(now_s, event.joint_positions_rad, event.flange_pose))

    def _keep_for_backfill(self, backfill: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]], time_s: np.ndarray,
                           wrench: np.ndarray, pose: np.ndarray | None) -> None:
        """Keep thinned raw samples (placed ones in ``backfill``, the listener's list); without a pose they wait for the next PoseMeasured (the arm is still while
        the procedure reads the sensor)."""
        if self._backfill_samples >= BACKFILL_MAX_SAMPLES:
            return
        _, keep = np.unique(np.floor(time_s * BACKFILL_RATE_HZ), return_index=True)
        keep = keep[: BACKFILL_MAX_SAMPLES - self._backfill_samples]
        part = (time_s[keep], wrench[keep].astype(np.float32))
        if pose is None:
            self._unplaced.append(part)
        else:
            backfill.append((*part, np.asarray(pose, dtype=float), self._window))
        self._backfill_samples += keep.size

    def _place_backfill(self, event: events.PoseMeasured) -> None:
        """Keep the samples of the pose's averaging window (the arm surely still at ``event.pose``); the others
        read since the last measured pose (settling, and what the driver held from before the move) get none."""
        unplaced, self._unplaced = self._unplaced, []
        window, self._window = self._window, self._window + 1
        if self._backfill is None:
            return
        pose = np.asarray(event.pose, dtype=float)
        if event.t_start_s is None or event.t_end_s is None:
            self._backfill += [(t, w, pose, window) for t, w in unplaced]
            return
        unix_minus_monotonic_s = time.time() - time.monotonic()  # the window is in UNIX time, samples monotonic
        start_s, end_s = event.t_start_s - unix_minus_monotonic_s, event.t_end_s - unix_minus_monotonic_s
        for t, w in unplaced:
            inside = (t >= start_s) & (t <= end_s)
            if inside.any():
                self._backfill.append((t[inside], w[inside], pose, window))

    def _log_backfill(self) -> None:
        """Log the compensated wrench of the samples kept before the calibration was known."""
        parts, self._backfill = self._backfill or [], None
        if not parts or self._calibration is None:
            return
        time_s = np.concatenate([t for t, _, _, _ in parts])
        wrench = np.concatenate([w for _, w, _, _ in parts]).astype(np.float64)
        sizes = [t.size for t, _, _, _ in parts]
        flange_R_base = np.repeat(np.stack([rotation_from_rotvec(p[3:6]).T for _, _, p, _ in parts]), sizes, axis=0)
        window = np.repeat([k for _, _, _, k in parts], sizes)
        compensated = self._calibration.compensate(wrench, flange_R_base)
        ends = np.flatnonzero(np.diff(window)) + 1  # where the next window starts
        for rows in np.split(np.arange(time_s.size), ends):  # a line per window, ended by a NaN row
            self.dashboard.log_wrench_batch(time_s[rows], None, compensated[rows])  # raw: logged as it came
            self.dashboard.break_lines(float(time_s[rows].max()) + LINE_BREAK_AFTER_S, COMPENSATED_PATHS)

    def _fed_arm(self, event: events.FedWrenches) -> None:
        """The arm in the controller cycles the bridge fed, at most :data:`ARM_RATE_HZ` (flange pose by the DH
        model, as the link frames)."""
        q = event.joint_positions_rad
        if q is None or self.model is None or not len(event.time_s):
            return
        time_s = np.asarray(event.time_s, dtype=float)
        q = np.asarray(q, dtype=float).reshape(-1, 6)
        keep = np.flatnonzero(np.isfinite(time_s) & np.isfinite(q).all(axis=1))
        tick = np.floor(time_s[keep] * ARM_RATE_HZ)
        _, first = np.unique(tick, return_index=True)  # the first cycle of each 1/ARM_RATE_HZ tick …
        keep = keep[first[tick[first] > self._fed_arm_tick]]  # … not drawn yet
        if not keep.size:
            return
        base_T_flange = link_frames(self.model, q[keep])[:, 5]
        pose = np.hstack([base_T_flange[:, :3, 3], rotvec_from_rotation(base_T_flange[:, :3, :3]).reshape(-1, 3)])
        self._fed_arm_tick = float(np.floor(time_s[keep[-1]] * ARM_RATE_HZ))
        self.dashboard.log_arm(time_s[keep], pose, q[keep])

    def _robot(self, event: events.RobotState) -> None:
        self._arm.append(event)
        self._last_arm_s = float(event.time_s)
        if self._arm[-1].time_s - self._arm[0].time_s >= ARM_SEND_PERIOD_S:
            self._send_arm()

    def _send_arm(self) -> None:
        states, self._arm = self._arm, []
        if not states:
            return
        self.dashboard.log_arm(np.array([s.time_s for s in states]), np.array([s.flange_pose for s in states]),
                               None if self.model is None else np.array([s.joint_positions_rad for s in states]))

    # -- dispatch ----------------------------------------------------------------------------------------------

    def _handle(self, event: events.Event) -> None:
        dash = self.dashboard
        if isinstance(event, events.WrenchSamples):
            self._samples(event)
        elif isinstance(event, events.RobotState):
            self._robot_events = True
            self._robot(event)
        elif isinstance(event, events.SensorStatus):
            self._send_arm()
            dash.log_health(event.time_s, event.health, dropped=event.dropped)
        elif isinstance(event, events.BiasDrift):
            dash.log_bias_drift(event.time_s, event.offset, event.sigma)
        elif isinstance(event, events.FedWrenches):
            dash.log_fed(event.time_s, event.fed)
            self._fed_arm(event)
        elif isinstance(event, events.Notice):
            dash.log_text(event.text, level=event.level, time_s=event.time_s,
                          path=LOG_PATHS.get(event.source, f"{LOG}/{event.source}"))
        else:
            self._procedure(event)

    def _procedure(self, event: events.Event) -> None:
        now = self._clock_s()
        dash = self.dashboard
        if isinstance(event, events.PlanReady):
            self._backfill, self._backfill_samples = [], 0
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
            if event.state in ("done", "stopped", "failed"):
                self._send_arm()
        elif isinstance(event, events.PoseMeasured):
            dash.log_pose_measured(now, event.index, event.mean)
            if self._calibration is not None and event.t_end_s is not None:  # compensated live: end the line
                end_s = event.t_end_s - (time.time() - time.monotonic())
                dash.break_lines(end_s + LINE_BREAK_AFTER_S, COMPENSATED_PATHS)
            self._place_backfill(event)
            self._send_arm()
            dash.log_arm(np.array([now]), np.asarray(event.pose)[None, :],
                         None if self.model is None else np.asarray(event.joint_positions_rad)[None, :])
            if event.saturated or event.lost:
                dash.log_text(f"pose {event.index} {event.label}: {event.saturated} saturated, {event.lost} lost",
                              level="WARN", time_s=now, path=CALIBRATION_LOG)
        elif isinstance(event, events.Identified):
            indices = np.array([self._labels.index(label) if label in self._labels else i
                                for i, label in enumerate(event.labels)], dtype=np.int64)
            self.set_calibration(event.calibration)
            dash.log_residuals(now, event.residuals, indices)
            self._log_backfill()
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


__all__ = ["DashboardListener", "ARM_SEND_PERIOD_S"]
