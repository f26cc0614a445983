"""The time base of every stream: a device's own clock on the host's, the minimum-delay line through (device time,
arrival − device time). The sensor's samples (:class:`SampleClock`), the controller's states
(drivers/ur_stream.py, procedures/bridge.py) and recordings mapped after the fact (:func:`device_to_host_clock`)
all go through :class:`DeviceClock`, with one restart rule (:func:`new_session`).

The model (docs/dynamics.md, "How the clocks are aligned"). A device (the Net F/T's sample counter, the UR
controller's ``timestamp``) stamps each sample with its own time ``d`` (s); the host stamps its arrival ``a`` (s,
``time.monotonic``). The two crystals run at slightly different rates, so

    a = d · (1 + ε) + c + δ,   δ ≥ 0,

with ε the rate error (tens of ppm, at most a few hundred), c an offset and δ the transport delay of that sample
(the network, a datagram waiting for its burst, the receive thread's coalescing, a descheduled reader: never
negative, sometimes 100 ms). In the plane (x = d, y = a − d) every sample lies on or above the line y = ε·x + c,
and the samples that waited least lie on it. So the line is the **lower convex hull**'s supporting line:

- it is below every point (a sample is never mapped later than it arrived: the mapping never runs ahead of the
  data), and it touches the points with the least delay;
- least squares on the arrival stamps (the period fit this replaces) estimates the line through the *mean* delay:
  its slope follows how the delay changes over the fit (a queue filling, bursts starting, the host's load), not
  the clocks. A mean delay that grows by 2 ms over 10 s is a 0.2 % period error, 54 ms late after 30 s. The lower
  hull depends only on the fastest samples, which keep the same (smallest) transport time whatever the load;
- bursts (several samples arriving together) put the last of the burst on the hull and the others above it;
  skipped samples leave a gap in ``d`` and change nothing; a stall leaves points high above the hull.

The estimator (:class:`DeviceClock`): the lower hull of the points of a sliding window
(:data:`CLOCK_WINDOW_S` of device time), kept as per-:data:`CLOCK_BLOCK_S` block hulls (a point joins the newest
block's hull and the window's hull by Andrew's monotone chain, O(1) amortised; when a block leaves the window the
window's hull is rebuilt from the block hulls, a few hundred points once a block). Each batch is first reduced to
its lowest point per :data:`CLOCK_BIN_S` (numpy): the hull only needs the lower envelope. The line used is the
hull edge under the middle of the window, for its slope: the longest baseline, so the rate is known to the floor's
noise over half the window (50 µs over 30 s: 2 ppm), bounded to ±:data:`MAX_RATE_ERROR` (a line steeper than that
is a queue, not a crystal). Its height is the lowest that keeps the points of the newest :data:`CLOCK_RECENT_S`
above it: the newest batch is never mapped later than it arrived, and a slope off by δε moves the mapping of the
newest samples by δε × at most CLOCK_RECENT_S (40 µs at 2 ppm) rather than δε × half the window.

What it cannot know, and says: the constant part of the transport (the smallest delay) is in ``c``; it is part of
the lag between the sensor and the robot streams that the identification measures (``estimate_lag``). A rate that
changes within the window (a crystal warming up: ppm over minutes) bends the points; the line through the window's
middle is then below the newest points, and :attr:`DeviceClock.uncertainty_s` shows by how much. While the span
covered is shorter than :data:`SETTLE_SPAN_S` the rate is poorly known: :attr:`DeviceClock.settled` is False.
"""

from __future__ import annotations

import bisect
import collections
import math

import numpy as np

CLOCK_WINDOW_S = 60.0
"""Device time over which the minimum-delay line is fitted, s: long enough that the fastest samples of a loaded
host (a few per second) pin the rate to a few ppm, short enough that a crystal's rate change over it (≪ 1 ppm) is
negligible."""
CLOCK_BLOCK_S = 1.0
"""The window is kept as hulls of blocks of this much device time, s: a block leaves the window whole."""
CLOCK_BIN_S = 0.02
"""A batch is reduced to its lowest point per this much device time before it joins the hull, s (the hull's
points are then at most 50 a second; a sample beside the lowest one of its bin is at most MAX_RATE_ERROR × this
= 10 µs lower on any line)."""
MAX_RATE_ERROR = 5e-4
"""Largest |rate error| (s/s, 500 ppm) the line may have: a crystal is within ±100 ppm of its rate (±200 ppm
between two of them), a queue filling is not a clock."""
CLOCK_RECENT_S = 20.0
"""The line's height is the lowest under the points of this much newest device time, s (its slope comes from the
whole window): shorter follows a changing rate more closely but rides on a sparser floor (the newest fastest
sample's own delay); on bursty, queued arrivals (tests/clock_arrivals.py) 5 s left the mapping up to 0.39 ms late,
20 s 0.15 ms, while a slope off by 2 ppm moves it by at most 40 µs."""
SETTLE_SPAN_S = 5.0
"""Span of device time the window must cover before the line is :attr:`DeviceClock.settled`, s."""
SETTLED_UNCERTAINTY_S = 5e-4
"""Largest :attr:`DeviceClock.uncertainty_s` of a settled mapping, s."""


