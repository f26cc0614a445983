"""Live dynamic compensation: the monitor's :class:`~procedures.monitor.Compensator` for a calibration with inertia
(and the controller bridge's, procedures/bridge.py).

Per sensor batch (≈ 10 ms, 70 samples at 7 kHz in the monitor; 2 ms, 14 samples in the bridge): the samples are put
on the host clock through their sequence numbers (:class:`SensorClock`), shifted by the lag the identification
measured, and compensated as :func:`ftacq.dynamics.compensate_moving` does: the rigid-body model
(:class:`ftacq.dynamics.model.WrenchPredictor`, Pinocchio's RNEA) is evaluated once per new 500 Hz robot state from
:class:`drivers.ur_stream.URStateStream` (predictions are kept in a ring, not recomputed for the next batch) and
interpolated onto the samples. The acceleration is target_qdd while the arm tracks the controller's trajectory, else
a filtered derivative (:mod:`ftacq.dynamics.acceleration`), taken for the new states only. A batch without robot
states around it (the stream is late or lost) is compensated statically and counted in
:attr:`DynamicCompensator.static_batches`.
"""

from __future__ import annotations

import numpy as np

from ftacq.calibration import Calibration
from ftacq.dynamics.acceleration import DERIVATIVE_HALF_WIDTH, joint_acceleration
from ftacq.dynamics.model import SensorDynamics, WrenchPredictor
from ftacq.dynamics.timing import interpolate_rows
from ftacq.kinematics import URModel
from ftacq.so3 import rotation_from_rotvec

STATE_WINDOW_ROWS = 64
"""Newest robot states looked at per batch (128 ms at 500 Hz), and predictions kept."""
TAIL_ROWS = 16
"""Newest robot states read per batch when few are new (the bridge: one per controller cycle; the monitor: about
five per 10 ms batch)."""
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

    Args: calibration (``has_dynamics``), robot (the arm's model), stream (a started URStateStream, or anything with
    its ``window(last=…)``), lag_s (the sensor's lag behind the robot stream; default the one the identification
    measured), counts_samples and sample_rate_hz (the sensor's reported rate, Hz: its nominal period for
    :class:`SensorClock`).

    Per batch it reads the newest :data:`TAIL_ROWS` states (all :data:`STATE_WINDOW_ROWS` when the new ones reach
    into their first :data:`~ftacq.dynamics.acceleration.DERIVATIVE_HALF_WIDTH`: the derivative needs that many
    older neighbours), takes q̈ for the new states only, runs the model once per new state
    (:class:`ftacq.dynamics.model.WrenchPredictor`) and keeps the newest :data:`STATE_WINDOW_ROWS` predictions in a
    ring. The result equals evaluating the whole window each batch and keeping the new rows.
    """

    def __init__(self, calibration: Calibration, robot: URModel, stream, lag_s: float | None = None,
                 counts_samples: bool = True, sample_rate_hz: float | None = None) -> None:
        if not calibration.has_dynamics:
            raise ValueError("the calibration has no inertia: use the static GravityCompensator")
        self.calibration = calibration
        self.stream = stream
        self.dynamics = SensorDynamics.for_calibration(robot, calibration)
        self.predictor = WrenchPredictor(self.dynamics, calibration)
        measured = calibration.metadata.get("dynamics", {}).get("lag_ms") if isinstance(
            calibration.metadata.get("dynamics"), dict) else None
        self.lag_s = float(lag_s if lag_s is not None else (measured or 0.0) / 1e3)
        self.clock = SensorClock(counts_samples, 1.0 / sample_rate_hz if sample_rate_hz else None)
        # the newest STATE_WINDOW_ROWS predictions, written twice (at k and k + rows) so that they are always one
        # contiguous slice, oldest first
        self._ring_times = np.empty(2 * STATE_WINDOW_ROWS)
        self._ring_predicted = np.empty((2 * STATE_WINDOW_ROWS, 6))
        self._predictions = 0
        self._last_controller_time = -np.inf
        self.static_batches = 0
        self.dynamic_batches = 0
        self.derivative_states = 0

    def _kept(self) -> tuple[np.ndarray, np.ndarray]:
        """(host times (K,), predicted wrenches (K, 6)) of the newest K ≤ STATE_WINDOW_ROWS states, oldest first."""
        count = self._predictions
        start = count % STATE_WINDOW_ROWS if count >= STATE_WINDOW_ROWS else 0
        stop = start + min(count, STATE_WINDOW_ROWS)
        return self._ring_times[start:stop], self._ring_predicted[start:stop]

    def _update_predictions(self) -> None:
        window = self.stream.window(last=TAIL_ROWS)
        new = window.controller_time_s > self._last_controller_time
        fresh = int(np.count_nonzero(new))
        if fresh == 0:
            return
        size = len(window)
        first = size - fresh
        if new[first] and (first >= DERIVATIVE_HALF_WIDTH or size < TAIL_ROWS) and (fresh == 1 or new[first:].all()):
            rows: list[int] = list(range(first, size))  # the usual case: the newest few states are the new ones
            low = max(first - DERIVATIVE_HALF_WIDTH, 0)
        else:  # many new states (the first batch, a stall): the whole window, as before
            window = self.stream.window(last=STATE_WINDOW_ROWS)
            new = window.controller_time_s > self._last_controller_time
            rows = np.flatnonzero(new).tolist()
            size = len(window)
            contiguous = rows[-1] - rows[0] == len(rows) - 1
            low = max(rows[0] - DERIVATIVE_HALF_WIDTH, 0) if contiguous else 0
        # q̈ of the new states and of the older neighbours their derivative reaches: row by row as over the window
        qdd, tracking = joint_acceleration(window.time_s[low:], window.qd[low:], window.target_qd[low:],
                                           window.qdd[low:])
        self.derivative_states += len(rows) - int(np.count_nonzero(tracking[[row - low for row in rows]]))
        q, qd, time_s = window.q, window.qd, window.time_s
        ring_times, ring_predicted, predict = self._ring_times, self._ring_predicted, self.predictor.predict_one
        for row in rows:
            slot = self._predictions % STATE_WINDOW_ROWS
            predict(q[row], qd[row], qdd[row - low], ring_predicted[slot])
            ring_predicted[slot + STATE_WINDOW_ROWS] = ring_predicted[slot]
            ring_times[slot] = ring_times[slot + STATE_WINDOW_ROWS] = time_s[row]
            self._predictions += 1
        self._last_controller_time = float(window.controller_time_s[-1])

    def compensate(self, batch, robot) -> np.ndarray | None:
        """Return the contact wrench (N, 6) of ``batch``; statically compensated (and counted) without states."""
        times = self.clock.host_times(batch.time_s, batch.sequence) - self.lag_s
        self._update_predictions()
        state_times, predicted = self._kept()
        if state_times.size >= 2 and times[0] >= state_times[0] and times[-1] <= state_times[-1] + MAX_STATE_GAP_S:
            self.dynamic_batches += 1
            contact = interpolate_rows(times, state_times, predicted)
            return np.subtract(batch.wrench, contact, out=contact)
        self.static_batches += 1
        if robot is None:
            return None
        return self.calibration.compensate(batch.wrench, rotation_from_rotvec(np.asarray(robot.flange_pose)[3:6]).T)
