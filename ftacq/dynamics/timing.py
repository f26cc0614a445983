"""Matching sensor samples to robot samples by time: one host clock, and resampling between 7 kHz and 500 Hz.

How the clocks are aligned (docs/dynamics.md):

- Both streams are put on the host's monotonic clock (``time.monotonic``). Each device counts its own time — the
  sensor its sample sequence number at a fixed rate, the UR controller its ``timestamp`` — and each sample is
  stamped on arrival. Arrival = device time + offset + a transport delay that is never negative, so the offset is
  the *lower envelope* of (arrival − device time): :func:`device_to_host_clock`. This removes the receive jitter
  (a 1 ms wake-up coalescing of the sensor driver, a descheduled thread) without trusting either clock's epoch.
- Over hours the two clocks drift apart (tens of ppm is normal for a crystal): the offset is then a slowly
  moving line, not a constant. :class:`ControllerClock` (the UR controller's ``timestamp``, for
  drivers/ur_stream.py and the bridge's cycle states) lets the lower envelope rise by at most
  :data:`CLOCK_DRIFT_ALLOWANCE` of the elapsed device time and fall at once, and :func:`settled_offsets` lets a
  later package that waited less lower the offsets of the rows before it, within the same allowance. The sensor
  side fits its period instead (procedures/dynamic_compensation.py ``SensorClock``).
- What remains is a constant lag between the two streams (the fastest transport of each, the sensor's filter
  delay): :func:`ftacq.dynamics.identify.estimate_lag` measures it from the motion itself (the shift that best
  fits the rigid-body model) and reports it.
"""

from __future__ import annotations

import numpy as np

CLOCK_DRIFT_ALLOWANCE = 1e-4
"""Fastest rate (s/s, 100 ppm) at which the offset between a device's clock and the host's may change: more than
two crystals drift apart (tens of ppm each), far less than the envelope of a queue that is filling (a package
that waited longer than the one before it raises arrival − timestamp by its whole extra delay)."""


class ControllerClock:
    """The host time of a device's own timestamps (the UR controller's ``timestamp``, s), learnt from their arrival
    stamps (host monotonic clock, s) as they come.

    Arrival = timestamp + offset + a transport delay that is never negative, and the offset moves at most
    :data:`CLOCK_DRIFT_ALLOWANCE` × the elapsed timestamp (the clocks' drift). So every package bounds the offset
    from above, at its own time and, widened by the allowance, at every later time; the offset at timestamp t is
    the tightest such bound, ``min over packages k (arrival_k − timestamp_k + allowance × (t − timestamp_k))``:

    - host slower than the device (arrival − timestamp falls): the newest package is the bound, followed at once;
    - host faster (arrival − timestamp rises, tens of ppm): the bound rises with the allowance and meets the
      packages that waited least, so the offset follows instead of staying at an old minimum (a plain lower
      envelope puts the states 50 ppm × the run's duration older than they are: 0.18 s an hour);
    - a package that waited in a queue (ms) rises far faster than the allowance and does not move it.

    The result is the true offset plus the smallest recent transport delay (part of the constant lag measured
    between the streams), never more than one package's own delay. Kept as one running minimum of
    (arrival − timestamp − allowance × elapsed), O(1) per package; :meth:`observe` takes a batch as numpy arrays,
    :meth:`observe_one` one package as floats (the bridge's feed thread, once per cycle). A timestamp going
    backwards (another controller session) starts the mapping anew. One reader thread; not locked.
    """

    def __init__(self) -> None:
        self._origin_s: float | None = None
        """The first timestamp (s): elapsed times are taken from it (keeps the sums small over days)."""
        self._floor_s = np.inf
        """min over packages of (arrival − timestamp − allowance × (timestamp − origin)), s."""
        self._last_timestamp_s = -np.inf
        self.offset_s: float | None = None
        """Host time − device time at the newest timestamp observed, s (None before the first package)."""

    def observe(self, arrival_s, timestamp_s) -> np.ndarray:
        """Take a batch of packages, oldest first: ``timestamp_s`` (N,) device times, ``arrival_s`` their host receive
        stamps ((N,) or one stamp for the whole read). Return each package's offset (N,) as known after it (host
        time = timestamp + offset), and update :attr:`offset_s`."""
        timestamp = np.asarray(timestamp_s, dtype=float).reshape(-1)
        arrival = np.asarray(arrival_s, dtype=float)
        if timestamp.size == 0:
            return np.empty(0)
        if timestamp[0] < self._last_timestamp_s or (timestamp[1:] < timestamp[:-1]).any():
            # another session: the mapping starts again at each timestamp that went backwards
            arrival = np.broadcast_to(arrival, timestamp.shape)
            back = np.flatnonzero(np.diff(timestamp, prepend=self._last_timestamp_s) < 0)
            parts = np.split(np.arange(timestamp.size), back)
            out = [self._observe_run(arrival[parts[0]], timestamp[parts[0]])] if parts[0].size else []
            for part in parts[1:]:
                self._origin_s = None
                out.append(self._observe_run(arrival[part], timestamp[part]))
            return np.concatenate(out)
        return self._observe_run(arrival, timestamp)

    def _observe_run(self, arrival: np.ndarray, timestamp: np.ndarray) -> np.ndarray:
        if self._origin_s is None:
            self._origin_s, self._floor_s = float(timestamp[0]), np.inf
        slope = CLOCK_DRIFT_ALLOWANCE * (timestamp - self._origin_s)
        floor = np.minimum.accumulate(arrival - timestamp - slope)
        np.minimum(floor, self._floor_s, out=floor)
        offsets = floor + slope
        self._floor_s = float(floor[-1])
        self._last_timestamp_s = float(timestamp[-1])
        self.offset_s = float(offsets[-1])
        return offsets

    def observe_one(self, arrival_s: float, timestamp_s: float) -> float:
        """Take one package (as :meth:`observe`, in floats: no array per package); return its offset, s."""
        if self._origin_s is None or timestamp_s < self._last_timestamp_s:
            self._origin_s, self._floor_s = timestamp_s, np.inf
        slope = CLOCK_DRIFT_ALLOWANCE * (timestamp_s - self._origin_s)
        self._floor_s = min(self._floor_s, arrival_s - timestamp_s - slope)
        self._last_timestamp_s = timestamp_s
        self.offset_s = self._floor_s + slope
        return self.offset_s


