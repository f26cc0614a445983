"""Drift inside a recording: each pose's time, and a test of the residuals for a trend against it (beyond the paper).

A sensor that is not warmed up drifts while the poses are recorded. The model (eqs 10-11) has constant biases, so
a fit without a drift term bends the tool's weight, the sensor rotation and the centre of mass to absorb what it
can of the drift and leaves the rest as residuals that trend with time. :func:`residual_trend` fits, per channel,
a straight line through the residuals against the pose's time (weighted by each pose's noise and robust weight),

    r_i,ch = a_ch + b_ch s_i + noise,    z_ch = b_ch / σ(b_ch),    Σ_ch z_ch² ~ χ²₆ without a trend,

and reports the implied drift per hour (per row when the record has no time) and over the whole recording. The
identification models a linear bias drift (refine.py, ``bias_rate``) when asked (``drift="linear"``) or, with
``drift="auto"``, when this test finds a trend that is both significant (p < :data:`TREND_P`) and large (its change
over the recording above the drift warning thresholds of CELL.toml, the verdict's WARN level).

Time of a pose (:func:`pose_times`): the middle of its averaging window (``t_start_s``/``t_end_s`` columns), else
``t_end_s``; a record without times uses its row order (``row_index`` column when a caller kept the rows of a
split record, else 0, 1, 2, …). The drift time s_i is the time relative to the last pose (≤ 0) in hours, or in
rows: the biases the model identifies are those at the end of the recording.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc  # χ² tails: scipy.stats's own functions, without its 1 s import

from ftacq.posefile import PoseRecord

TREND_P = 1e-3
"""A residual trend is significant when its χ²₆ p-value is below this."""
SECONDS_PER_HOUR = 3600.0
ROW_INDEX_COLUMN = "row_index"
"""Extra column a caller adds (``PoseRecord.extra``) to keep the row order of a record it splits."""


@dataclass(frozen=True)
class PoseTimes:
    """Each pose's drift time s_i (N,) ≤ 0 relative to ``reference`` and what it is measured in.

    Attributes:
        drift_time: (N,) s_i in ``unit`` ("h" or "row"), 0 at the last pose of the whole record.
        source: the column it came from ("t_start_s/t_end_s", "t_end_s", "row_index" or "row order").
        unit: "h" when the record has times, else "row".
        reference: the time (s) or row index of s = 0.
    """

    drift_time: np.ndarray
    source: str
    unit: str
    reference: float

    def to_dict(self) -> dict:
        return {"source": self.source, "unit": self.unit, "reference": float(self.reference)}


def pose_times(record: PoseRecord, reference: dict | None = None) -> PoseTimes:
    """Return the drift time of every pose of ``record`` (module docstring); ``reference`` (a
    :meth:`PoseTimes.to_dict` of the fitted record) places held-out poses on the fit's time axis."""
    start, end = record.extra.get("t_start_s"), record.extra.get("t_end_s")
    n = len(record)
    if end is not None and np.all(np.isfinite(end)):
        if start is not None and np.all(np.isfinite(start)):
            seconds, source = 0.5 * (np.asarray(start) + np.asarray(end)), "t_start_s/t_end_s"
        else:
            seconds, source = np.asarray(end, dtype=float), "t_end_s"
        ref = float(reference["reference"]) if reference else float(np.max(seconds)) if n else 0.0
        return PoseTimes((seconds - ref) / SECONDS_PER_HOUR, source, "h", ref)
    rows = record.extra.get(ROW_INDEX_COLUMN)
    if rows is not None and np.all(np.isfinite(rows)):
        rows, source = np.asarray(rows, dtype=float), ROW_INDEX_COLUMN
    else:
        rows, source = np.arange(n, dtype=float), "row order"
    ref = float(reference["reference"]) if reference else float(np.max(rows)) if n else 0.0
    return PoseTimes(rows - ref, source, "row", ref)


