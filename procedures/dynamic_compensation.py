"""Live dynamic compensation: the monitor's :class:`~procedures.monitor.Compensator` for a calibration with inertia
(and the controller bridge's, procedures/bridge.py).

Per sensor batch (≈ 10 ms, 70 samples at 7 kHz in the monitor; 2 ms, 14 samples in the bridge): the samples are put
on the host clock through the device's own sample times (:class:`ftacq.timebase.SampleClock`: the minimum-delay
line, docs/dynamics.md "How the clocks are aligned"), shifted by the lag the identification measured, and compensated
as :func:`ftacq.dynamics.compensate_moving` does: the rigid-body model (:class:`ftacq.dynamics.model.WrenchPredictor`,
Pinocchio's RNEA) is evaluated once per new robot state (500 Hz; 125 Hz on a CB3) from
:class:`drivers.ur_stream.URStateStream` (predictions are kept in a ring of :data:`PREDICTION_WINDOW_S`, not
recomputed for the next batch) and
interpolated onto the samples, a moveJ's steps of q̈ switched where they are located inside the state interval
(:meth:`DynamicCompensator._locate_steps`; linearly they were smeared over 8-12 ms on a CB3). The state is the physical arm's: ``actual_q``, ``actual_qd`` and, while the arm tracks
the controller's trajectory, ``target_qdd`` of the servo lag earlier (the lag the identification measured,
``dynamics.servo_lag_ms``), else a filtered derivative (:mod:`ftacq.dynamics.acceleration`), taken for the new
states only.

A batch whose newest samples are newer than the newest robot state (the RTDE reader thread was held off, a state
package is still on its way) waits for the states of its time, at most ``state_wait_s`` (:data:`STATE_WAIT_S` in
the monitor, whose record may come a few ms later; 0 in the bridge, which answers the controller's cycle now and
holds the newest prediction instead; ``monitor --ros2`` holds it for samples up to ``hold_s`` ahead and waits only
for reads further ahead): under load the reader fell up to 50 ms behind the sensor reads, and a
prediction held over that is wrong by dW/dt × 50 ms (issue 27). A stream that stays silent through one wait is not
waited for again until it delivers a state.

A batch older than the kept predictions (the monitor's first read, which holds the samples since the sensor
started, seconds when the start-up was slow; a reader that fell behind by more than the ring) is predicted from the
states of its own span, when the stream still keeps them (:meth:`DynamicCompensator._predictions_over`: the model
once per state of the span, the ring left as it is; counted in :attr:`DynamicCompensator.catch_up_batches`). Without
it, a first read of 2 s that began 50 ms before the oldest kept prediction was compensated statically throughout a
jog move (1.1 N RMS of inertial wrench left in, issue 27).

A batch neither the kept predictions nor a catch-up covers (the reader fell behind by more than
:data:`CATCH_UP_MAX_S`, or the state stream is late) is compensated statically with the flange orientation *at the samples' time*, interpolated (slerp) from the state
stream's rows by :class:`procedures.flange_orientation.FlangeOrientations`, as :mod:`procedures.static_compensation`
does for a calibration without inertia (counted in :attr:`DynamicCompensator.static_batches`); when no robot state lies within
:data:`MAX_STATE_GAP_S` of the samples (the stream is lost or far behind) the batch is left uncompensated:
:meth:`DynamicCompensator.compensate` returns None (the monitor then publishes and records it without a contact
wrench) and counts it in :attr:`DynamicCompensator.uncompensated_batches`. Never a pose from another time.
"""

from __future__ import annotations

import time

import numpy as np

from ftacq.calibration import Calibration
from ftacq.dynamics.acceleration import (DERIVATIVE_HALF_WIDTH, acceleration_steps, history_rows, joint_acceleration,
                                        step_shape)
