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

import functools

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
BISECTION_STEPS = 24
"""Bisection steps of the median-based τ² (relative precision 6e-8 of its bracket: a robust start only)."""
NEWTON_STEPS = 30
MEDIAN_SUBSAMPLE = 4096
"""The median-based scale uses at most this many (evenly spaced) poses."""


_WEIGHT_THRESHOLD = float(chi2.ppf(WEIGHT_QUANTILE, CHANNELS))


def weight_threshold() -> float:
    """Return k² = χ²₆ quantile below which a pose has full weight."""
    return _WEIGHT_THRESHOLD


@functools.lru_cache(maxsize=256)
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
    if n == 0:
        return np.zeros((0, CHANNELS)), np.zeros(CHANNELS)
    if statistic == "median":
        keep = np.flatnonzero(w > 0)
        if keep.size > MEDIAN_SUBSAMPLE:  # the median of a large even subsample is as good and far cheaper
            keep = keep[np.linspace(0, keep.size - 1, MEDIAN_SUBSAMPLE).astype(int)]
        r2_keep, se2_keep = r2[keep], se2[keep]
        target = CHI2_1_MEDIAN * dof_ratio
        upper = np.maximum(np.median(r2_keep, axis=0) / target, floor**2)
        if standard_error is None:
            tau2 = upper  # σ² = median(r²) / (median of χ²₁ · dof ratio)
        else:
            need = np.median(r2_keep / np.maximum(se2_keep, 1e-300), axis=0) > target
            lo, hi = np.zeros(CHANNELS), upper.copy()
            for _ in range(BISECTION_STEPS):
                mid = 0.5 * (lo + hi)
                positive = np.median(r2_keep / (se2_keep + mid), axis=0) > target
                lo = np.where(positive, mid, lo)
                hi = np.where(positive, hi, mid)
            tau2 = np.where(need, hi, 0.0)
    else:
        total = max(w.sum(), 1e-300)
        if standard_error is None:
            tau2 = np.maximum((w @ r2) / (total * dof_ratio), floor**2)
        else:
            # Newton on the convex, decreasing f(τ²) = Σ w r²/(se² + τ²)/Σ w − ρ from τ² = 0 (stays left of the root)
            tau2 = np.zeros(CHANNELS)
            for _ in range(NEWTON_STEPS):
                inverse = 1.0 / (se2 + tau2)
                value = (w @ (r2 * inverse)) / total - dof_ratio
                slope = -(w @ (r2 * inverse**2)) / total
                active = value > 1e-12 * dof_ratio
                if not np.any(active):
                    break
                tau2 = np.where(active, tau2 - value / np.minimum(slope, -1e-300), tau2)
    sigma = np.sqrt(np.maximum(se2 + tau2, floor**2))
    return sigma, np.sqrt(tau2)


def pose_statistic(residual: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Return d² (N,) = Σ_ch (r / σ)², χ²₆ for a clean pose."""
    return np.sum((residual / sigma) ** 2, axis=1)


def robust_weights(d2: np.ndarray) -> np.ndarray:
    """Return pose weights (N,): 1 while d² ≤ k², else k²/d² (redescending Huber-type)."""
    k2 = weight_threshold()
    return np.where(d2 <= k2, 1.0, k2 / np.maximum(d2, 1e-300))
