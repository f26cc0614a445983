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


STEP_ISOLATION = 0.05
"""A change of ``target_qdd`` between two states is taken as one step (a moveJ's phase boundary) when the interval
before changed by at most this fraction of it: a q̈ that varies from state to state (a moveL, a blend) is left to
the linear interpolation."""


def acceleration_steps(time_s: np.ndarray, target_qd: np.ndarray,
                       target_qdd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Locate the steps of the target's piecewise-constant q̈ inside the state intervals (a moveJ's trapezoid
    switches at any instant, not at a state). Over the interval (tⱼ, tⱼ₊₁) of length Δ whose q̈ changes from a = q̈ⱼ
    to b = q̈ⱼ₊₁, the speed changes by q̇ⱼ₊₁ − q̇ⱼ = a s + b (Δ − s), s the time from tⱼ to the step: s by least
    squares over the joints, clipped to [0, Δ]. Only isolated steps (:data:`STEP_ISOLATION`; the interval before
    must be in the rows given).

    Returns (j (S,): the row before each step, the step's time (S,) on the rows' clock, s, and b − a (S, 6), rad/s²)."""
    qdd = np.asarray(target_qdd, dtype=float)
    change = qdd[1:] - qdd[:-1]
    if not change.any():  # (the usual case, per new state: a constant q̈, at rest or cruising)
        return np.empty(0, dtype=np.intp), np.empty(0), np.empty((0, 6))
    t = np.asarray(time_s, dtype=float)
    qd = np.asarray(target_qd, dtype=float)
    size = np.einsum("ij,ij->i", change, change)
    isolated = size[:-1] <= STEP_ISOLATION ** 2 * size[1:]
    isolated &= size[1:] > 0.0
    j = np.flatnonzero(isolated) + 1
    span = t[j + 1] - t[j]
    jump = change[j]
    # (qd[j+1] - qd[j]) - b Δ = (a - b) s
    rest = qd[j + 1] - qd[j] - qdd[j + 1] * span[:, None]
    s = np.einsum("ij,ij->i", rest, jump)
    s /= -size[j]
    np.clip(s, 0.0, span, out=s)
    return j, t[j] + s, jump


def step_shape(at_s: np.ndarray, state_s: np.ndarray, step_s: float, row_s: float, span_s: float,
               servo_lag_s: float) -> np.ndarray:
    """How much of one step of the arm's q̈ (of b − a; at ``step_s`` + ``servo_lag_s``, the step located by
    :func:`acceleration_steps` in the target's interval [``row_s``, ``row_s`` + ``span_s``]) the linear interpolation
    between the states misses at ``at_s`` (N,): H(t − step) − g(t), g the linear interpolation over the states'
    times ``state_s`` (sorted; held beyond the ends, as :func:`~ftacq.dynamics.timing.interpolate_rows`) of the
    weight (t − τ − row)/span ∈ [0, 1] that :func:`joint_acceleration` gave the step's later row at each state.
    Zero outside the states around the step. The predicted wrench's error is this times B(q)(b − a), B the model's
    q̈-linear part (its wrench is affine in q̈)."""
    first = max(int(state_s.searchsorted(row_s + servo_lag_s, side="right")) - 1, 0)
    last = int(state_s.searchsorted(row_s + span_s + servo_lag_s, side="left")) + 1
    knots = state_s[first:last]
    weight = np.subtract(knots, row_s + servo_lag_s)
    weight /= span_s
    np.clip(weight, 0.0, 1.0, out=weight)
    shape = np.greater_equal(at_s, step_s + servo_lag_s).astype(float)
    shape -= np.interp(at_s, knots, weight)
    return shape
