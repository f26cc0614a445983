"""Which joint state the dynamic model uses, sample by sample: the physical arm's, from one source.

A real arm's joints follow the controller's target a few ms late (servo tracking): ``actual_q`` and ``actual_qd``
at time t are ``target_q``/``target_qd`` of about t − τ (τ the servo lag, 2-8 ms on a UR), and the tool's wrench
at t is that of the actual motion. The model therefore takes q and q̇ from ``actual_*`` and q̈ as the physical
arm's at the same instant:

- While the controller follows its own trajectory (a moveJ/moveL, a program, the pendant's jog), ``target_qdd``
  *τ earlier* (:func:`joint_acceleration` with ``servo_lag_s``: the target's rows interpolated at t − τ): exact and
  noise-free for an arm that follows its target by a delay. The arm tracks the target when |target_qd(t − τ) −
  actual_qd(t)| ≤ :data:`TRACKING_TOLERANCE_RAD_S` on every joint. Taking ``target_qdd`` of t itself (ftacq before
  issue 37) mixed two instants: an acceleration τ ahead of the orientation and speeds it was used with.
- Otherwise (freedrive, a collision, an external servo stream, a controller that leaves target_qdd at zero) the
  derivative of ``actual_qd``, a central difference over ± :data:`DERIVATIVE_HALF_WIDTH` samples (±4 ms at
  500 Hz: a zero-phase low-pass of about 60 Hz); at the newest samples one-sided (a 4 ms delay there).

τ is measured from the recorded motion (:func:`estimate_servo_lag`: the shift of ``target_qd`` that fits
``actual_qd`` best), stored with the calibration (``dynamics.servo_lag_ms``) and used live.
"""

from __future__ import annotations

import math

import numpy as np

from ftacq.dynamics.timing import interpolate_rows

TRACKING_TOLERANCE_RAD_S = 0.02
DERIVATIVE_HALF_WIDTH = 2
SERVO_LAG_MAX_S = 0.03
"""The servo lag is searched within [0, this], s (a UR's is a few ms)."""
SERVO_LAG_STEP_S = 0.0002
_MIN_MOVING_RAD_S = 1e-3


def history_rows(servo_lag_s: float, period_s: float = 0.002) -> int:
    """Older robot states the acceleration of a state needs: the derivative's half width, or the rows back to τ
    earlier and one more (for the interpolation), whichever is more."""
    return max(DERIVATIVE_HALF_WIDTH, int(math.ceil(max(servo_lag_s, 0.0) / period_s)) + 1)


def filtered_derivative(time_s: np.ndarray, values: np.ndarray, half_width: int = DERIVATIVE_HALF_WIDTH) -> np.ndarray:
    """d values / dt (M, k) by differences over ± ``half_width`` samples (one-sided at the ends)."""
    t = np.asarray(time_s, dtype=float)
    v = np.asarray(values, dtype=float).reshape(t.shape[0], -1)
    m = t.shape[0]
    if m < 2:
        return np.zeros_like(v)
    index = np.arange(m)
    hi = np.minimum(index + half_width, m - 1)
    lo = np.maximum(index - half_width, 0)
    span = t[hi] - t[lo]
    return (v[hi] - v[lo]) / np.where(span > 0, span, np.inf)[:, None]


def estimate_servo_lag(time_s: np.ndarray, actual_qd: np.ndarray, target_qd: np.ndarray,
                       search_s: float = SERVO_LAG_MAX_S, step_s: float = SERVO_LAG_STEP_S) -> float | None:
    """Return τ (s): how late the arm follows its target, the shift that minimises Σ |actual_qd(t) −
    target_qd(t − τ)|² over the states (grid of ``step_s`` in [0, ``search_s``], refined by a parabola); None when the
    target never moves (nothing to measure)."""
    t = np.asarray(time_s, dtype=float)
    actual = np.asarray(actual_qd, dtype=float).reshape(t.shape[0], 6)
    target = np.asarray(target_qd, dtype=float).reshape(t.shape[0], 6)
    if t.shape[0] < 10 or float(np.abs(target).max(initial=0.0)) < _MIN_MOVING_RAD_S:
        return None
    inner = t - search_s >= t[0]  # rows whose shifted target lies inside the record
    if np.count_nonzero(inner) < 10:
        return None
    shifts = np.arange(0.0, search_s + 0.5 * step_s, step_s)
    costs = np.array([float(np.sum((actual[inner] - interpolate_rows(t[inner] - s, t, target)) ** 2))
                      for s in shifts])
    best = int(np.argmin(costs))
    if 0 < best < len(shifts) - 1:
        c0, c1, c2 = costs[best - 1:best + 2]
        curvature = c0 - 2 * c1 + c2
        if curvature > 0:
            return float(shifts[best] + 0.5 * step_s * (c0 - c2) / curvature)
    return float(shifts[best])


def joint_acceleration(time_s: np.ndarray, actual_qd: np.ndarray, target_qd: np.ndarray,
                       target_qdd: np.ndarray, tolerance_rad_s: float = TRACKING_TOLERANCE_RAD_S,
                       servo_lag_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Return (q̈ (M, 6) of the physical arm, tracking (M,) bool: True where the target's was used) for robot
    samples (M, 6): ``target_qdd`` of ``servo_lag_s`` earlier while the arm tracks the target, else the filtered
    derivative of ``actual_qd``. The first states, whose t − τ lies before the rows given, take the oldest row's."""
    if servo_lag_s > 0.0:  # both targets in one interpolation (column by column: the same values as two)
        t = np.asarray(time_s, dtype=float)
        targets = interpolate_rows(t - servo_lag_s, t, np.concatenate((target_qd, target_qdd), axis=1))
        target_qd, target_qdd = targets[:, :6], targets[:, 6:]
    deviation = np.subtract(target_qd, actual_qd, dtype=float)
    np.abs(deviation, out=deviation)
    tracking = np.logical_and.reduce(deviation <= tolerance_rad_s, axis=1)  # np.all without its Python layer
    if np.logical_and.reduce(tracking):
        return np.asarray(target_qdd, dtype=float), tracking
    derivative = filtered_derivative(time_s, actual_qd)
    return np.where(tracking[:, None], target_qdd, derivative), tracking


def physical_acceleration(time_s: np.ndarray, actual_qd: np.ndarray, target_qd: np.ndarray,
                          target_qdd: np.ndarray) -> tuple[np.ndarray, float]:
    """Return (q̈ (M, 6) of the physical arm, the servo lag τ (s) measured from these states, 0 when the target
    never moved) for a recorded motion: :func:`estimate_servo_lag`, then :func:`joint_acceleration`."""
    lag = estimate_servo_lag(time_s, actual_qd, target_qd) or 0.0
    qdd, _ = joint_acceleration(time_s, actual_qd, target_qd, target_qdd, servo_lag_s=lag)
    return qdd, lag
