"""Noise scales and robust pose weights (beyond the paper: a contact or motion during sampling must not
spoil the calibration, and the report must name the disturbed pose).

Noise model per pose i and channel ch:  σ_i,ch² = se_i,ch² + τ_ch², where se = std/√count is the measured
standard error of the mean (0 when the file has no std/count columns) and τ_ch the extra scatter the
model does not explain (robot kinematic error, drift, …), estimated from the residuals by solving

    Σ_i w_i r_i,ch² / (se_i,ch² + τ_ch²) = ρ Σ_i w_i         (ρ = (6N − 15)/(6N), the model's dof)

(or its median version at the start, when an outlier may still be in the residuals).
A noise model that cannot collapse (issue: a 6-pose record without std/count columns was refused as degenerate
with a scaled condition number of 1e300, because one channel's τ fell to zero, its weight to infinity, and the
fit then bent to zero that channel's residuals further). Two guards, both in this module:

- **Pooling across channels** (when the noise comes from the residuals alone, no measured std/count): each
  channel's τ² is shrunk towards the mean τ² of its group (the three forces, the three torques) as with a
  scaled-inverse-χ² prior worth :data:`POOLING_PRIOR_DOF` residual degrees of freedom,

      τ_ch² ← (ν_ch τ_ch² + ν₀ τ̄_group²) / (ν_ch + ν₀),   ν_ch = ρ Σ_i w_i.

  Chosen over a fixed prior because nothing in a pose file says which sensor measured it, and over a plain floor
  because it is scale-free: the three force channels of one transducer share its gauges and electronics and have
  the same noise within a small factor, so borrowing strength between them costs nothing on large sets (ν_ch
  ≫ ν₀: the per-channel estimate wins) and keeps a 6-pose set (ν_ch ≈ 3.5) from trusting one channel without
  bound. A channel can only reach zero when its whole group does (exact data).
- **A floor from the data's resolution** (:func:`resolution_floor`): a file whose values are all multiples of a
  step q (printed to 3 decimals, or raw counts) cannot know a channel better than the rounding error q/√12.

The pose statistic d_i² = Σ_ch r_i,ch² / σ_i,ch² is χ²₆ for a clean pose. Weights: 1 up to the 99 %
quantile k² of χ²₆, then k²/d_i² (a redescending Huber-type weight: the influence of a pose falls as
1/d_i). A pose is named an outlier when d_i² exceeds the χ²₆ quantile at family-wise level 1 %.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.special import chdtri, gammaincinv  # χ² tails: scipy.stats's own functions, without its 1 s import

CHANNELS = 6
WEIGHT_QUANTILE = 0.99
"""χ²₆ quantile below which a pose keeps full weight."""
OUTLIER_FAMILY_ALPHA = 0.01
"""Probability that a clean record of N poses has any pose named an outlier (Bonferroni over N)."""
CHI2_1_MEDIAN = float(2.0 * gammaincinv(0.5, 0.5))  # χ²₁ ppf
"""Median of χ²₁ (≈ 0.4549): the median of r²/σ² for Gaussian residuals."""
NOISE_FLOOR_RELATIVE = 1e-13
"""σ never goes below this fraction of a channel's signal range (+ an absolute 1e-15): exact data stay finite."""
BISECTION_STEPS = 24
"""Bisection steps of the median-based τ² (relative precision 6e-8 of its bracket: a robust start only)."""
NEWTON_STEPS = 30
MEDIAN_SUBSAMPLE = 4096
"""The median-based scale uses at most this many (evenly spaced) poses."""
POOLING_PRIOR_DOF = 10.0
"""Weight ν₀ (in residual degrees of freedom) of the group's mean τ² in each channel's τ² (module docstring):
about 3 poses' worth against 6 poses (ν ≈ 3.5 per channel) it dominates; against 100 poses it moves τ² < 2 %."""
FORCE_CHANNELS, TORQUE_CHANNELS = slice(0, 3), slice(3, 6)
RESOLUTION_TOLERANCE = 0.02
"""A value lies on the lattice of step q when it is within this fraction of q of a multiple of q (float32 files)."""
RESOLUTION_MIN_VALUES = 6
"""Fewer distinct values than this in a channel say nothing about its resolution."""


_WEIGHT_THRESHOLD = float(2.0 * gammaincinv(CHANNELS / 2, WEIGHT_QUANTILE))  # χ²₆ ppf


