"""Drift or step: do rest windows that the drift tracker's innovation gate refused continue its track smoothly?

The tracker (:class:`ftacq.drift.DriftTracker`) refuses a rest window whose mean is too far from its prediction.
That happens for two different reasons, which need opposite answers:

- **a step**: the residual at rest jumped (a push held steadily on the tool, another tool put on during a move, the
  box biased or power-cycled). The level after the jump is off the track, but it moves at the tracked rate.
  It must never be absorbed; ``--auto-tare`` must stop applying the offset it no longer trusts.
- **drift faster than tracked**: the sensor warms up faster than the tracker's rate estimate allowed (a rate the
  prior thought unlikely, or a long move with a changing rate). The windows lie on a line whose slope differs from
  the tracked rate, and that line joins the track without a jump.

:func:`judge` fits a straight line (level and rate per channel, weighted by each window's noise, std²/count)
through the refused windows taken at one orientation and tests continuity with the last accepted state (offset
b_a, rate r_a at t_a). If the rate moved from r_a to the line's rate s over the gap (monotonically, on any path),
the offset moved by between r_a (t_c − t_a) and s (t_c − t_a), so the distance D of L(t_c) − b_a from that interval
(L the line's level at the windows' centre t_c; 0 inside it) is zero up to its variance: the line's and the track's
covariance through the trapezoid's linear combination (L − b_a − (r_a + s)/2 · (t_c − t_a)), the model error's variance at a new orientation (the line's level includes
the model error there; the track knows it only where it last learnt) and the base process noise over the gap. Drift when
Σ D²/var(D) over the six channels is within the χ² gate, the line fits its windows (χ²/dof ≤
``MAX_LINE_CHI2_PER_DOF``: a drift is smooth) and no channel's rate exceeds the largest plausible drift rate;
otherwise a step, whose size is the jump against the track's own prediction, L(t_c) − b_a − r_a (t_c − t_a).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

MAX_LINE_CHI2_PER_DOF = 3.0
"""The refused windows must lie on their line within this χ²/dof (their noise std²/count): drift is smooth."""


@dataclass(frozen=True)
class Line:
    """A weighted straight line through window means, per channel: ``level`` (6,) at ``time_s``, ``rate`` (6,)
    per s, ``covariance`` (6, 2, 2) of [level, rate], ``chi2_per_dof`` of the windows about it."""

    time_s: float
    level: np.ndarray
    rate: np.ndarray
    covariance: np.ndarray
    chi2_per_dof: float

    def at(self, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Return the line's level (6,) at ``time_s`` and its covariance with the rate (6, 2, 2)."""
        dt = time_s - self.time_s
        J = np.array([[1.0, dt], [0.0, 1.0]])
        return self.level + dt * self.rate, J @ self.covariance @ J.T


def fit_line(time_s: np.ndarray, mean: np.ndarray, variance: np.ndarray) -> Line:
    """Fit level + rate per channel to window means (n,) s, (n, 6), their variances (n, 6); level at the
    weighted centre of the times (where level and rate are uncorrelated)."""
    t = np.asarray(time_s, dtype=float)
    w = 1.0 / np.maximum(np.asarray(variance, dtype=float), 1e-300)  # (n, 6)
    sw = w.sum(axis=0)
    centre = (w * t[:, None]).sum(axis=0) / sw  # (6,)
    dt = t[:, None] - centre
    level = (w * mean).sum(axis=0) / sw
    sxx = np.maximum((w * dt**2).sum(axis=0), 1e-300)
    rate = (w * dt * (mean - level)).sum(axis=0) / sxx
    residual = mean - level - dt * rate
    dof = max(mean.size - 2 * mean.shape[1], 1)
    chi2 = float((w * residual**2).sum()) / dof
    t_ref = float(np.mean(centre))
    covariance = np.zeros((6, 2, 2))  # at the per-channel centre: uncorrelated; moved to the common reference
    shift = t_ref - centre
    covariance[:, 0, 0] = 1.0 / sw + shift**2 / sxx
    covariance[:, 0, 1] = covariance[:, 1, 0] = shift / sxx
    covariance[:, 1, 1] = 1.0 / sxx
    return Line(t_ref, level + shift * rate, rate, covariance, chi2)


@dataclass(frozen=True)
class Judgement:
    """What :func:`judge` found: ``drift`` (True: re-acquire from ``line``), the continuity statistic ``nis``
    (χ², 6 channels), the ``step`` (6,) against the track's prediction, and ``reason`` (one line)."""

    drift: bool
    line: Line
    nis: float
    step: np.ndarray
    reason: str


def judge(time_s: Sequence[float], mean: np.ndarray, variance: np.ndarray, track_time_s: float,
          track_x: np.ndarray, track_P: np.ndarray, model_sigma: np.ndarray, gap_variance: np.ndarray,
          gate_chi2: float, max_rate: np.ndarray) -> Judgement:
    """Decide drift or step for refused windows (module docstring).

    Args:
        time_s, mean, variance: the refused windows' mid times (n,), means (n, 6) and noise variances (n, 6).
        track_time_s, track_x, track_P: the last accepted state: the level it predicts at the windows'
            orientation (offset plus the model error known there) and the rate (6, 2), their covariance (6, 2, 2),
            at ``track_time_s``.
        model_sigma: (6,) the model error's 1σ at the windows' orientation not in the track (0 at the same one).
        gap_variance: (6,) the base process noise's offset variance over the gap.
        gate_chi2: the continuity threshold (χ², 6 degrees of freedom). max_rate: (6,) the largest drift rate, /s.
    """
    line = fit_line(np.asarray(time_s, dtype=float), np.asarray(mean, dtype=float),
                    np.asarray(variance, dtype=float))
    gap = line.time_s - track_time_s
    b_a, r_a = track_x[:, 0], track_x[:, 1]
    change = line.level - b_a  # what the offset did over the gap; a drift's rate went from r_a to s on some path
    low, high = np.minimum(r_a, line.rate) * gap, np.maximum(r_a, line.rate) * gap
    continuity = change - np.clip(change, low, high)
    a_line = np.array([1.0, -0.5 * gap])
    a_track = np.array([1.0, 0.5 * gap])
    var = (np.einsum("i,cij,j->c", a_line, line.covariance, a_line)
           + np.einsum("i,cij,j->c", a_track, track_P, a_track) + model_sigma**2 + gap_variance)
    nis = float(np.sum(continuity**2 / np.maximum(var, 1e-300)))
    step = line.level - b_a - r_a * gap
    too_fast = np.abs(line.rate) > max_rate
    if too_fast.any():
        reason = "its rate is faster than any drift"
    elif line.chi2_per_dof > MAX_LINE_CHI2_PER_DOF:
        reason = f"not smooth (χ²/dof {line.chi2_per_dof:.1f} about a line)"
    elif nis > gate_chi2:
        reason = f"a jump against the track (continuity χ² {nis:.0f} > {gate_chi2:.1f})"
    else:
        reason = f"joins the track smoothly (continuity χ² {nis:.1f})"
        return Judgement(True, line, nis, step, reason)
    return Judgement(False, line, nis, step, reason)


__all__ = ["Line", "fit_line", "Judgement", "judge", "MAX_LINE_CHI2_PER_DOF"]