from ftacq.dynamics.model import SensorDynamics, WrenchPredictor
from ftacq.timebase import SampleClock
from ftacq.dynamics.timing import interpolate_rows
from ftacq.kinematics import URModel
from procedures.flange_orientation import (
    DEFAULT_STATE_RATE_HZ,
    MAX_STATE_GAP_S,
    FlangeOrientations,
    pose_rows,
    still_over,
    stream_count,
)

PREDICTION_WINDOW_S = 2.0
"""How far behind the robot state stream a batch's samples may be and still be compensated dynamically, s: the
predictions of the newest states over this span are kept (a reader that lags by up to ~1 s under load, e.g. a
descheduled monitor, still finds the states of its samples' time; 64 rows = 128 ms was too few: beyond that the
batches fell back to the static model). Memory, not CPU: each prediction is computed once, when its state is new."""
STATE_WAIT_S = 0.1
"""The monitor's longest wait for the robot states of a batch's newest samples, s: above the 50 ms the RTDE reader
fell behind under two CPU burners (benchmarks/README.md), below the driver's buffer (the sensor keeps streaming into
it meanwhile; the next read takes what came)."""
CATCH_UP_MAX_S = 30.0
"""Oldest a batch may be (its first sample behind the newest robot state, s) to be predicted from the stream's
states of its span when the kept predictions do not reach it: the model once per state over at most this much
(15 000 states at 500 Hz, ~0.5 s of CPU once); older batches fall back (static, or uncompensated)."""
TAIL_ROWS = 16
"""Newest robot states read per batch when few are new (the bridge: one per controller cycle; the monitor: about
five per 10 ms batch)."""
STEP_REACH_SPANS = 3.0
"""A located q̈ step's correction is zero beyond its row's time + this many of its state intervals + the servo lag
(it ends at the first state at or after the later row + the lag: two intervals at most)."""
STEP_KEEP_S = 1.0
"""Located steps are forgotten this long after their reach falls behind the oldest kept prediction, s."""


def measured_lags_ms(calibration: Calibration) -> tuple[float | None, float | None]:
    """(the sensor's lag behind the arm, the arm's behind its target), ms, as the identification stored them
    (``metadata['dynamics']``, or ``metadata['quick']`` for a calibration from ``--quick``); None where not known."""
    lags: list[float | None] = [None, None]
    for key in ("dynamics", "quick"):
        section = calibration.metadata.get(key)
        if isinstance(section, dict):
            for i, name in enumerate(("lag_ms", "servo_lag_ms")):
                if lags[i] is None and section.get(name) is not None:
                    lags[i] = float(section[name])
    return lags[0], lags[1]