def weight_threshold() -> float:
    """Return k² = χ²₆ quantile below which a pose has full weight."""
    return _WEIGHT_THRESHOLD


@functools.lru_cache(maxsize=256)
def outlier_threshold(n_poses: int) -> float:
    """Return the d² above which a pose is named an outlier (χ²₆ at level OUTLIER_FAMILY_ALPHA / N)."""
    return float(chdtri(CHANNELS, OUTLIER_FAMILY_ALPHA / max(n_poses, 1)))


def resolution_step(values: np.ndarray) -> float:
    """Return the step q of the lattice every value of one channel lies on (0 when none is found).

    Candidates: the smallest difference between distinct values divided by 1 … 16 (raw counts, of which a short
    record may skip a few), and the decades 10⁻⁹ … 1 (a file printed to a fixed number of decimals); the largest
    candidate every value lies on (within :data:`RESOLUTION_TOLERANCE`
    of a multiple) is the step. Continuous data (means of many samples, float output) have none.
    """
    distinct = np.unique(np.asarray(values, dtype=float))
    if distinct.size < RESOLUTION_MIN_VALUES:
        return 0.0
    gaps = np.diff(distinct)
    candidates = sorted({*(float(gaps.min()) / k for k in range(1, 17)), *(10.0**-k for k in range(10))},
                        reverse=True)
    origin = distinct[0]
    for step in candidates:
        if step <= 0.0 or step > 0.1 * np.ptp(distinct):
            continue
        offset = (distinct - origin) / step
        if np.all(np.abs(offset - np.round(offset)) <= RESOLUTION_TOLERANCE):
            return float(step)
    return 0.0


def resolution_floor(wrench: np.ndarray) -> np.ndarray:
    """Return (6,) the rounding error q/√12 of each channel of a record's wrenches (N, 6) (0 when unquantised)."""
    wrench = np.asarray(wrench, dtype=float).reshape(-1, CHANNELS)
    return np.array([resolution_step(wrench[:, k]) for k in range(CHANNELS)]) / np.sqrt(12.0)


def noise_floor(wrench: np.ndarray) -> np.ndarray:
    """Return the per-channel σ floor (6,) for a record's wrenches (N, 6): the data's resolution (q/√12), and at
    least a tiny fraction of the signal so that exact synthetic data stay finite."""
    span = np.ptp(wrench, axis=0) + np.abs(wrench).max(axis=0)
    return np.maximum(NOISE_FLOOR_RELATIVE * span + 1e-15, resolution_floor(wrench))


def pool_channels(tau2: np.ndarray, dof: float) -> np.ndarray:
    """Return τ² (6,) shrunk towards the mean of its group (forces, torques) with prior weight
    :data:`POOLING_PRIOR_DOF` against ``dof`` residual degrees of freedom per channel (module docstring)."""
    tau2 = np.asarray(tau2, dtype=float)
    out = np.empty_like(tau2)
    dof = max(float(dof), 0.0)
    for group in (FORCE_CHANNELS, TORQUE_CHANNELS):
        out[group] = (dof * tau2[group] + POOLING_PRIOR_DOF * np.mean(tau2[group])) / (dof + POOLING_PRIOR_DOF)
    return out


def channel_noise(
    residual: np.ndarray,
    standard_error: np.ndarray | None,
    pose_weight: np.ndarray,
    dof_ratio: float,
    floor: np.ndarray,
    statistic: str = "mean",
) -> tuple[np.ndarray, np.ndarray]:
    """Return (σ (N, 6), τ (6,)): the per-pose, per-channel noise used to weight the fit.

    ``statistic`` "median" (robust, for the first pass) or "mean" (efficient, with robust weights). Without a
    measured standard error the channels are pooled (:func:`pool_channels`).
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
    if standard_error is None:
        tau2 = np.maximum(pool_channels(tau2, dof_ratio * float(w.sum())), floor**2)
    sigma = np.sqrt(np.maximum(se2 + tau2, floor**2))
    return sigma, np.sqrt(tau2)


def pose_statistic(residual: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Return d² (N,) = Σ_ch (r / σ)², χ²₆ for a clean pose."""
    return np.sum((residual / sigma) ** 2, axis=1)


def robust_weights(d2: np.ndarray) -> np.ndarray:
    """Return pose weights (N,): 1 while d² ≤ k², else k²/d² (redescending Huber-type)."""
    k2 = weight_threshold()
    return np.where(d2 <= k2, 1.0, k2 / np.maximum(d2, 1e-300))
