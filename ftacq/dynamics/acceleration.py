"""Which joint acceleration the dynamic model uses, sample by sample.

- While the controller follows its own trajectory (a moveJ/moveL, a program, the pendant's jog), its
  ``target_qdd`` is the acceleration it commands and the joints track it within the servo error: exact, no delay,
  no noise. ftacq takes it when the arm tracks the target: |target_qd − actual_qd| ≤ :data:`TRACKING_TOLERANCE_RAD_S`
  on every joint.
- Otherwise (freedrive, a collision, an external servo stream, a controller that leaves target_qdd at zero) the
  target says nothing about the motion: the derivative of ``actual_qd`` is used, a central difference over
  ± :data:`DERIVATIVE_HALF_WIDTH` samples (±4 ms at 500 Hz: a zero-phase low-pass of about 60 Hz, which keeps
  encoder quantisation noise down while the tool's accelerations, below a few Hz on a technician's jog, pass).
  At the newest samples the difference becomes one-sided (a 4 ms delay there).
"""

from __future__ import annotations

import numpy as np

TRACKING_TOLERANCE_RAD_S = 0.02
DERIVATIVE_HALF_WIDTH = 2


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


def joint_acceleration(time_s: np.ndarray, actual_qd: np.ndarray, target_qd: np.ndarray,
                       target_qdd: np.ndarray, tolerance_rad_s: float = TRACKING_TOLERANCE_RAD_S
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Return (q̈ (M, 6), tracking (M,) bool: True where target_qdd was used) for robot samples (M, 6)."""
    deviation = np.subtract(target_qd, actual_qd, dtype=float)
    np.abs(deviation, out=deviation)
    tracking = np.logical_and.reduce(deviation <= tolerance_rad_s, axis=1)  # np.all without its Python layer
    if np.logical_and.reduce(tracking):
        return np.asarray(target_qdd, dtype=float), tracking
    derivative = filtered_derivative(time_s, actual_qd)
    return np.where(tracking[:, None], target_qdd, derivative), tracking
