"""Matching sensor samples to robot samples in time: resampling between 7 kHz and 500 Hz.

Both streams are first put on the host's monotonic clock by :class:`ftacq.timebase.DeviceClock` (each device's
own sample times through the minimum-delay line of their arrival stamps; docs/dynamics.md, "How the clocks are
aligned"). What remains is a constant lag between the two streams (the fastest transport of each, the sensor's filter
delay): :func:`ftacq.dynamics.identify.estimate_lag` measures it from the motion itself. This module averages and
interpolates samples between the two time bases.
"""

from __future__ import annotations

import numpy as np

_min = np.minimum.reduce
"""The least entry of an array (np.min without its Python layer, ~3x faster on a batch's few values)."""


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
    following = time_s.searchsorted(at_s, side="right")  # (the method: np.searchsorted's Python layer cost as much)
    np.maximum(following, 1, out=following)
    np.minimum(following, time_s.shape[0] - 1, out=following)
    index = following - 1
    start = time_s.take(index)
    span = time_s.take(following)
    span -= start
    if not (span.size and _min(span) > 0.0):  # a repeated time or NaN (NaN > 0 is False): that interval held
        span = np.where(span > 0.0, span, 1.0)
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


def slerp_rows(at_s: np.ndarray, time_s: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """Rotations (M, 3, 3) sampled at sorted ``time_s`` (M,), s, interpolated onto ``at_s`` (N,), s, along the
    shortest arc between the two neighbours of each time (slerp: R_i · exp(f · log(R_iᵀ R_{i+1})), f the fraction
    of the interval; equal to :class:`scipy.spatial.transform.Slerp` to 1e-15, at a fraction of its cost on the
    live path's dozens of rows); held at the ends as :func:`interpolate_rows` holds. Returns (N, 3, 3) proper
    rotations: an entry-wise linear interpolation is off SO(3) by θ²/8 (θ the rotation over the interval). Numpy
    batches (:func:`ftacq.so3.rotvec_from_rotation`, :func:`ftacq.so3.rotation_from_rotvec`), no Python loop per
    sample."""
    from ftacq.so3 import rotation_from_rotvec, rotvec_from_rotation

    time_s = np.asarray(time_s, dtype=float)
    at_s = np.asarray(at_s, dtype=float)
    known = np.asarray(rotations, dtype=float).reshape(-1, 3, 3)
    if time_s.shape[0] == 1:
        return np.repeat(known, at_s.shape[0], axis=0)
    index = np.searchsorted(time_s, at_s, side="right") - 1
    np.clip(index, 0, time_s.shape[0] - 2, out=index)
    span = time_s[index + 1] - time_s[index]
    fraction = np.divide(at_s - time_s[index], span, out=np.zeros_like(at_s), where=span > 0)
    np.clip(fraction, 0.0, 1.0, out=fraction)
    used = np.unique(index)  # the intervals holding samples: log only those
    steps = np.zeros((known.shape[0], 3))
    steps[used] = rotvec_from_rotation(np.swapaxes(known[used], 1, 2) @ known[used + 1])
    return known[index] @ rotation_from_rotvec(steps[index] * fraction[:, None])