def new_session(previous_s: float, device_s: float, block_s: float = CLOCK_BLOCK_S,
                window_s: float = CLOCK_WINDOW_S) -> bool:
    """The restart rule: True when a device time ``device_s`` after ``previous_s`` (s) starts a new session of the
    device's clock: a step back longer than ``block_s`` (a power-cycled sensor, another controller session) or a
    silence longer than ``window_s``. A shorter step back is a late sample of the same session."""
    return device_s < previous_s - block_s or device_s - previous_s > window_s


def session_starts(device_time_s: np.ndarray, block_s: float = CLOCK_BLOCK_S,
                   window_s: float = CLOCK_WINDOW_S) -> np.ndarray:
    """Indices of the samples of ``device_time_s`` (s, in arrival order) that start a new session by
    :func:`new_session` (the first sample is not counted)."""
    step = np.diff(np.asarray(device_time_s, dtype=float))
    return np.flatnonzero((step < -block_s) | (step > window_s)) + 1


def _lower_hull_push(xs: list[float], ys: list[float], x: float, y: float) -> None:
    """Add a point to the right end of a lower convex hull kept as two lists (x increasing): Andrew's monotone
    chain, popping the vertices the new point makes non-convex. A point at the last x keeps the lower of the two;
    a point left of the last one is ignored (the caller restarts the clock on a backward step)."""
    if xs:
        last = xs[-1]
        if x < last:
            return
        if x == last:
            if y >= ys[-1]:
                return
            xs.pop()
            ys.pop()
    while len(xs) >= 2:
        ox, oy, ax, ay = xs[-2], ys[-2], xs[-1], ys[-1]
        if (ax - ox) * (y - oy) - (ay - oy) * (x - ox) > 0.0:  # a left turn: the last vertex stays on the hull
            break
        xs.pop()
        ys.pop()
    xs.append(x)
    ys.append(y)


