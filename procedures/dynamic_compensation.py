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
    that does not count samples (a polled sensor) leaves the arrival stamps.

    Cost per read (≈ 14 samples in the bridge): the least-squares sums as running Python floats, and the envelope's
    candidates kept as offsets (arrival − sequence·period) in a ring, re-evaluated over the ring only when the
    period changes (never while the nominal one holds); the same arithmetic as evaluating every candidate each read.
    """

    def __init__(self, counts_samples: bool = True, nominal_period_s: float | None = None) -> None:
        self._usable = counts_samples
        self._nominal_period_s = nominal_period_s if nominal_period_s and nominal_period_s > 0 else None
        self._restart()

    def _restart(self) -> None:
        self._origin: tuple[float, float] | None = None
        self._n = 0
        self._sum_s = self._sum_a = self._sum_ss = self._sum_sa = 0.0  # Σs, Σa, Σs², Σsa (relative to the origin)
        self._points = np.empty((2, ENVELOPE_READS))  # per read: (s, a) of the sample closest to the envelope (a ring)
        self._candidates = np.empty(ENVELOPE_READS)  # a − s·period of each point, for _candidates_period
        self._scratch = np.empty(ENVELOPE_READS)
        self._candidates_period = np.nan
        self._point_count = 0
        self._last = -np.inf

    def host_times(self, arrival_s: np.ndarray, sequence: np.ndarray) -> np.ndarray:
        arrival = np.asarray(arrival_s, dtype=float)
        if not self._usable or arrival.size == 0:
            return arrival
        seq = np.asarray(sequence, dtype=float)
        if seq.size > 1 and np.less_equal(seq[1:], seq[:-1]).any():
            return arrival  # a restart inside one read: this read keeps its arrival stamps
        # a restarted count starts a new run; a gap in arrival with the count going on (the host stalled, records
        # were lost or delayed) does not: the device's own clock ran on, and the lower envelope already ignores delay
        if self._origin is not None and seq[0] - self._origin[0] <= self._last:
            self._restart()
        if self._origin is None:
            self._origin = (float(seq[0]), float(arrival[0]))
        add = np.add.reduce
        s, a = seq - self._origin[0], arrival - self._origin[1]
        self._last = float(s[-1])
        self._n += s.size
        self._sum_s += add(s)
        self._sum_a += add(a)
        self._sum_ss += add(s * s)
        self._sum_sa += add(s * a)
        nominal = self._nominal_period_s
        if nominal is not None and self._last * nominal < PERIOD_FIT_SPAN_S:
            period = nominal
        else:
            n, ss, sa, sss, ssa = self._n, self._sum_s, self._sum_a, self._sum_ss, self._sum_sa
            denominator = n * sss - ss * ss
            if n < 50 or denominator <= 0:
                return arrival
            period = float((n * ssa - ss * sa) / denominator)
            if not period > 0:
                return arrival
        shift = s * period
        below = a - shift
        best = int(below.argmin())
        slot = self._point_count % ENVELOPE_READS
        self._points[0, slot], self._points[1, slot] = s[best], a[best]
        self._point_count += 1
        kept = min(self._point_count, ENVELOPE_READS)
        candidates = self._candidates[:kept]
        if period == self._candidates_period:
            candidates[slot] = below[best]  # the same a − s·period as the whole ring's below
        else:
            scratch = self._scratch[:kept]
            np.multiply(self._points[0, :kept], period, out=scratch)
            np.subtract(self._points[1, :kept], scratch, out=candidates)
            self._candidates_period = period
        offset = float(candidates.min())
        shift += self._origin[1]
        shift += offset
        return shift


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