class DynamicCompensator:
    """Compensates gravity and the tool's inertial wrench (calibration with inertia) with the RTDE state stream.

    Args: calibration (``has_dynamics``), robot (the arm's model), stream (a started URStateStream, or anything with
    its ``window(last=…)``), lag_s (the sensor's lag behind the robot stream; default the one the identification
    measured), clock (the samples' :class:`~ftacq.timebase.SampleClock`, shared with the monitor or the
    bridge so that each batch is observed once; default its own), window_s (how far back predictions are kept, s;
    default :data:`PREDICTION_WINDOW_S`), state_wait_s (longest wait for the states of a batch's newest samples, s;
    0: never wait, hold the newest prediction), servo_lag_s (how far the arm follows its target; default the one
    the identification measured, else 0).

    Per batch it reads the newest :data:`TAIL_ROWS` states (all ``window_rows`` when the new ones reach
    into their first :data:`~ftacq.dynamics.acceleration.DERIVATIVE_HALF_WIDTH`: the derivative needs that many
    older neighbours), takes q̈ for the new states only, runs the model once per new state
    (:class:`ftacq.dynamics.model.WrenchPredictor`) and keeps the newest ``window_s`` of predictions in a ring (one
    slice of it is interpolated per batch: a binary search, so the ring's size costs memory, not time). The result equals evaluating the whole window each batch and keeping the new rows.
    """

    def __init__(self, calibration: Calibration, robot: URModel, stream, lag_s: float | None = None,
                 clock: SampleClock | None = None, window_s: float = PREDICTION_WINDOW_S,
                 state_wait_s: float = 0.0, servo_lag_s: float | None = None, hold_s: float = 0.0) -> None:
        if not calibration.has_dynamics:
            raise ValueError("the calibration has no inertia: use the static GravityCompensator")
        self.calibration = calibration
        self.stream = stream
        self.dynamics = SensorDynamics.for_calibration(robot, calibration)
        self.predictor = WrenchPredictor(self.dynamics, calibration)
        measured, servo = measured_lags_ms(calibration)
        self.lag_s = float(lag_s if lag_s is not None else (measured or 0.0) / 1e3)
        self.servo_lag_s = float(servo_lag_s if servo_lag_s is not None else (servo or 0.0) / 1e3)
        """How far the arm follows its target, s: q̈ is target_qdd of this long before each state."""
        rate_hz = float(getattr(stream, "frequency_hz", None) or DEFAULT_STATE_RATE_HZ)
        self._history = history_rows(self.servo_lag_s, 1.0 / rate_hz)
        self.clock = clock if clock is not None else SampleClock()
        self.orientations = FlangeOrientations(robot, stream)
        """The static fallback's flange orientation at the samples' time (slerp between the states around them)."""
        self.window_rows = max(int(round(window_s * rate_hz)), 2 * TAIL_ROWS)
        """Predictions kept (``window_s`` at the stream's rate: 1000 at 500 Hz), and robot states read at once
        after a stall."""
        # the newest window_rows predictions, written twice (at k and k + rows) so that they are always one
        # contiguous slice, oldest first
        self._ring_times = np.empty(2 * self.window_rows)
        self._ring_predicted = np.empty((2 * self.window_rows, 6))
        self._predictions = 0
        self._last_controller_time = -np.inf
        self.static_batches = 0
        """Batches compensated statically, with the flange orientation at the samples' time."""
        self.catch_up_batches = 0
        """Batches older than the kept predictions, predicted from the stream's states of their own span."""
        self.uncompensated_batches = 0
        """Batches with no robot state within MAX_STATE_GAP_S of their samples: compensate() returned None."""
        self.dynamic_batches = 0
        self.held_samples = 0
        """Dynamically compensated samples newer than the newest robot state: that state's prediction is held for
        them (interpolate_rows holds beyond the end), an error of about dW/dt × how far ahead (issue 27)."""
        self.held_max_s = 0.0
        """The farthest such a sample was ahead of the newest robot state, s."""
        self._times = np.empty(0)
        """The last batch's sample times on the host clock, lag taken off, s."""
        self._static_pose: np.ndarray | None = None
        self.derivative_states = 0
        self.state_wait_s = float(state_wait_s)
        self.hold_s = float(hold_s)
        """Samples up to this much newer than the newest robot state take its prediction held without a wait, s (a
        live publisher: the newest state is 2-4 ms old at 500 Hz); a read further ahead waits (``state_wait_s``)."""
        self.waits = 0
        """Batches that waited for the robot states of their newest samples."""
        self.wait_timeouts = 0
        """Waits that ended at ``state_wait_s`` without the states (those samples' prediction is then held)."""
        self.waited_max_s = 0.0
        """The longest wait, s."""
        self._silent_at_count: int | None = None
        """The stream's count when a wait last timed out: not waited for again until a state comes."""
        self._updated_at_count: int | None = None
        """The stream's count when the predictions were last brought up to date (its ``count``, when it has one)."""
        self._steps: list[tuple[float, float, float, np.ndarray]] = []
        """The located steps of the arm's q̈ over the kept states, oldest first: (step s, row s, span s, B(q)(b − a)
        (6,): the wrench's jump), host times on the target's clock (:meth:`_locate_steps`)."""
        self._steps_until_s = -np.inf
        """The located steps' shapes are zero after this (host s)."""
        self.located_steps = 0
        """Steps of q̈ located inside a state interval (:func:`ftacq.dynamics.acceleration.acceleration_steps`)."""

    def _kept(self) -> tuple[np.ndarray, np.ndarray]:
        """(host times (K,), predicted wrenches (K, 6)) of the newest K ≤ window_rows states, oldest first."""
        count, rows = self._predictions, self.window_rows
        start = count % rows if count >= rows else 0
        stop = start + min(count, rows)
        return self._ring_times[start:stop], self._ring_predicted[start:stop]

    def _update_predictions(self) -> None:
        count = stream_count(self.stream)  # read before the window: a state stored meanwhile is read again
        if count is not None and count == self._updated_at_count:
            return  # no state since the last update (the monitor reads on data faster than 500 Hz)
        window = self.orientations.newest(TAIL_ROWS)  # (the stillness check's read of this state: one for both)
        self._updated_at_count = count
        base = max(len(window) - TAIL_ROWS, 0)  # the newest TAIL_ROWS are window[base:]
        new = window.controller_time_s[base:] > self._last_controller_time
        fresh = int(np.count_nonzero(new))
        if fresh == 0:
            return
        size = len(window) - base
        first = size - fresh
        history = self._history
        if (new[first] and (first >= history or size < TAIL_ROWS)
                and (fresh == 1 or np.count_nonzero(new[first:]) == fresh)):
            rows: list[int] = list(range(base + first, base + size))  # the usual case: the newest few are new
            low = base + max(first - history, 0)
        else:  # many new states (the first batch, a stall): the whole window, as before
            window = self.stream.window(last=self.window_rows)
            new = window.controller_time_s > self._last_controller_time
            rows = np.flatnonzero(new).tolist()
            size = len(window)
            contiguous = rows[-1] - rows[0] == len(rows) - 1
            low = max(rows[0] - history, 0) if contiguous else 0
        # q̈ of the new states and of the older neighbours their derivative (or the servo lag) reaches: row by row
        # as over the window
        qdd, tracking = joint_acceleration(window.time_s[low:], window.qd[low:], window.target_qd[low:],
                                           window.qdd[low:], servo_lag_s=self.servo_lag_s)
        tracked = tracking[rows[0] - low:] if rows[-1] - rows[0] == len(rows) - 1 and rows[-1] == len(window) - 1 \
            else tracking[[row - low for row in rows]]  # (the new rows: usually the newest, a slice)
        self.derivative_states += len(rows) - int(np.count_nonzero(tracked))
        q, qd, time_s = window.q, window.qd, window.time_s
        ring_times, ring_predicted, predict = self._ring_times, self._ring_predicted, self.predictor.predict_one
        kept = self.window_rows
        for row in rows:
            slot = self._predictions % kept
            predict(q[row], qd[row], qdd[row - low], ring_predicted[slot])
            ring_predicted[slot + kept] = ring_predicted[slot]
            ring_times[slot] = ring_times[slot + kept] = time_s[row]
            self._predictions += 1
        self._locate_steps(window, rows, low, qdd, tracking)
        self._last_controller_time = float(window.controller_time_s[-1])

    def _locate_steps(self, window, rows: list[int], low: int, qdd: np.ndarray, tracking: np.ndarray) -> None:
        """Record the steps of the target's q̈ (a moveJ's phase boundaries) between a new state and the one before,
        located inside the interval (:func:`~ftacq.dynamics.acceleration.acceleration_steps`), with the wrench's
        jump there, B(q)(b − a) at the new state (one more model evaluation per step): the linear interpolation of
        the predictions smears a step over the state period and the servo lag (8-16 ms on a CB3).
        While the arm tracks its target only (its q̈ is then the target's of ``servo_lag_s`` earlier)."""
        stop = rows[-1] + 1
        target_qdd = window.qdd
        if (target_qdd[max(rows[0] - 1, 0)].tolist() == target_qdd[rows[-1]].tolist()
                and (len(rows) <= TAIL_ROWS or not (target_qdd[rows[0]:stop] != target_qdd[rows[0]]).any())):
            return  # the usual case: no change since the last state (cheaper as lists: two rows; a change and back
            # within one read, a few states, is left to the linear interpolation)
        start = max(rows[0] - 2, low)
        if rows[-1] - start < 2:
            return
        time_s = window.time_s
        before, step_s, jump = acceleration_steps(time_s[start:stop], window.target_qd[start:stop],
                                                  window.qdd[start:stop])
        steps = self._steps
        for row, at_s, change in zip((before + start).tolist(), step_s.tolist(), jump):
            later = row + 1
            if later < rows[0] or not (tracking[row - low] and tracking[later - low]):
                continue
            acceleration = qdd[later - low]
            base = self.predictor.predict_one(window.q[later], window.qd[later], acceleration, np.empty(6))
            shifted = self.predictor.predict_one(window.q[later], window.qd[later], acceleration + change,
                                                 np.empty(6))
            span_s = float(time_s[later] - time_s[row])
            steps.append((at_s, float(time_s[row]), span_s, shifted - base))
            self.located_steps += 1
            # (the shape is 0 from the first state at or after the step's later row + the servo lag)
            self._steps_until_s = max(self._steps_until_s, self._step_end_s(float(time_s[row]), span_s))
        oldest = float(self._kept()[0][0]) - STEP_KEEP_S
        while steps and self._step_end_s(steps[0][1], steps[0][2]) < oldest:
            steps.pop(0)

    def _step_end_s(self, row_s: float, span_s: float) -> float:
        """Host time after which a step located in the interval [row_s, row_s + span_s] corrects nothing, s."""
        return row_s + STEP_REACH_SPANS * span_s + self.servo_lag_s

    def _add_steps(self, times: np.ndarray, state_times: np.ndarray, predicted_rows: np.ndarray) -> None:
        """Add to the interpolated predictions (N, 6) at the samples' ``times`` the located steps' jumps that the
        linear interpolation over ``state_times`` missed (:func:`~ftacq.dynamics.acceleration.step_shape`); a
        Python step per located step near the batch (a few per move), numpy over the samples."""
        newest, oldest = float(times[-1]), float(times[0])
        for step_s, row_s, span_s, jump in self._steps:
            if row_s > newest or self._step_end_s(row_s, span_s) < oldest:
                continue
            shape = step_shape(times, state_times, step_s, row_s, span_s, self.servo_lag_s)
            predicted_rows += shape[:, None] * jump

    def compensate(self, batch, robot=None) -> np.ndarray | None:
        """Return the contact wrench (N, 6) of ``batch``: dynamically, else statically with the pose at the samples'
        time, else None (uncompensated: no robot state near the samples). ``robot`` (the newest state from another
        source) is not used: its pose is from another time."""
        times = self._times = self.clock.host_times(batch.time_s, batch.device_time_s) - self.lag_s
        self._static_pose = None
        self._update_predictions()
        state_times, predicted = self._kept()
        if self.state_wait_s > 0.0 and state_times.size and times[-1] > state_times[-1] + self.hold_s:
            state_times, predicted = self._wait_for_states(float(times[-1]) - self.hold_s)
        if (state_times.size >= 2 and times[0] < state_times[0] and times[-1] <= state_times[-1] + MAX_STATE_GAP_S
                and state_times[-1] - times[0] <= CATCH_UP_MAX_S):
            state_times, predicted = self._predictions_over(times, state_times, predicted)
        if state_times.size >= 2 and times[0] >= state_times[0] and times[-1] <= state_times[-1] + MAX_STATE_GAP_S:
            self.dynamic_batches += 1
            if times[-1] > state_times[-1]:  # the batch's newest samples are ahead of the RTDE stream
                self.held_samples += int(times.size - times.searchsorted(state_times[-1], side="right"))
                self.held_max_s = max(self.held_max_s, float(times[-1] - state_times[-1]))
            contact = interpolate_rows(times, state_times, predicted)
            if times[0] < self._steps_until_s:  # (a located step near or after the samples)
                self._add_steps(times, state_times, contact)
            return np.subtract(batch.wrench, contact, out=contact)
        flange_R_base = self.orientations.flange_R_base_at(times)
        if flange_R_base is None:
            self.uncompensated_batches += 1
            return None
        self.static_batches += 1
        self._static_pose = pose_rows(self.orientations.position_m, flange_R_base)
        return self.calibration.compensate(batch.wrench, flange_R_base)

    def _predictions_over(self, times: np.ndarray, state_times: np.ndarray,
                          predicted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The kept predictions preceded by the model over the older states the stream still keeps around the
        sample ``times`` (host s, oldest first): from the state before the first sample to the one after the last
        (q̈ over them with their neighbours, as for new states; the ring is left as it is). Returns the kept ones
        unchanged when the stream has none older."""
        rate_hz = float(getattr(self.stream, "frequency_hz", None) or DEFAULT_STATE_RATE_HZ)
        wanted = int((float(state_times[-1]) - float(times[0])) * rate_hz * 1.25) + 4 * self._history + 8
        window = self.stream.window(last=wanted)
        # (half a period below the oldest kept one: its own row, mapped again with a newer line, is not taken twice)
        older = window.time_s < state_times[0] - 0.5 / rate_hz
        first = int(np.searchsorted(window.time_s, times[0], side="right")) - 1  # the state before the first sample
        last = int(np.searchsorted(window.time_s, times[-1], side="left"))  # the state after the last one
        if first < 0 or not older[first]:
            return state_times, predicted
        rows = np.arange(first, min(last + 1, len(window)))
        rows = rows[older[rows]]
        low, high = max(first - self._history, 0), min(int(rows[-1]) + DERIVATIVE_HALF_WIDTH + 1, len(window))
        qdd, _ = joint_acceleration(window.time_s[low:high], window.qd[low:high], window.target_qd[low:high],
                                    window.qdd[low:high], servo_lag_s=self.servo_lag_s)
        self.catch_up_batches += 1
        earlier = self.predictor(window.q[rows], window.qd[rows], qdd[rows - low])
        return np.concatenate([window.time_s[rows], state_times]), np.vstack([earlier, predicted])

    def _wait_for_states(self, newest_sample_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Wait (at most ``state_wait_s``) until a robot state at or after ``newest_sample_s`` (host s; the read's
        newest sample less ``hold_s``) is kept;
        return the kept predictions then. The stream's ``wait_for_samples`` sleeps on its reader's notification."""
        wait = getattr(self.stream, "wait_for_samples", None)
        count = int(getattr(self.stream, "count", 0))
        if wait is None or count == self._silent_at_count or getattr(self.stream, "stale", False):
            return self._kept()
        self.waits += 1
        start_s = time.monotonic()
        deadline_s = start_s + self.state_wait_s
        state_times, predicted = self._kept()
        while state_times[-1] < newest_sample_s:
            remaining_s = deadline_s - time.monotonic()
            count = int(self.stream.count)
            if remaining_s <= 0.0 or not wait(count + 1, remaining_s):
                self.wait_timeouts += 1
                self._silent_at_count = int(self.stream.count)
                break
            self._update_predictions()
            state_times, predicted = self._kept()
        self.waited_max_s = max(self.waited_max_s, time.monotonic() - start_s)
        return state_times, predicted

    def still_over(self, window_s: float, tolerance_rad: float) -> bool:
        """:func:`procedures.flange_orientation.still_over` for the last batch's sample times."""
        return still_over(self.orientations, self._times, window_s, tolerance_rad)

    def sample_flange_pose(self) -> np.ndarray | None:
        """The flange pose (N, 6) (m, rad: a UR pose, base frame) at each sample's time of the last batch (the lag
        taken off), from the state stream (the model itself uses the joint states, not this pose); None when no
        state is near them. For the record: each sample beside the pose of its time."""
        if self._static_pose is not None:
            return self._static_pose
        return self.orientations.flange_pose_at(self._times) if self._times.size else None