class DeviceClock:
    """The host time of a device's own sample times, learnt from their arrival stamps (module docstring: the model,
    the estimator and why it is right).

    :meth:`observe` takes a batch (device times, s, oldest first; arrival stamps, s, one per sample or one for the
    whole read), :meth:`observe_one` one sample as floats (once per controller cycle, no array);
    :meth:`map_times` / :meth:`map_time` map device times onto the host clock with the newest line. A device
    time that goes back by more than a block (a power-cycled sensor, another controller session) starts the
    mapping anew, as does a silence longer than the window; a shorter step back (a late record) is ignored. One
    writer thread; readers in other threads see a consistent line (one tuple, replaced whole).

    Attributes (after the first sample): ``rate_error`` (ε, s/s: the host advances by 1 + ε s per device s),
    ``offset_s`` (host − device time at the newest sample, s), ``span_s`` (device time covered by the window, s),
    ``uncertainty_s`` (s: how far the recent samples' floor lies above the whole window's minimum-delay line of
    the same slope — the floor's noise plus a rate change the window has not followed; a mapping whose slope or
    height were off by more would show it here), :attr:`settled` and ``restarts``.
    """

    def __init__(self, window_s: float = CLOCK_WINDOW_S, block_s: float = CLOCK_BLOCK_S,
                 max_rate_error: float = MAX_RATE_ERROR) -> None:
        if not (window_s > 0 and block_s > 0 and max_rate_error >= 0):
            raise ValueError("window_s and block_s must be positive, max_rate_error not negative")
        self.window_s, self.block_s, self.max_rate_error = float(window_s), float(block_s), float(max_rate_error)
        self.restarts = 0
        """Times the mapping started anew (a device time going backwards, a silence longer than the window)."""
        self._line: tuple[float, float, float, float] | None = None
        """(support device time x0, s; y0 = host − device time there, s; rate error, s/s; the oldest device time in
        the window, s): replaced whole by the writer, so a reader in another thread always sees one consistent line
        (the previous session's until the new one has its first point)."""
        self._reset()

    def _reset(self) -> None:
        self._blocks: collections.deque[tuple[float, list[float], list[float]]] = collections.deque()
        """Completed blocks in the window: (start x, hull xs, hull ys), oldest first."""
        self._block_start = math.nan
        self._block_x: list[float] = []
        self._block_y: list[float] = []
        self._hull_x: list[float] = []
        self._hull_y: list[float] = []
        self._recent_x = self._recent_y = np.empty(0)
        """The vertices of the recent completed blocks' hulls (see _collect_recent)."""
        self._recent_key: tuple[float, float, np.ndarray] | None = None
        self._recent_lowest = (math.inf, 0.0)
        """The lowest of the recent completed blocks' vertices on the line (x0, ε) of _recent_key: (height, x)."""
        self._last_x = -math.inf
        self._window_line = (math.nan, math.nan, math.nan)
        self.rate_error = 0.0
        self.offset_s: float | None = None
        self.span_s = 0.0
        self.uncertainty_s = math.inf

    @property
    def settled(self) -> bool:
        """True when the window covers at least :data:`SETTLE_SPAN_S` and the newest samples' floor is within
        :data:`SETTLED_UNCERTAINTY_S` of the line."""
        return self.span_s >= SETTLE_SPAN_S and self.uncertainty_s <= SETTLED_UNCERTAINTY_S

    @property
    def line(self) -> tuple[float, float, float, float] | None:
        """(x0, y0, ε, valid from): host time = d + y0 + ε (d − x0), s, for device times d from the oldest one in the
        window (older ones, or those of an earlier session, were mapped by the lines of their time); None before
        the first sample."""
        return self._line

    def window_line(self) -> tuple[float, float, float]:
        """(x0, y0, ε) of the whole window's minimum-delay line (below every point of the window, through its
        fastest ones; the mapping uses its slope with the recent points' height): for mapping a whole recording
        at once. NaN before the first sample."""
        return self._window_line

    @property
    def valid_from_s(self) -> float | None:
        """The oldest device time the current line was fitted on, s (None before the first sample): a device time
        before it (hours ago, or of an earlier session) is better mapped by the line of its own time."""
        line = self._line
        return None if line is None else line[3]

    # ------------------------------------------------------------------ input

    def observe(self, device_time_s, arrival_s) -> None:
        """Take a batch of samples, oldest first: ``device_time_s`` (N,) the device's times of the samples, s;
        ``arrival_s`` their host receive stamps ((N,), or one stamp for the whole read), s. NaN device times (a
        device without a clock) are ignored."""
        device = np.asarray(device_time_s, dtype=float).reshape(-1)
        if device.size == 0:
            return
        arrival = np.asarray(arrival_s, dtype=float)
        if arrival.shape != device.shape:
            arrival = np.broadcast_to(arrival, device.shape)
        if device.size == 1:
            self.observe_one(float(device[0]), float(arrival[0]))
            return
        if not (math.isfinite(device[0]) and math.isfinite(device[-1])):  # a batch has a device clock or none
            valid = np.isfinite(device) & np.isfinite(arrival)
            device, arrival = device[valid], arrival[valid]
            if device.size == 0:
                return
        back = device[1:] < device[:-1]
        if np.count_nonzero(back):  # a step back inside the batch: each run in order (_push applies the restart rule)
            runs = np.split(np.arange(device.size), np.flatnonzero(back) + 1)
            for run in runs:
                self.observe(device[run], arrival[run])
            return
        below = arrival - device
        if device[-1] - device[0] < CLOCK_BIN_S:  # the usual batch: one point, the lowest on the current line
            best = int((below - self.rate_error * device).argmin()) if self.rate_error else int(below.argmin())
            self._push(float(device[best]), float(below[best]))
        else:
            tilted = below - self.rate_error * device
            bins = np.floor((device - device[0]) / CLOCK_BIN_S).astype(np.int64)
            starts = np.flatnonzero(np.diff(bins, prepend=-1))
            lowest = np.minimum.reduceat(tilted, starts)
            owner = np.repeat(np.arange(starts.size), np.diff(np.append(starts, device.size)))
            hits = np.flatnonzero(tilted == lowest[owner])
            first = hits[np.diff(owner[hits], prepend=-1) > 0]  # the first lowest sample of each bin
            for index in first.tolist():
                self._push(float(device[index]), float(below[index]))
        self._update()

    def observe_one(self, device_time_s: float, arrival_s: float) -> None:
        """Take one sample (as :meth:`observe`, in floats)."""
        if not (math.isfinite(device_time_s) and math.isfinite(arrival_s)):
            return
        self._push(device_time_s, arrival_s - device_time_s)
        self._update()

    def _push(self, x: float, y: float) -> None:
        """Add one point (device time x, arrival − device time y) to the window: restart on a step back longer than a
        block (a power-cycled sensor, another controller session) or a silence longer than the window; ignore a
        shorter step back (a late record)."""
        if new_session(self._last_x, x, self.block_s, self.window_s):
            if self._line is not None:
                self.restarts += 1
                self._reset()
        elif x < self._last_x:
            return  # a late or repeated sample (a step back shorter than a block): the hull is right of it
        self._last_x = x
        if not self._block_x:
            self._block_start = x
        elif x >= self._block_start + self.block_s:
            self._blocks.append((self._block_start, self._block_x, self._block_y))
            self._block_start, self._block_x, self._block_y = x, [], []
            expired = False
            while self._blocks and self._blocks[0][0] + self.block_s < x - self.window_s:
                self._blocks.popleft()
                expired = True
            if expired:
                self._rebuild()
            self._collect_recent()
        _lower_hull_push(self._block_x, self._block_y, x, y)
        _lower_hull_push(self._hull_x, self._hull_y, x, y)

    def _rebuild(self) -> None:
        """The window's hull from the blocks' hulls (the hull of a union is the hull of the parts' hulls)."""
        xs: list[float] = []
        ys: list[float] = []
        for _, bx, by in self._blocks:
            for x, y in zip(bx, by):
                _lower_hull_push(xs, ys, x, y)
        for x, y in zip(self._block_x, self._block_y):
            _lower_hull_push(xs, ys, x, y)
        self._hull_x, self._hull_y = xs, ys

    # ------------------------------------------------------------------ the line

    def _update(self) -> None:
        """Choose the line (the hull edge under the window's middle, slope bounded), then the uncertainty."""
        xs, ys = self._hull_x, self._hull_y
        n = len(xs)
        if n == 0:
            return
        if n == 1:
            x0, y0, rate = xs[0], ys[0], 0.0
        else:
            middle = 0.5 * (xs[0] + xs[-1])
            i = min(max(bisect.bisect_right(xs, middle) - 1, 0), n - 2)
            rate = (ys[i + 1] - ys[i]) / (xs[i + 1] - xs[i])
            x0, y0 = xs[i], ys[i]
            bound = self.max_rate_error
            if not -bound <= rate <= bound:
                rate = min(max(rate, -bound), bound)
                # the lowest line of that slope under every vertex (the hull's vertices bound all the points)
                k = min(range(n), key=lambda j: ys[j] - rate * xs[j])
                x0, y0 = xs[k], ys[k]
        self._window_line = (x0, y0, rate)
        # the height: the lowest line of that slope under the recent points (a slope off by δε moves the line at
        # the newest sample by δε × the distance to its support: ≤ CLOCK_RECENT_S away, not half the window)
        key = (x0, rate, self._recent_x)
        if self._recent_key is not None and key[0] == self._recent_key[0] and key[1] == self._recent_key[1] \
                and key[2] is self._recent_key[2]:
            recent_y0, x_recent = self._recent_lowest  # the same line over the same completed blocks
        else:
            heights = self._recent_y - rate * (self._recent_x - x0)
            k = int(np.argmin(heights)) if heights.size else -1
            recent_y0, x_recent = (float(heights[k]), float(self._recent_x[k])) if k >= 0 else (math.inf, x0)
            self._recent_key, self._recent_lowest = key, (recent_y0, x_recent)
        for x, y in zip(self._block_x, self._block_y):
            height = y - rate * (x - x0)
            if height < recent_y0:
                recent_y0, x_recent = height, x
        self.uncertainty_s = max(recent_y0 - y0, 0.0)
        y_support = recent_y0 + rate * (x_recent - x0)
        self._line = (x_recent, y_support, rate, xs[0] - CLOCK_BIN_S)  # a point stands for its bin's samples
        self.rate_error = rate
        self.span_s = xs[-1] - xs[0]
        self.offset_s = y_support + rate * (self._last_x - x_recent)

    def _collect_recent(self) -> None:
        """The vertices of the completed blocks that end within CLOCK_RECENT_S of the newest one, as arrays."""
        since = self._block_start - CLOCK_RECENT_S
        xs: list[float] = []
        ys: list[float] = []
        for start, bx, by in reversed(self._blocks):
            if start + self.block_s < since:
                break
            xs.extend(bx)
            ys.extend(by)
        self._recent_x, self._recent_y = np.array(xs), np.array(ys)

    # ------------------------------------------------------------------ output

    def map_times(self, device_time_s) -> np.ndarray:
        """Map device times (s, any shape) onto the host clock with the newest line, s (NaN before any sample)."""
        device = np.asarray(device_time_s, dtype=float)
        line = self._line
        if line is None:
            return np.full(device.shape, np.nan)
        x0, y0, rate, _ = line
        out = device - x0
        out *= rate
        out += device
        out += y0
        return out

    def map_time(self, device_time_s: float) -> float:
        """:meth:`map_times` of one device time (a float), s."""
        line = self._line
        if line is None:
            return math.nan
        x0, y0, rate, _ = line
        return device_time_s + y0 + rate * (device_time_s - x0)


