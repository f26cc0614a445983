"""Live dynamic compensation: the monitor's :class:`~procedures.monitor.Compensator` for a calibration with inertia.

Per sensor batch (≈ 10 ms, 70 samples at 7 kHz): the samples are put on the host clock through their sequence
numbers (:class:`SensorClock`), shifted by the lag the identification measured, and compensated with
:func:`ftacq.dynamics.compensate_moving`; the rigid-body model is evaluated once per new 500 Hz robot state from
:class:`drivers.ur_stream.URStateStream` (predictions are kept, not recomputed for the next batch) and interpolated
onto the samples. The acceleration is target_qdd while the arm tracks the controller's trajectory, else a
filtered derivative (:mod:`ftacq.dynamics.acceleration`). A batch without robot states around it (the stream is
late or lost) is compensated statically and counted in :attr:`DynamicCompensator.static_batches`.
"""

from __future__ import annotations

import numpy as np

from ftacq.calibration import Calibration
from ftacq.dynamics.acceleration import joint_acceleration
from ftacq.dynamics.model import SensorDynamics, predict_moving
from ftacq.dynamics.timing import interpolate_rows
from ftacq.kinematics import URModel
from ftacq.so3 import rotation_from_rotvec

STATE_WINDOW_ROWS = 64
"""Newest robot states looked at per batch (128 ms at 500 Hz)."""
MAX_STATE_GAP_S = 0.05
"""A batch whose samples are further than this from the newest robot state is compensated statically, s."""
ENVELOPE_READS = 2000
"""Reads (≈ 20 s) over which the sensor clock's lower envelope is taken."""
PERIOD_FIT_SPAN_S = 10.0
"""A run shorter than this keeps the sensor's nominal period (when known): a least-squares period over a few
seconds of delayed arrivals is off by far more than the device clock's error (ppm), s."""


class SensorClock:
    """Host times of a sensor's samples from its sequence numbers (its own clock) and the arrival stamps: the
    period by least squares over the current run, the offset as the lower envelope of (arrival − sequence·period)
    over the run's recent reads (one candidate kept per read, re-evaluated with the newest period). A restarted count
    starts a new run; a stall of the host or of the link does not (the device's clock ran on). With ``nominal_period_s``
(the rate the device reports) a run shorter than :data:`PERIOD_FIT_SPAN_S` uses it instead of the fit. A sequence
that does not count samples (a polled sensor) leaves the arrival stamps."""

    def __init__(self, counts_samples: bool = True, nominal_period_s: float | None = None) -> None:
        self._usable = counts_samples
        self._nominal_period_s = nominal_period_s if nominal_period_s and nominal_period_s > 0 else None
        self._restart()

    def _restart(self) -> None:
        self._origin: tuple[float, float] | None = None
        self._sums = np.zeros(5)  # n, Σs, Σa, Σs², Σsa (relative to the origin)
        self._points = np.empty((ENVELOPE_READS, 2))  # per read: the sample closest to the envelope (a ring)
        self._point_count = 0
        self._last = -np.inf

    def host_times(self, arrival_s: np.ndarray, sequence: np.ndarray) -> np.ndarray:
        arrival = np.asarray(arrival_s, dtype=float)
        seq = np.asarray(sequence, dtype=float)
        if not self._usable or arrival.size == 0:
            return arrival
        if np.any(np.diff(seq) <= 0):
            return arrival  # a restart inside one read: this read keeps its arrival stamps
        # a restarted count starts a new run; a gap in arrival with the count going on (the host stalled, records
        # were lost or delayed) does not: the device's own clock ran on, and the lower envelope already ignores delay
        if self._origin is not None and seq[0] - self._origin[0] <= self._last:
            self._restart()
        if self._origin is None:
            self._origin = (float(seq[0]), float(arrival[0]))
        s, a = seq - self._origin[0], arrival - self._origin[1]
        self._last = float(s[-1])
        self._sums += (s.size, s.sum(), a.sum(), (s * s).sum(), (s * a).sum())
        n, ss, sa, sss, ssa = self._sums
        nominal = self._nominal_period_s
        if nominal is not None and self._last * nominal < PERIOD_FIT_SPAN_S:
            period = nominal
        else:
            denominator = n * sss - ss * ss
            if n < 50 or denominator <= 0:
                return arrival
            period = (n * ssa - ss * sa) / denominator
            if not period > 0:
                return arrival
        best = int(np.argmin(a - s * period))
        self._points[self._point_count % ENVELOPE_READS] = s[best], a[best]
        self._point_count += 1
        points = self._points[:min(self._point_count, ENVELOPE_READS)]
        offset = float(np.min(points[:, 1] - points[:, 0] * period))
        return self._origin[1] + s * period + offset


class DynamicCompensator:
    """Compensates gravity and the tool's inertial wrench (calibration with inertia) with the RTDE state stream.

    Args: calibration (``has_dynamics``), robot (the arm's model), stream (a started URStateStream),
    lag_s (the sensor's lag behind the robot stream; default the one the identification measured),
    counts_samples and sample_rate_hz (the sensor's reported rate, Hz: its nominal period for :class:`SensorClock`).
    """

    def __init__(self, calibration: Calibration, robot: URModel, stream, lag_s: float | None = None,
                 counts_samples: bool = True, sample_rate_hz: float | None = None) -> None:
        if not calibration.has_dynamics:
            raise ValueError("the calibration has no inertia: use the static GravityCompensator")
        self.calibration = calibration
        self.stream = stream
        self.dynamics = SensorDynamics.for_calibration(robot, calibration)
        measured = calibration.metadata.get("dynamics", {}).get("lag_ms") if isinstance(
            calibration.metadata.get("dynamics"), dict) else None
        self.lag_s = float(lag_s if lag_s is not None else (measured or 0.0) / 1e3)
        self.clock = SensorClock(counts_samples, 1.0 / sample_rate_hz if sample_rate_hz else None)
        self._times = np.empty(0)
        self._predicted = np.empty((0, 6))
        self._last_controller_time = -np.inf
        self.static_batches = 0
        self.dynamic_batches = 0
        self.derivative_states = 0

    def _update_predictions(self) -> None:
        window = self.stream.window(last=STATE_WINDOW_ROWS)
        new = window.controller_time_s > self._last_controller_time
        if not np.any(new):
            return
        qdd, tracking = joint_acceleration(window.time_s, window.qd, window.target_qd, window.qdd)
        self.derivative_states += int(np.count_nonzero(~tracking[new]))
        predicted = predict_moving(self.dynamics, self.calibration, window.q[new], window.qd[new], qdd[new])
        self._times = np.concatenate([self._times, window.time_s[new]])[-STATE_WINDOW_ROWS:]
        self._predicted = np.vstack([self._predicted, predicted])[-STATE_WINDOW_ROWS:]
        self._last_controller_time = float(window.controller_time_s[-1])

    def compensate(self, batch, robot) -> np.ndarray | None:
        """Return the contact wrench (N, 6) of ``batch``; statically compensated (and counted) without states."""
        times = self.clock.host_times(batch.time_s, batch.sequence) - self.lag_s
        self._update_predictions()
        if self._times.size >= 2 and times[0] >= self._times[0] and times[-1] <= self._times[-1] + MAX_STATE_GAP_S:
            self.dynamic_batches += 1
            return batch.wrench - interpolate_rows(times, self._times, self._predicted)
        self.static_batches += 1
        if robot is None:
            return None
        return self.calibration.compensate(batch.wrench, rotation_from_rotvec(np.asarray(robot.flange_pose)[3:6]).T)
