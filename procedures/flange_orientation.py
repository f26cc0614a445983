"""The flange orientation at any recent host time, from the robot state stream's rows: :class:`FlangeOrientations`.

The live compensators' static path (:mod:`procedures.static_compensation`, and the dynamic compensator's fallback,
:mod:`procedures.dynamic_compensation`) compensates each sensor sample with the tool's weight at the orientation the
flange had *when the sample was taken* (the samples' times on the host clock through the sensor's own clock,
:class:`ftacq.timebase.SampleClock`), never with the newest one: a monitor that reads 100 ms late while the
arm turns at 1 rad/s would otherwise rotate the tool's weight by 0.1 rad (4 N of a 4 kg tool).

Per query (one sensor batch): the stream's rows around the samples (host times through the controller's own clock,
:class:`drivers.ur_stream.URStateStream`), base_R_flange of each by forward kinematics (Pinocchio,
:class:`ftacq.kinematics.FlangeRotation`, ≈ 3 µs; kept for the next batch, so only the new states are computed),
interpolated onto the samples along the shortest arc (:func:`ftacq.dynamics.timing.slerp_rows`: numpy batches, no
Python object per sample; entry-wise where the states are so close that the two agree to 10⁻⁵: :data:`SLERP_ABOVE_RAD`). A sample between two states is given the slerp between them, when they are at most
``max_gap_s`` apart; a sample newer than the newest state (the live edge: its state has not arrived yet) the
newest state's orientation, when it is at most ``max_gap_s`` newer. Otherwise (the stream is lost, late, or has a
gap around the sample; the sample is older than the states read) the answer is None: the caller leaves the batch
uncompensated rather than use a pose from another time.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.ur_connection import E_SERIES_RATE_HZ
from ftacq.dynamics.timing import interpolate_rows, slerp_rows
from ftacq.kinematics import FlangeRotation, URModel
from ftacq.so3 import rotvec_from_rotation

MAX_STATE_GAP_S = 0.05
"""Longest interval between the two robot states around a sample, and longest time a sample may be newer than the
newest state, for it to be given an orientation, s (25 controller cycles at 500 Hz: a gap of the state stream longer
than this is a stall or a lost link, not jitter)."""
SLERP_ABOVE_RAD = 0.01
"""When every interval between the states around a batch turns the flange by less than this (rad), the orientation
is interpolated entry-wise (:func:`ftacq.dynamics.timing.interpolate_rows`) instead of along the arc
(:func:`ftacq.dynamics.timing.slerp_rows`): the entry-wise mean of two rotations θ apart is the arc's midpoint
scaled by cos(θ/2), so the weight it predicts is at most θ²/8 short (1.3·10⁻⁵ at 0.01 rad: 0.5 mN of a 40 N tool,
far below any sensor's noise), for a fraction of the slerp's cost per batch (benchmarks/static_compensation.py).
0.01 rad between 2 ms states is a flange turning at 5 rad/s; a wider interval (a gap of the stream, a faster
wrist) takes the slerp."""
DEFAULT_STATE_RATE_HZ = E_SERIES_RATE_HZ
"""The state stream's rate when it does not say (``frequency_hz``), Hz: only sizes the first read of rows."""
READ_MARGIN_ROWS = 4
"""Rows read beyond what the last query needed (the next batch may reach a little further back)."""
MAX_ROWS = 1 << 16
"""Most rows read for one query (131 s at 500 Hz): samples older than that are not compensated."""


class FlangeOrientations:
    """flange_R_base at given host times from a robot state stream (module docstring).

    Args: model (the arm's kinematics), stream (a started :class:`drivers.ur_stream.URStateStream`, or anything
    with its ``window(last=…)`` returning host ``time_s``, ``controller_time_s`` and ``q``), max_gap_s.
    One thread (a :class:`~ftacq.kinematics.FlangeRotation` is not thread-safe).
    """

    def __init__(self, model: URModel, stream, max_gap_s: float = MAX_STATE_GAP_S) -> None:
        self.stream = stream
        self.max_gap_s = float(max_gap_s)
        self._flange_rotation = FlangeRotation(model)
        self._period_s = 1.0 / float(getattr(stream, "frequency_hz", DEFAULT_STATE_RATE_HZ) or DEFAULT_STATE_RATE_HZ)
        self._known_time = np.empty(0)
        """Controller times (s) of the rows whose base_R_flange the last query computed, in order."""
        self._known_rotation = np.empty((0, 3, 3))
        self._known_position = np.empty((0, 3))
        self._positions: tuple[np.ndarray, np.ndarray, np.ndarray] = (np.empty(0), np.empty(0), np.empty((0, 3)))
        """(sample times, state times, state positions) of the last answer: :attr:`position_m` when asked."""
        self._read: dict[str, tuple[int, int, Any, bool]] = {}
        """Per kind of query, (the stream's count, rows asked, the window, its controller times in order) of its last
        read: a query that comes before the next state reads nothing (rows and host times change only when one is
        stored)."""
        self._last_rows: dict[str, int] = {}
        """Per kind of query, the rows its last one needed back to its oldest time (plus a margin)."""
        self.computed = 0
        """States whose forward kinematics was computed (each once while consecutive queries overlap)."""

    def flange_R_base_at(self, time_s: np.ndarray) -> np.ndarray | None:
        """Return flange_R_base (N, 3, 3) at each host time of ``time_s`` (N,), s, sorted; None when a time lies in
        a gap of the stream longer than ``max_gap_s``, more than that after the newest state, or before the
        states read (module docstring)."""
        times = np.asarray(time_s, dtype=float)
        if times.size == 0:
            return np.empty((0, 3, 3))
        window = self._rows(times[0], times[-1])
        if window is None:
            return None
        state = window.time_s
        # the states bracketing the samples: from the last one at or before the oldest sample to the first one at
        # or after the newest (or the newest state, which the newest samples may have outrun by up to max_gap_s)
        low = int(np.searchsorted(state, times[0], side="right")) - 1
        high = int(np.searchsorted(state, times[-1], side="left")) + 1
        if low < 0:
            return None  # older than every state read
        around = state[low:high]
        after = np.searchsorted(around, times, side="left")  # ≥ 1 for every sample (around[0] ≤ times[0])
        newer = after >= around.size  # the live edge: the state of these samples' time has not arrived yet
        interval = np.where(newer, times - around[-1],
                            around[np.minimum(after, around.size - 1)] - around[np.maximum(after - 1, 0)])
        if not np.all(interval <= self.max_gap_s):
            return None  # a gap of the stream around these samples (lost, stalled): no orientation of their time
        base_R_flange, position = self._placements(window.controller_time_s[low:high], window.q[low:high])
        self._positions = (times, around, position)
        flat = base_R_flange.reshape(-1, 9)
        widest_rad = float(np.linalg.norm(np.diff(flat, axis=0), axis=1).max()) / np.sqrt(2.0) if len(flat) > 1 else 0.0
        if widest_rad < SLERP_ABOVE_RAD:  # ‖R_{i+1} − R_i‖_F = 2√2 sin(θ/2) ≈ √2 θ
            return np.swapaxes(interpolate_rows(times, around, flat).reshape(-1, 3, 3), 1, 2)
        return np.swapaxes(slerp_rows(times, around, base_R_flange), 1, 2)

    def _rows(self, oldest_s: float, newest_s: float, query: str = "orientation"):
        """The stream's newest rows back to the last one at or before ``oldest_s`` (host s; all it keeps if none
        is), or None when the newest state is more than ``max_gap_s`` older than ``newest_s``. ``query`` names the
        caller, whose last read sizes this one."""
        rows = self._last_rows.get(query, READ_MARGIN_ROWS)  # as many as its last query needed: usually one read
        while True:
            window = self._window(rows, query)
            if len(window) == 0 or newest_s > window.time_s[-1] + self.max_gap_s:
                return None  # the newest state does not reach these samples
            if len(window) < rows or window.time_s[0] <= oldest_s or rows >= MAX_ROWS:
                if window.time_s[0] <= oldest_s:  # the rows from the last one at or before oldest_s, and a margin
                    first = int(window.time_s.searchsorted(oldest_s, side="right")) - 1
                    self._last_rows[query] = len(window) - first + READ_MARGIN_ROWS
                return window
            # read further back: as far as the stream's rate says, at least twice as far
            span_rows = (float(window.time_s[-1]) - oldest_s) / self._period_s + 2
            rows = int(min(max(2 * rows, span_rows), MAX_ROWS))

    def newest(self, rows: int):
        """The stream's newest ``rows`` or more (``window(last=…)``): as many as the stillness check's next query
        (:meth:`still_between`) will read, which then reads nothing (one read of the stream per state for the
        dynamic compensator's predictions and the check: a read costs ~40 µs, and with --ros2 the monitor reads at
        each state). The same rows, host times and all, as ``window(last=rows)``: more only when their controller
        times are in order."""
        wanted = max(rows, self._last_rows.get("still", rows))
        if wanted == rows or stream_count(self.stream) is None:
            return self._window(rows, "still")
        window = self._window(wanted, "still")
        kept = self._read.get("still")
        if len(window) > rows and (kept is None or kept[2] is not window or not kept[3]):
            return self.stream.window(last=rows)  # (two controller sessions in the wider rows: mapped apart)
        return window

    def _window(self, rows: int, query: str):
        """The stream's newest ``rows`` (``window(last=rows)``), or the last read of this ``query`` while the stream's
        count has not moved: the rows asked for then, or more when their controller times are in order (their host
        times are then those of a read of fewer: the same line maps the same rows)."""
        count = stream_count(self.stream)  # read before the window: a state stored meanwhile is read again
        kept = self._read.get(query)
        if count is not None and kept is not None and kept[0] == count and (
                kept[1] == rows or (kept[1] > rows and kept[3])):
            return kept[2]
        window = self.stream.window(last=rows)
        if count is not None:
            times = window.controller_time_s
            self._read[query] = (count, rows, window, not np.count_nonzero(times[1:] < times[:-1]))
        return window

    def still_between(self, start_s: float, end_s: float, tolerance_rad: float) -> bool:
        """True when the robot states cover host times [start_s, end_s] (s; no gap longer than ``max_gap_s``, the
        newest at most that before ``end_s``) and every joint stayed within ``tolerance_rad`` over them: the arm
        was still while those samples were taken (not when they were read)."""
        window = self._rows(start_s, end_s, "still")
        if window is None or len(window) == 0 or window.time_s[0] > start_s:
            return False
        state = window.time_s  # (ndarray methods, not numpy's module functions: this runs at every read)
        low = int(state.searchsorted(start_s, side="right")) - 1
        high = int(state.searchsorted(end_s, side="left")) + 1
        span = state[low:high]
        if span.size > 1 and np.count_nonzero(span[1:] - span[:-1] > self.max_gap_s):
            return False
        q = np.ascontiguousarray(window.q[low:high].T)  # (6, M): each joint's angles in a row (half the cost of
        within = q.max(axis=1) - q.min(axis=1) <= tolerance_rad  # reducing the window's strided rows)
        return np.count_nonzero(within) == within.size  # (.all(): numpy's reduction machinery, ~4x the cost)

    @property
    def position_m(self) -> np.ndarray:
        """The flange positions (N, 3), m, base frame, at the times of the last :meth:`flange_R_base_at` answered
        (linear between the states; computed when asked: only a record needs them)."""
        times, around, position = self._positions
        return interpolate_rows(times, around, position) if times.size else np.empty((0, 3))

    def flange_pose_at(self, time_s: np.ndarray) -> np.ndarray | None:
        """Return the flange pose (N, 6) at each host time of ``time_s`` (s, sorted) as a UR pose (x, y, z in m,
        the rotation vector of base_R_flange in rad; base frame), or None as :meth:`flange_R_base_at`: for a
        record pairing each sample with the pose of its time."""
        flange_R_base = self.flange_R_base_at(time_s)
        if flange_R_base is None:
            return None
        return pose_rows(self.position_m, flange_R_base)

    def _placements(self, controller_time_s: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(base_R_flange (K, 3, 3), flange position (K, 3) m, base frame) of these rows: those the last query
        computed are reused, the others computed."""
        rotations, positions = np.empty((controller_time_s.size, 3, 3)), np.empty((controller_time_s.size, 3))
        known_time = self._known_time
        hit = np.zeros(controller_time_s.size, dtype=bool)
        if known_time.size:
            where = np.minimum(np.searchsorted(known_time, controller_time_s), known_time.size - 1)
            hit = known_time[where] == controller_time_s
            rotations[hit], positions[hit] = self._known_rotation[where[hit]], self._known_position[where[hit]]
        placement = self._flange_rotation.placement
        for row in np.flatnonzero(~hit).tolist():  # the new states only: a few per batch
            rotations[row], positions[row] = placement(q[row])
            self.computed += 1
        if controller_time_s.size < 2 or np.all(np.diff(controller_time_s) > 0):
            self._known_time = controller_time_s.copy()
            self._known_rotation, self._known_position = rotations, positions
        return rotations, positions


def stream_count(stream) -> int | None:
    """The states ``stream`` has stored so far (:attr:`drivers.ur_stream.URStateStream.count`), or None when it does
    not say: its rows (and their host times) change only when this moves."""
    count = getattr(stream, "count", None)
    return count if isinstance(count, int) else None


def pose_rows(position_m: np.ndarray, flange_R_base: np.ndarray) -> np.ndarray:
    """UR poses (N, 6) (x, y, z m; rotation vector of base_R_flange, rad) from positions (N, 3) and flange_R_base
    (N, 3, 3)."""
    return np.hstack([position_m, rotvec_from_rotation(np.swapaxes(flange_R_base, 1, 2))])


__all__ = ["FlangeOrientations", "MAX_STATE_GAP_S", "pose_rows", "stream_count"]


def still_over(orientations: FlangeOrientations, sample_times_s: np.ndarray, window_s: float,
               tolerance_rad: float) -> bool:
    """True when every joint stayed within ``tolerance_rad`` from ``window_s`` before a batch's first sample to its
    last one (``sample_times_s``, host s, from the sample clock): the arm was still while the samples were taken,
    however late they were read (the drift tracker's rest windows)."""
    if sample_times_s.size == 0:
        return False
    return orientations.still_between(float(sample_times_s[0]) - window_s, float(sample_times_s[-1]), tolerance_rad)