_NO_STARTS = np.empty(0, dtype=np.intp)


class SampleClock:
    """Host times of a sensor's samples: through :class:`DeviceClock` from the device's own sample times
    (``WrenchBatch.device_time_s``), or the arrival stamps where the device has no clock (NaN device times: a
    polled CAN sensor). :meth:`host_times` observes the batch, then maps it (the batch's own samples are never mapped
    later than they arrived). One clock may serve several consumers of the same batches (the monitor's record and
    its dynamic compensator): a batch already observed (the same ``device_time_s`` array) is not observed again."""

    def __init__(self, window_s: float = CLOCK_WINDOW_S) -> None:
        self.clock = DeviceClock(window_s)
        self._last: tuple[np.ndarray, np.ndarray] | None = None

    def host_times(self, arrival_s: np.ndarray, device_time_s: np.ndarray) -> np.ndarray:
        """Return the samples' times on the host clock, s ((N,) as ``arrival_s``; a new array)."""
        last = self._last
        if last is not None and last[0] is device_time_s:
            return last[1].copy()
        device = np.asarray(device_time_s, dtype=float)
        arrival = np.asarray(arrival_s, dtype=float)
        if device.size == 0 or not np.isfinite(device[-1]):
            return arrival.copy()
        # (a batch that ends after it starts, within a window, holds no restart worth looking for: the usual case,
        # no per-sample check; a restart needs a step back longer than a block)
        usual = device[0] <= device[-1] <= device[0] + self.clock.window_s
        starts = _NO_STARTS if usual else session_starts(device, self.clock.block_s, self.clock.window_s)
        if starts.size == 0:
            self.clock.observe(device, arrival)
            out = self.clock.map_times(device)
        else:  # the device restarted its clock inside the batch: each run on the line of its own session
            out = np.empty_like(arrival)
            for run in np.split(np.arange(device.size), starts):
                self.clock.observe(device[run], arrival[run])
                out[run] = self.clock.map_times(device[run])
        self._last = (device_time_s, out)
        return out.copy()

    @property
    def uncertainty_s(self) -> float:
        """The mapping's :attr:`DeviceClock.uncertainty_s` (inf before any sample, or without a device clock)."""
        return self.clock.uncertainty_s

    @property
    def rate_error(self) -> float:
        """The mapping's :attr:`DeviceClock.rate_error`, s/s (0 before two samples)."""
        return self.clock.rate_error


def device_to_host_clock(device_time_s: np.ndarray, arrival_s: np.ndarray) -> np.ndarray:
    """Return a recording's sample times on the host clock, s: the minimum-delay line of the whole recording (the
    hull of every sample, :meth:`DeviceClock.window_line`: below every sample, through the fastest ones), applied
    to every sample. ``device_time_s`` the device's own times (s, in order; a new session by :func:`new_session`
    starts a new mapping for the rest), ``arrival_s`` the host receive stamps, s. NaN device times (no device
    clock) keep their arrival stamps."""
    device = np.asarray(device_time_s, dtype=float)
    arrival = np.broadcast_to(np.asarray(arrival_s, dtype=float), device.shape)
    out = np.array(arrival, dtype=float)
    known = np.flatnonzero(np.isfinite(device))
    if known.size == 0:
        return out
    runs = np.split(known, session_starts(device[known]))
    for run in runs:
        span = float(device[run[-1]] - device[run[0]])
        clock = DeviceClock(window_s=span + 2.0 * CLOCK_BLOCK_S)
        clock.observe(device[run], arrival[run])
        x0, y0, rate = clock.window_line()
        out[run] = device[run] + y0 + rate * (device[run] - x0)
    return out
