"""Noise scales and robust pose weights (beyond the paper: a contact or motion during sampling must not
spoil the calibration, and the report must name the disturbed pose).

Noise model per pose i and channel ch:  σ_i,ch² = se_i,ch² + τ_ch², where se = std/√count is the measured
standard error of the mean (0 when the file has no std/count columns) and τ_ch the extra scatter the
model does not explain (robot kinematic error, drift, …), estimated from the residuals by solving

    Σ_i w_i r_i,ch² / (se_i,ch² + τ_ch²) = ρ Σ_i w_i         (ρ = (6N − 15)/(6N), the model's dof)

(or its median version at the start, when an outlier may still be in the residuals).
The pose statistic d_i² = Σ_ch r_i,ch² / σ_i,ch² is χ²₆ for a clean pose. Weights: 1 up to the 99 %
quantile k² of χ²₆, then k²/d_i² (a redescending Huber-type weight: the influence of a pose falls as
1/d_i). A pose is named an outlier when d_i² exceeds the χ²₆ quantile at family-wise level 1 %.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

CHANNELS = 6
WEIGHT_QUANTILE = 0.99
"""χ²₆ quantile below which a pose keeps full weight."""
OUTLIER_FAMILY_ALPHA = 0.01
"""Probability that a clean record of N poses has any pose named an outlier (Bonferroni over N)."""
CHI2_1_MEDIAN = float(chi2.ppf(0.5, 1))
"""Median of χ²₁ (≈ 0.4549): the median of r²/σ² for Gaussian residuals."""
NOISE_FLOOR_RELATIVE = 1e-13
"""σ never goes below this fraction of a channel's signal range (+ an absolute 1e-15): exact data stay finite."""
BISECTION_STEPS = 80


def weight_threshold() -> float:
    """Return k² = χ²₆ quantile below which a pose has full weight."""
    return float(chi2.ppf(WEIGHT_QUANTILE, CHANNELS))


def outlier_threshold(n_poses: int) -> float:
    """Return the d² above which a pose is named an outlier (χ²₆ at level OUTLIER_FAMILY_ALPHA / N)."""
    return float(chi2.isf(OUTLIER_FAMILY_ALPHA / max(n_poses, 1), CHANNELS))


def noise_floor(wrench: np.ndarray) -> np.ndarray:
    """Return the per-channel σ floor (6,) for a record's wrenches (N, 6)."""
    span = np.ptp(wrench, axis=0) + np.abs(wrench).max(axis=0)
    return NOISE_FLOOR_RELATIVE * span + 1e-15


def channel_noise(
    residual: np.ndarray,
    standard_error: np.ndarray | None,
    pose_weight: np.ndarray,
    dof_ratio: float,
    floor: np.ndarray,
    statistic: str = "mean",
) -> tuple[np.ndarray, np.ndarray]:
    """Return (σ (N, 6), τ (6,)): the per-pose, per-channel noise used to weight the fit.

    ``statistic`` "median" (robust, for the first pass) or "mean" (efficient, with robust weights).
    """
    r2 = residual**2
    n = len(residual)
    se2 = np.zeros_like(r2) if standard_error is None else np.maximum(standard_error, floor) ** 2
    w = np.asarray(pose_weight, dtype=float)
    if statistic == "median":
        keep = w > 0
        target = CHI2_1_MEDIAN * dof_ratio

        def excess(tau2: np.ndarray) -> np.ndarray:
            return np.median(r2[keep] / (se2[keep] + tau2), axis=0) - target

        upper = np.median(r2[keep], axis=0) / target
    else:
        total = max(w.sum(), 1e-300)

        def excess(tau2: np.ndarray) -> np.ndarray:
            return (w @ (r2 / (se2 + tau2))) / total - dof_ratio

        upper = (w @ r2) / (total * dof_ratio)
    tau2 = np.zeros(CHANNELS)
    lower = np.zeros(CHANNELS)
    upper = np.maximum(upper, floor**2)
    if standard_error is None:
        tau2 = upper  # closed form: σ² = weighted mean (or median-based) r² / dof
    else:
        need = excess(np.full(CHANNELS, 1e-300)) > 0  # residuals larger than the measured noise explains
        lo, hi = lower.copy(), upper.copy()
        for _ in range(BISECTION_STEPS):
            mid = 0.5 * (lo + hi)
            positive = excess(mid) > 0
            lo = np.where(positive, mid, lo)
            hi = np.where(positive, hi, mid)
        tau2 = np.where(need, hi, 0.0)
    sigma = np.sqrt(np.maximum(se2 + tau2, floor**2))
    if n == 0:
        sigma = np.zeros((0, CHANNELS))
    return sigma, np.sqrt(tau2)


def pose_statistic(residual: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Return d² (N,) = Σ_ch (r / σ)², χ²₆ for a clean pose."""
    return np.sum((residual / sigma) ** 2, axis=1)


def robust_weights(d2: np.ndarray) -> np.ndarray:
    """Return pose weights (N,): 1 while d² ≤ k², else k²/d² (redescending Huber-type)."""
    k2 = weight_threshold()
    return np.where(d2 <= k2, 1.0, k2 / np.maximum(d2, 1e-300))