@dataclass(frozen=True)
class ResidualTrend:
    """The straight-line trend of the residuals against time (module docstring).

    Attributes:
        rate: (6,) slope per ``unit`` [N, N·m per h or per row].
        rate_sigma: (6,) its 1σ.
        chi2, p_value: Σ z² over the six channels and its χ²₆ upper-tail probability.
        span: the recording's duration in ``unit`` (last − first pose).
        unit: "h" or "row".
    """

    rate: np.ndarray
    rate_sigma: np.ndarray
    chi2: float
    p_value: float
    span: float
    unit: str

    @property
    def change(self) -> np.ndarray:
        """(6,) the drift over the whole recording implied by the slope [N, N·m]."""
        return self.rate * self.span

    @property
    def significant(self) -> bool:
        return bool(self.p_value < TREND_P)

    def large(self, warn_force_n: float, warn_torque_nm: float) -> bool:
        """Whether the change over the recording exceeds the drift warning thresholds."""
        change = self.change
        return bool(np.linalg.norm(change[:3]) > warn_force_n or np.linalg.norm(change[3:]) > warn_torque_nm)

    @staticmethod
    def from_dict(values: dict) -> "ResidualTrend":
        """The inverse of :meth:`to_dict`."""
        return ResidualTrend(np.asarray(values["rate"], dtype=float), np.asarray(values["rate_sigma"], dtype=float),
                             float(values["chi2"]), float(values["p_value"]), float(values["span"]),
                             str(values["unit"]))

    def to_dict(self) -> dict:
        return {"rate": self.rate.tolist(), "rate_sigma": self.rate_sigma.tolist(), "chi2": self.chi2,
                "p_value": self.p_value, "span": self.span, "unit": self.unit, "change": self.change.tolist()}


def residual_trend(residual: np.ndarray, variance: np.ndarray, pose_weight: np.ndarray,
                   drift_time: np.ndarray, unit: str) -> ResidualTrend:
    """Fit a line per channel through ``residual`` (N, 6) against ``drift_time`` (N,), weighted by
    ``pose_weight`` (N,) / ``variance`` (N, 6); return the slopes, their 1σ and the χ²₆ test of "no trend"."""
    residual = np.asarray(residual, dtype=float).reshape(-1, 6)
    t = np.asarray(drift_time, dtype=float).reshape(-1)
    w = np.asarray(pose_weight, dtype=float).reshape(-1, 1) / np.maximum(np.asarray(variance, dtype=float), 1e-300)
    span = float(np.ptp(t)) if t.size else 0.0
    total = w.sum(axis=0)
    if t.size < 3 or span <= 0.0 or np.any(total <= 0.0):
        zeros = np.zeros(6)
        return ResidualTrend(zeros, np.full(6, np.inf), 0.0, 1.0, span, unit)
    mean_t = (w * t[:, None]).sum(axis=0) / total
    centred = t[:, None] - mean_t
    sxx = np.sum(w * centred**2, axis=0)
    rate = np.sum(w * centred * residual, axis=0) / sxx
    rate_sigma = 1.0 / np.sqrt(sxx)
    chi2 = float(np.sum((rate / rate_sigma) ** 2))
    return ResidualTrend(rate, rate_sigma, chi2, float(chdtrc(6, chi2)), span, unit)


def bias_drift_at(calibration, record: PoseRecord) -> np.ndarray:
    """Return (M, 6) the modelled bias at each pose of ``record`` minus the calibration's (end-of-recording) bias:
    zeros unless the calibration's ``drift_model`` is linear. Subtract it from the compensated wrench of a pose
    measured during the recording (held-out poses) to judge it with the bias of its own time."""
    model = dict(calibration.metadata.get("drift_model", {}) or {})
    if model.get("model") != "linear":
        return np.zeros((len(record), 6))
    return pose_times(record, model).drift_time[:, None] * np.asarray(model["bias_rate"], dtype=float)


__all__ = ["bias_drift_at", "PoseTimes", "ResidualTrend", "pose_times", "residual_trend", "TREND_P", "ROW_INDEX_COLUMN"]
