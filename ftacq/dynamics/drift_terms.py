"""A linear bias drift inside one recorded motion (``calibrate --quick``, docs/quick.md), as the full run's ``--drift
auto`` models it over its poses (:mod:`ftacq.identification.trend`).

The joint fit (:mod:`ftacq.dynamics.joint`) takes six more linear columns: the bias of each channel moves by
rate × s, s the row's time in hours relative to the reference (the end of the recording, so the fitted biases are
those at its end and compensation uses them, as the full run's are at its last pose):

    wrench_S = … + bias + rate · s,    s = (t − t_end) / 3600 s            (equation (1) of joint.py, extended)

When (``drift="auto"``): the fit with the drift is tried first; the drift is kept when its rates differ from zero
by the full run's significance (Σ_ch (rate/σ)² against χ²₆, p < :data:`ftacq.identification.trend.TREND_P`), the σ
those of the fit's own covariance (its block sandwich takes the rows' correlations in); otherwise the motion is
fitted again without it. The full run also asks the trend to be large (beyond the drift warning thresholds): the
quick run does not, because its validation resolves far less than those thresholds, so an unmodelled drift the
data can see would fail a correct calibration.

The result's covariance then has 27 columns (θ 5, x 16, the rates 6); the rates (per hour) and their 1σ go into the
calibration's ``metadata["drift_model"]`` with the full run's keys.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import chdtrc  # χ² tail: scipy.stats's own function, without its 1 s import

from ftacq.fit_options import DRIFT_MODELS

SECONDS_PER_HOUR = 3600.0
DRIFT_COLUMNS = 6
"""One rate per channel (Fx, Fy, Fz, Tx, Ty, Tz), per hour."""


def drift_columns(drift_time_h: np.ndarray | None, rows: np.ndarray | slice, count: int) -> np.ndarray:
    """(N, 6, 6) the drift's columns of the regressor at ``rows`` (I₆ · s per row); (N, 6, 0) without a drift."""
    if drift_time_h is None:
        return np.zeros((count, 6, 0))
    s = np.asarray(drift_time_h, dtype=float)[rows]
    return s[:, None, None] * np.eye(6)[None]


def drift_time_h(robot_time_s: np.ndarray, reference_s: float) -> np.ndarray:
    """Each robot sample's drift time s (M,) in hours relative to ``reference_s`` (≤ 0 before it)."""
    return (np.asarray(robot_time_s, dtype=float) - float(reference_s)) / SECONDS_PER_HOUR


@dataclass(frozen=True)
class DriftFit:
    """The drift's rates (6,) [N/h, N·m/h], their 1σ and covariance (6, 6), the significance test (χ² on 6 degrees
    of freedom, its p-value), whether the model was kept, why, and the reference time (s, robot clock)."""

    rate: np.ndarray
    rate_sigma: np.ndarray
    rate_covariance: np.ndarray
    chi2: float
    p_value: float
    modelled: bool
    chosen: str
    reference_s: float
    span_h: float

    def to_metadata(self, warn: tuple[float, float], clock_offset_s: float = 0.0) -> dict[str, Any]:
        """The calibration's ``drift_model`` (the full run's keys; the rates only when modelled); its ``reference``
        the end of the recording + ``clock_offset_s`` (UNIX time − the recording's host monotonic clock, so a pose
        record's UNIX times are placed on the same axis, :func:`ftacq.identification.trend.bias_drift_at`)."""
        out: dict[str, Any] = {"model": "linear" if self.modelled else "none", "chosen": self.chosen,
                               "source": "robot time of the motion", "unit": "h",
                               "reference": self.reference_s + clock_offset_s,
                               "span": self.span_h, "warn_force_n": float(warn[0]), "warn_torque_nm": float(warn[1]),
                               "test": {"chi2": self.chi2, "p_value": self.p_value,
                                        "rate": self.rate.tolist(), "rate_sigma": self.rate_sigma.tolist()}}
        if self.modelled:
            out.update({"bias_rate": self.rate.tolist(), "bias_rate_sigma": self.rate_sigma.tolist(),
                        "bias_at": "end of the recording: force_bias and torque_bias are the biases at its end; "
                                   "compensation uses them"})
        return out


def drift_test(optimum: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(rate (6,), its covariance (6, 6), χ², p) of a fit with the drift's columns last in (θ, x)."""
    rate = np.asarray(optimum, dtype=float)[-DRIFT_COLUMNS:]
    cov = np.asarray(covariance, dtype=float)[-DRIFT_COLUMNS:, -DRIFT_COLUMNS:]
    sigma = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    chi2 = float(np.sum((rate / sigma) ** 2))
    return rate, cov, chi2, float(chdtrc(DRIFT_COLUMNS, chi2))


def identify_with_drift(record, robot, sensor_offset_m: np.ndarray, nominal_down: np.ndarray, *,
                        rows: np.ndarray | None = None, drift: str = "auto", reference_s: float | None = None,
                        metadata: dict | None = None):
    """:func:`ftacq.dynamics.joint.identify_joint` with a linear bias drift (module docstring). Returns
    (JointResult, DriftFit). ``reference_s``: the drift's zero (default the last robot sample's time)."""
    from ftacq.dynamics.joint import RobotPart, identify_joint
    from ftacq.identification.trend import TREND_P

    if drift not in DRIFT_MODELS:
        raise ValueError(f"unknown drift model {drift!r}; choose one of {', '.join(DRIFT_MODELS)}")
    times = np.asarray(record.robot_time_s, dtype=float)
    reference = float(times[-1]) if reference_s is None else float(reference_s)
    s = drift_time_h(times, reference)
    fitted = np.ones(len(times), dtype=bool) if rows is None else np.asarray(rows, dtype=bool)
    span = float(np.ptp(s[fitted])) if fitted.any() else 0.0
    none = np.zeros(DRIFT_COLUMNS)
    if drift == "none":
        result = identify_joint(record, robot, sensor_offset_m, nominal_down, rows=rows, metadata=metadata)
        return result, DriftFit(none, np.full(6, np.inf), np.zeros((6, 6)), 0.0, 1.0, False,
                                "asked for (none)", reference, span)
    part = RobotPart.of(robot, sensor_offset_m, record.q, record.qd, record.qdd)  # both fits' robot part
    result = identify_joint(record, robot, sensor_offset_m, nominal_down, rows=rows, metadata=metadata,
                            drift_time_h=s, robot_part=part)
    rate, cov, chi2, p = drift_test(result.optimum, result.covariance)
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    if drift == "linear":
        return result, DriftFit(rate, sigma, cov, chi2, p, True, "asked for (linear)", reference, span)
    if p < TREND_P:
        chosen = (f"chosen automatically: the rates differ from zero, χ² = {chi2:.1f} on 6 degrees of freedom, "
                  f"p = {p:.2g} < {TREND_P:g}")
        return result, DriftFit(rate, sigma, cov, chi2, p, True, chosen, reference, span)
    plain = identify_joint(record, robot, sensor_offset_m, nominal_down, rows=rows, metadata=metadata,
                           rotation_start=result.calibration.sensor_rotation, robot_part=part)
    chosen = f"not needed: the rates are not significant (χ² = {chi2:.1f}, p = {p:.2g} ≥ {TREND_P:g})"
    return plain, DriftFit(rate, sigma, cov, chi2, p, False, chosen, reference, span)


__all__ = ["DriftFit", "drift_columns", "drift_time_h", "drift_test", "identify_with_drift", "DRIFT_COLUMNS"]