def settled_offsets(timestamp_s: np.ndarray, offset_s: np.ndarray) -> np.ndarray:
    """Return the offsets (N,) of a window of rows, oldest first, each lowered by the rows after it.

    ``offset_s`` are the offsets :class:`ControllerClock` gave each row when it arrived (what was known then). A
    later package that waited less bounds the offset at an earlier time too, within the drift allowance:
    ``min over rows k ≥ i (offset_k + allowance × (timestamp_k − timestamp_i))``. Without it the first rows after
    the stream starts (or after a queue) keep their own delay, and host times could even run backwards where the
    offset falls by more than one period. After it, consecutive offsets differ by at most the allowance × the time
    between them, so host times keep the timestamps' order. Only rows after a row change it: the newest rows come
    out the same however far back the window reaches. Timestamps not in order (two sessions) are left as given."""
    timestamp = np.asarray(timestamp_s, dtype=float)
    offset = np.asarray(offset_s, dtype=float)
    if timestamp.size < 2 or np.any(np.diff(timestamp) < 0):
        return offset.copy()
    slope = CLOCK_DRIFT_ALLOWANCE * (timestamp - timestamp[-1])
    return np.minimum.accumulate((offset + slope)[::-1])[::-1] - slope


def device_to_host_clock(device_time_s: np.ndarray, arrival_s: np.ndarray) -> np.ndarray:
    """Return the samples' times on the host clock: device time + the lower envelope of (arrival − device time).

    ``device_time_s`` is the device's own time of each sample (s: a sequence number over the sample rate, or the
    controller's timestamp); ``arrival_s`` their host receive stamps. The device's rate is trusted (a 50 ppm
    crystal drifts 0.05 ms in a second, 3 ms in a minute: record windows of at most a few minutes)."""
    device = np.asarray(device_time_s, dtype=float)
    arrival = np.asarray(arrival_s, dtype=float)
    if device.size == 0:
        return device.copy()
    return device + float(np.min(arrival - device))


def box_average(time_s: np.ndarray, values: np.ndarray, at_s: np.ndarray, width_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Return (mean of ``values`` over [t − width/2, t + width/2) at each t of ``at_s``, count per window).

    ``time_s`` must be sorted. Windows with no sample give NaN. Vectorised (cumulative sums + searchsorted)."""
    time_s = np.asarray(time_s, dtype=float)
    values = np.asarray(values, dtype=float).reshape(time_s.shape[0], -1)
    at_s = np.asarray(at_s, dtype=float)
    sums = np.vstack([np.zeros((1, values.shape[1])), np.cumsum(values, axis=0)])
    lo = np.searchsorted(time_s, at_s - 0.5 * width_s, side="left")
    hi = np.searchsorted(time_s, at_s + 0.5 * width_s, side="left")
    count = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (sums[hi] - sums[lo]) / count[:, None]
    mean[count == 0] = np.nan
    return mean, count


def interpolate_rows(at_s: np.ndarray, time_s: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of each column of ``values`` (M, k) sampled at sorted ``time_s`` (M,) onto ``at_s`` (N,);
    held constant beyond the ends (the newest robot state is used for sensor samples newer than it). Returns a new
    (N, k) array.

    Called per sensor batch on the live path (a dozen samples): ufuncs with ``out=`` rather than ``np.clip`` and
    fancy indexing, the same arithmetic (``v[i] + f (v[i+1] − v[i])``)."""
    time_s = np.asarray(time_s, dtype=float)
    values = np.asarray(values, dtype=float).reshape(time_s.shape[0], -1)
    at_s = np.asarray(at_s, dtype=float)
    if time_s.shape[0] == 1:
        return np.repeat(values, at_s.shape[0], axis=0)
    index = np.searchsorted(time_s, at_s, side="right")
    index -= 1
    np.maximum(index, 0, out=index)
    np.minimum(index, time_s.shape[0] - 2, out=index)
    following = index + 1
    start = time_s.take(index)
    span = time_s.take(following)
    span -= start
    flat = np.greater(span, 0.0)
    np.logical_not(flat, out=flat)
    np.copyto(span, 1.0, where=flat)  # as np.where(span > 0, span, 1.0), NaN included
    fraction = np.subtract(at_s, start, out=start)
    fraction /= span
    np.maximum(fraction, 0.0, out=fraction)
    np.minimum(fraction, 1.0, out=fraction)
    lower = values.take(index, axis=0)
    out = values.take(following, axis=0)
    out -= lower
    out *= fraction[:, None]
    out += lower
    return out
