"""The inertia's least squares with an honest 1σ: nuisance terms fitted beside it, rows weighted by their noise,
a block sandwich covariance, and the uncertainty of what is held fixed propagated.

Why the plain weighted normal equations (σ² (AᵀA)⁻¹, σ² from χ²/dof) understated the inertia's 1σ 3-6 times
(issue 37, docs/dynamics.md "The inertia's 1σ"):

- *Heteroscedastic noise.* A sensor on a moving arm is noisier the faster it moves (vibration; the simulated cell's
  ``motion_noise_gain``), and the fast rows are exactly those that carry the inertia (large ω², α). One scatter per
  channel makes them look as good as the rows at rest. Here each row and channel is weighted by a noise model
  fitted to the first pass's residuals (variance = a + b s + c s², s the joint speed norm).
- *Correlated residuals.* What the model leaves (a ring-down after each stop, a lag error, the sensor's filter) is
  correlated over tens of ms: the rows are not independent draws. The covariance is a sandwich over blocks of
  :data:`BLOCK_S` (Hansen's block / Newey-West idea: scores summed within a block, blocks taken independent).
- *Nuisances.* The biases at the time of the motion (drifted since the static poses: drift maps into the inertia
  through the ω² columns, whose mean is not zero) and a residual lag between the streams are fitted as extra
  columns (6 offsets, the time derivative of the predicted wrench), so their uncertainty enters the sandwich.
- *Fixed mass and centre of mass.* The inertia about the centre of mass is I_S − m (cᵀc 𝟙 − c cᵀ) with m, c from
  the static calibration: their 1σ is propagated through the fit and the parallel-axis term.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BLOCK_S = 0.25
"""Length of the sandwich covariance's blocks, s: longer than the residuals' correlation (a ring-down of τ ≤ 0.15 s,
the lag's), short enough for over a hundred blocks in a 40 s excitation."""
NOISE_FLOOR_FRACTION = 0.1
"""A row's modelled noise variance is at least this fraction of its channel's median (a fit gone low stays sane)."""


@dataclass(frozen=True)
class InertiaFit:
    """inertia_s (6,): I about the sensor origin (Pinocchio's vech order); covariance (6, 6) of it (sandwich);
    bias_offset (6,): the biases at the motion minus the static ones (N, N·m); lag_correction_s: the residual lag;
    row_weights (K, 6): 1 / modelled noise per row and channel."""

    inertia_s: np.ndarray
    covariance: np.ndarray
    bias_offset: np.ndarray
    lag_correction_s: float
    row_weights: np.ndarray
    design: np.ndarray
    target: np.ndarray


def noise_weights(residual: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """Return 1 / σ (K, 6) per row and channel: the squared residuals (K, 6) regressed on [1, s, s²] (s (K,) the
    joint speed norm, rad/s), floored at :data:`NOISE_FLOOR_FRACTION` of the channel's median."""
    s = np.asarray(speed, dtype=float).reshape(-1)
    basis = np.column_stack([np.ones_like(s), s, s * s])
    squared = np.asarray(residual, dtype=float) ** 2
    coefficients, *_ = np.linalg.lstsq(basis, squared, rcond=None)
    variance = basis @ coefficients
    floor = NOISE_FLOOR_FRACTION * np.maximum(np.median(squared, axis=0), 1e-30)
    return 1.0 / np.sqrt(np.maximum(variance, np.maximum(floor, 1e-30)))


def block_sandwich(design: np.ndarray, residual: np.ndarray, time_s: np.ndarray, block_s: float = BLOCK_S
                   ) -> np.ndarray:
    """Covariance (p, p) of a least-squares solution of ``design`` (K, 6, p) ≈ target, weighted already, from its
    ``residual`` (K, 6): (AᵀA)⁻¹ (Σ_blocks g_b g_bᵀ) (AᵀA)⁻¹ · B / (B − p), g_b = Σ_{rows in b} A_kᵀ e_k, blocks of
    ``block_s`` of ``time_s`` (K,)."""
    k, _, p = design.shape
    scores = np.einsum("kcp,kc->kp", design, residual)
    t = np.asarray(time_s, dtype=float)
    block = np.floor((t - t[0]) / block_s).astype(int)
    _, index = np.unique(block, return_inverse=True)
    sums = np.zeros((int(index.max()) + 1, p))
    np.add.at(sums, index, scores)
    blocks = sums.shape[0]
    bread = np.linalg.pinv(np.einsum("kcp,kcq->pq", design, design))
    meat = sums.T @ sums * (blocks / max(blocks - p, 1))
    return bread @ meat @ bread


def fit_inertia(regressor: np.ndarray, target: np.ndarray, fixed: np.ndarray, weights: np.ndarray,
                lag_column: np.ndarray, time_s: np.ndarray) -> InertiaFit:
    """Fit the six inertia parameters about the sensor origin with m, m c = ``fixed`` (4,), beside 6 bias offsets
    and a residual lag.

    Args: regressor (K, 6, 10) and target (K, 6) = wrench − static biases; weights (K, 6) (1/σ); lag_column (K, 6):
    d(predicted wrench)/d(lag) (N/s, N·m/s); time_s (K,) of the rows (for the blocks).
    """
    k = regressor.shape[0]
    columns = np.concatenate([regressor[:, :, 4:], np.broadcast_to(np.eye(6), (k, 6, 6)), lag_column[:, :, None]],
                             axis=2)
    design = columns * weights[:, :, None]
    b = (target - regressor[:, :, :4] @ fixed) * weights
    x, *_ = np.linalg.lstsq(design.reshape(-1, 13), b.reshape(-1), rcond=None)
    residual = b - design @ x
    covariance = block_sandwich(design, residual, time_s)
    return InertiaFit(x[:6], covariance[:6, :6], x[6:12], float(x[12]), weights, design, b)


def fixed_sensitivity(fit: InertiaFit, regressor: np.ndarray) -> np.ndarray:
    """d(inertia_s) / d(m, m c) (6, 4): how the fitted I_S moves with the fixed mass and first moment."""
    design = fit.design.reshape(-1, fit.design.shape[2])
    fixed_design = (regressor[:, :, :4] * fit.row_weights[:, :, None]).reshape(-1, 4)
    return -(np.linalg.pinv(design) @ fixed_design)[:6]
