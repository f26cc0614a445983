"""Rest windows: the still, contact-free stretches the drift tracker learns from (pure numpy, fed with batches).

Step 1 of :mod:`ftacq.drift`: after the arm has been still for ``settle_s``, consecutive windows of ``window_s``
are summarised: mean, sample std, count, and the least-squares slope of each channel within the window (its
standard error from the residual scatter: a hand on the tool changes within a window, drift does not). Motion
discards the open window. Two windows share the calibration's per-pose model error when their flange orientations
agree within ``SAME_ORIENTATION_RAD``.

:func:`settled_starts` judges offline, from the samples, when each rest of a recorded motion has settled (the quick
calibration's holds: the tool rings after each stop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SAME_ORIENTATION_RAD = 0.01
"""Two windows whose flange orientations differ by less than this angle (rad) share the model error m."""


@dataclass(frozen=True)
class RestWindow:
    """One window of samples at rest (residuals: compensated with the file's calibration).

    Attributes:
        start_s, end_s: first and last sample time, s. count: samples. mean, std: (6,) N and N·m.
        slope_t: (6,) in-window slope over its standard error. flange_R_base: (3, 3) orientation (or None).
        slope, slope_se: (6,) in-window slope per s and its standard error (None: not measured).
    """

    start_s: float
    end_s: float
    count: int
    mean: np.ndarray
    std: np.ndarray
    slope_t: np.ndarray
    flange_R_base: np.ndarray | None
    slope: np.ndarray | None = None
    slope_se: np.ndarray | None = None

    @property
    def mid_s(self) -> float:
        return 0.5 * (self.start_s + self.end_s)

    @property
    def noise_variance(self) -> np.ndarray:
        """(6,) variance of the mean from the sensor's noise, std²/count (samples independent)."""
        return self.std**2 / max(self.count, 1)


def summarise_window(time_s: np.ndarray, values: np.ndarray, flange_R_base: np.ndarray | None) -> RestWindow:
    """Return the :class:`RestWindow` of samples (N,) s and (N, 6)."""
    t = time_s - time_s.mean()
    mean = values.mean(axis=0)
    centred = values - mean
    std = centred.std(axis=0, ddof=1) if len(values) > 1 else np.zeros(6)
    sxx = float(t @ t)
    if sxx > 0 and len(values) > 2:
        slope = (t @ centred) / sxx
        residual = centred - np.outer(t, slope)
        slope_se = np.sqrt(np.maximum((residual**2).sum(axis=0) / (len(values) - 2), 1e-300) / sxx)
        return RestWindow(float(time_s[0]), float(time_s[-1]), int(len(values)), mean, std, slope / slope_se,
                          flange_R_base, slope, slope_se)
    return RestWindow(float(time_s[0]), float(time_s[-1]), int(len(values)), mean, std, np.zeros(6), flange_R_base)


def same_orientation(a: np.ndarray | None, b: np.ndarray | None, tolerance_rad: float = SAME_ORIENTATION_RAD) -> bool:
    """True when two flange orientations (3, 3) differ by less than ``tolerance_rad`` (two unknowns are the same)."""
    if a is None or b is None:
        return a is None and b is None
    cos = (float(np.trace(np.asarray(a).T @ np.asarray(b))) - 1.0) / 2.0
    return math.acos(min(1.0, max(-1.0, cos))) < tolerance_rad


SETTLE_BOX_S = 0.02
"""Box over which :func:`settled_starts` averages the samples, s (a ring of 5-50 Hz still shows between boxes)."""
SETTLE_Z = 4.0
"""A change between consecutive box means beyond this many of its noise σ is the rest still moving ..."""
SETTLE_QUIET_S = 0.15
"""... and a rest has settled at the first box after which no change exceeds it for this long, s (over a period of a
ring of 7 Hz and more)."""


def settled_starts(time_s: np.ndarray, values: np.ndarray, rests: list[tuple[float, float]],
                   box_s: float = SETTLE_BOX_S, z: float = SETTLE_Z,
                   quiet_s: float = SETTLE_QUIET_S) -> tuple[list[float], np.ndarray]:
    """When each rest [t0, t1) s of samples (N,) s, (N, 6) has settled, judged from the data as the full run's settle
    check does (the sensor still, not only the arm), with thresholds from the samples' own noise.

    The samples of each rest are averaged in boxes of ``box_s``; the change between consecutive box means, over
    its noise σ √(1/n_j + 1/n_j+1) (σ per channel: the median absolute change over every rest, robust to the
    ringing minority, so correlated or filtered noise sets its own scale), must stay within ``z`` in every channel
    for ``quiet_s``; the rest has settled at the end of the first box from which it does (t1 if never). A slow
    drift moves a box mean by far less than its noise; a decaying oscillation does not.

    Returns (the settled time of each rest, s; the largest ring amplitude that can pass unseen (6,), z σ for a
    box: what a verdict allows for what is left of it).
    """
    time_s = np.asarray(time_s, dtype=float)
    values = np.asarray(values, dtype=float)
    boxes: list[tuple[np.ndarray, np.ndarray, np.ndarray] | None] = []
    for t0, t1 in rests:
        lo, hi = np.searchsorted(time_s, [t0, t1])
        index = np.floor((time_s[lo:hi] - t0) / box_s).astype(int)
        if hi - lo < 2 or index[-1] < 2:
            boxes.append(None)
            continue
        count = np.bincount(index)
        sums = np.stack([np.bincount(index, values[lo:hi, c], minlength=len(count)) for c in range(6)], axis=1)
        full = count >= 3
        starts = t0 + box_s * np.arange(len(count))
        boxes.append((starts[full], sums[full] / count[full, None], count[full]))
    scaled = [np.diff(m, axis=0) / np.sqrt(1.0 / n[:-1] + 1.0 / n[1:])[:, None]
              for b in boxes if b is not None for _, m, n in [b] if len(n) > 1]
    if not scaled:
        return [float(t1) for _, t1 in rests], np.zeros(6)
    pooled = np.concatenate(scaled)
    sigma = np.maximum(1.4826 * np.median(np.abs(pooled), axis=0) / np.sqrt(2.0), 1e-300)  # one sample's σ
    settled = []
    quiet = max(int(round(quiet_s / box_s)), 1)
    typical = float(np.median(np.concatenate([b[2] for b in boxes if b is not None])))
    for (t0, t1), b in zip(rests, boxes):
        if b is None or len(b[2]) < 2:
            settled.append(float(t1))
            continue
        starts, means, count = b
        change = np.abs(np.diff(means, axis=0)) / (sigma * np.sqrt(1.0 / count[:-1] + 1.0 / count[1:])[:, None])
        loud = np.max(change, axis=1) > z
        at = float(t1)
        for j in range(len(loud)):
            if not loud[j:j + quiet].any() and (j + quiet <= len(loud) or not loud[j:].any()):
                at = float(starts[j] + box_s) if j > 0 or loud[0] else float(t0)
                break
        settled.append(min(at, float(t1)))
    return settled, z * sigma * np.sqrt(2.0 / max(typical, 1.0))


class RestWindows:
    """Cuts batches of residual samples into rest windows (module docstring, step 1)."""

    def __init__(self, window_s: float, settle_s: float) -> None:
        self.window_s = float(window_s)
        self.settle_s = float(settle_s)
        self._still_since: float | None = None
        self._times: list[np.ndarray] = []
        self._values: list[np.ndarray] = []

    def feed(self, time_s: np.ndarray, values: np.ndarray, still: bool,
             flange_R_base: np.ndarray | None = None) -> list[RestWindow]:
        """Add a batch (all samples share ``still``); return the windows it completed."""
        if len(time_s) == 0:
            return []
        if not still:
            self._still_since = None
            self._times.clear()
            self._values.clear()
            return []
        if self._still_since is None:
            self._still_since = float(time_s[0])
        start = self._still_since + self.settle_s
        keep = time_s >= start
        if not keep.any():
            return []
        self._times.append(np.asarray(time_s[keep], dtype=float))
        self._values.append(np.asarray(values[keep], dtype=float))
        out = []
        while self._times and self._times[-1][-1] - self._times[0][0] >= self.window_s:
            times = np.concatenate(self._times)
            vals = np.concatenate(self._values)
            end = int(np.searchsorted(times, times[0] + self.window_s, side="left"))  # [start, start + window)
            out.append(summarise_window(times[:end], vals[:end], flange_R_base))
            self._times, self._values = ([times[end:]], [vals[end:]]) if end < len(times) else ([], [])
        return out


__all__ = ["RestWindow", "RestWindows", "summarise_window", "same_orientation", "settled_starts", "SAME_ORIENTATION_RAD",
           "SETTLE_BOX_S", "SETTLE_Z", "SETTLE_QUIET_S"]
