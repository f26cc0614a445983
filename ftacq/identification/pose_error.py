"""Robot orientation error as a noise source (beyond the paper).

The pose record gives each flange orientation as the robot reports it. The real orientation differs by a small
rotation δ (kinematic error, compliance, encoder resolution): the measured gravity wrench then differs from the
model's by G_i δ, with (v_i = S R_i g the gravity force in the sensor frame, c the centre of mass)

    ∂F/∂δ = [v_i]× S,    ∂T/∂δ = [c]× [v_i]× S          (δ in the flange frame; eqs 10-11 differentiated)

For an isotropic δ with variance σ_θ² per axis the wrench error of pose i has covariance σ_θ² G_i G_iᵀ with
G_i = [[v_i]×; [c]×[v_i]×] (S drops out: S Sᵀ = I). It grows with the tool's weight and couples the force and
torque channels, so a heavy tool's record is dominated by it and a per-channel weight mis-weights it. The noise
of pose i is then

    C_i = diag(se_i² + ρ_i² τ²) + σ_θ² G_i G_iᵀ

with se the measured standard error (std/√count, or 0), ρ_i the relative noise of a pose when only counts or
std are known (else 1) and τ² (6,) the per-channel scatter (robust.py). τ² and σ_θ² are estimated by restricted
maximum likelihood on the residuals (:func:`estimate_noise`); the refinement then whitens every pose with C_i
(generalised least squares) and the pose statistic is rᵀ C⁻¹ r (χ²₆ for a clean pose). σ_θ² is kept only when
the likelihood ratio test rejects "no orientation error" at the 1 % level; otherwise the model is diagonal, as
before this module existed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftacq.identification.robust import pool_channels
from ftacq.identification.torque import skew

CHANNELS = 6
MAX_POSES_FOR_ESTIMATE = 4096
"""The variance components are estimated on at most this many (evenly spaced) poses."""
MAX_SCORING_STEPS = 50
SCORING_TOLERANCE = 1e-3
"""Fisher scoring stops when no variance component moves more than this fraction (well inside the noise) ..."""
LIKELIHOOD_TOLERANCE = 1e-3
"""... or −2 log-likelihood falls by less than this (statistically irrelevant: a 1σ change moves it by ~1)."""
ORIENTATION_LIKELIHOOD_RATIO = 5.41
"""−2 log Λ above which the orientation error is kept: the 1 % level of ½χ²₀ + ½χ²₁ (σ_θ² = 0 is on the boundary)."""
NEGLIGIBLE_ORIENTATION_SHARE = 1e-3
"""σ_θ² G Gᵀ below this fraction of the channel noise on every pose: treated as 0 (the diagonal, faster path)."""


def orientation_sensitivity(gravity_sensor: np.ndarray, center_of_mass: np.ndarray) -> np.ndarray:
    """Return G (N, 6, 3): the wrench change per rad of flange orientation error (isotropic, S factored out).

    ``gravity_sensor`` (N, 3) N is v_i = S R_i g; ``center_of_mass`` (3,) m.
    """
    v_cross = skew(np.asarray(gravity_sensor, dtype=float).reshape(-1, 3))
    out = np.empty((len(v_cross), 6, 3))
    out[:, :3] = v_cross
    out[:, 3:] = skew(np.asarray(center_of_mass, dtype=float)) @ v_cross
    return out


@dataclass(frozen=True)
class NoiseModel:
    """The noise of every pose: C_i = diag(se² + ρ² τ² (floored)) + σ_θ² G_i G_iᵀ (module docstring).

    Attributes:
        channel_variance: (N, 6) se² + ρ² τ², N², (N·m)²; floored so exact data stay finite.
        scatter: τ (6,), the per-channel scatter beyond the measured standard error (N, N·m; relative when ρ ≠ 1).
        orientation_variance_rad2: σ_θ², rad² per axis.
        sensitivity: G (N, 6, 3).
        likelihood_ratio: −2 log of the likelihood ratio of "no orientation error" against the fitted σ_θ²;
            σ_θ² is kept only when it exceeds ORIENTATION_LIKELIHOOD_RATIO (else 0).
        fitted_orientation_variance_rad2: the maximum-likelihood σ_θ² before that test (a warm start).
    """

    channel_variance: np.ndarray
    scatter: np.ndarray
    orientation_variance_rad2: float
    sensitivity: np.ndarray
    likelihood_ratio: float = 0.0
    fitted_orientation_variance_rad2: float = 0.0

    @property
    def orientation_error_deg(self) -> float:
        """σ_θ in degrees (1σ per axis)."""
        return float(np.degrees(np.sqrt(self.orientation_variance_rad2)))

    @property
    def channel_sigma(self) -> np.ndarray:
        """(N, 6) the sensor-side noise √(se² + ρ² τ²) per pose and channel."""
        return np.sqrt(self.channel_variance)

    @property
    def orientation_variance(self) -> np.ndarray:
        """(N, 6) the orientation error's share of diag C_i: σ_θ² Σ_b G_ab²."""
        return self.orientation_variance_rad2 * np.sum(self.sensitivity**2, axis=2)

    @property
    def total_variance(self) -> np.ndarray:
        """(N, 6) diag C_i: the full variance of every pose and channel."""
        return self.channel_variance + self.orientation_variance

    @property
    def full(self) -> bool:
        """Whether the orientation error matters (else the model is diagonal: per-channel weights suffice)."""
        if self.orientation_variance_rad2 <= 0.0:
            return False
        return bool(np.any(self.orientation_variance > NEGLIGIBLE_ORIENTATION_SHARE * self.channel_variance))

    def covariance(self) -> np.ndarray:
        """Return C (N, 6, 6)."""
        out = self.orientation_variance_rad2 * (self.sensitivity @ self.sensitivity.transpose(0, 2, 1))
        index = np.arange(CHANNELS)
        out[:, index, index] += self.channel_variance
        return out

    def weight(self, pose_weight: np.ndarray) -> np.ndarray:
        """Return the refinement's weight: w_i / diag C_i (N, 6) when the model is diagonal, else the whitening
        √w_i L_i⁻¹ (N, 6, 6) with L_i L_iᵀ = C_i (see refine.normal_equations)."""
        w = np.asarray(pose_weight, dtype=float)
        if not self.full:
            return w[:, None] / self.channel_variance
        inverse_cholesky = np.linalg.inv(np.linalg.cholesky(self.covariance()))
        return np.sqrt(w)[:, None, None] * inverse_cholesky

    def pose_statistic(self, residual: np.ndarray) -> np.ndarray:
        """Return d² (N,) = rᵀ C⁻¹ r, χ²₆ for a clean pose."""
        if not self.full:
            return np.sum(residual**2 / self.channel_variance, axis=1)
        solved = np.linalg.solve(self.covariance(), residual[:, :, None])[:, :, 0]
        return np.einsum("na,na->n", residual, solved)


def estimate_noise(
    residual: np.ndarray,
    sensitivity: np.ndarray,
    standard_error: np.ndarray | None,
    relative: np.ndarray,
    pose_weight: np.ndarray,
    dof_ratio: float,
    floor: np.ndarray,
    start_scatter2: np.ndarray,
    start_orientation_variance: float = 0.0,
    model_orientation: bool = True,
) -> NoiseModel:
    """Estimate τ² (6,) and σ_θ² from the residuals (N, 6) by restricted maximum likelihood; return the model.

    Minimises Σ_i w_i [log det C_i + r_iᵀ C_i⁻¹ r_i / ρ] over τ² ≥ 0, σ_θ² ≥ 0 (ρ = (6N − 15)/(6N) corrects for
    the 15 fitted parameters, as robust.channel_noise does) by projected Fisher scoring: the gradient

        ∂/∂τ_k² = Σ w ρ_k² (C⁻¹_kk − u_k² / ρ),   ∂/∂σ_θ² = Σ w (tr(Gᵀ C⁻¹ G) − ‖Gᵀ u‖² / ρ),   u = C⁻¹ r,

    and the expected Hessian Σ w tr(C⁻¹ D_j C⁻¹ D_k) with D = ∂C/∂(τ², σ_θ²), with step halving.

    ``standard_error`` (N, 6) or None (then se = 0), ``relative`` (N, 6) ρ_i (ones when se is known),
    ``pose_weight`` (N,) robust weights, ``floor`` (6,) the σ floor; ``start_*`` a warm start;
    ``model_orientation`` False: σ_θ² = 0 (per-channel noise only).
    """
    n = len(residual)
    se2_all = np.zeros((n, CHANNELS)) if standard_error is None else np.maximum(standard_error, floor) ** 2
    rel2_all = np.asarray(relative, dtype=float) ** 2
    floor2 = floor**2
    keep = np.flatnonzero(np.asarray(pose_weight) > 0)
    if keep.size > MAX_POSES_FOR_ESTIMATE:
        keep = keep[np.linspace(0, keep.size - 1, MAX_POSES_FOR_ESTIMATE).astype(int)]
    r, g, se2, rel2 = residual[keep], sensitivity[keep], se2_all[keep], rel2_all[keep]
    w = np.asarray(pose_weight, dtype=float)[keep]
    ggt = g @ g.transpose(0, 2, 1)
    index = np.arange(CHANNELS)

    # scales so that the optimiser's variables are O(1)
    scatter_scale = np.maximum(np.mean(r**2 / np.maximum(rel2, 1e-300), axis=0), floor2)
    g2 = g**2  # (n, 6, 3)
    orientation_scale = max(float(np.sum(r**2) / max(np.sum(g2), 1e-300)), 1e-30)
    scale = np.concatenate([scatter_scale, [orientation_scale]])

    def evaluate(x: np.ndarray, want_information: bool):
        """Return (objective, gradient, expected Hessian or None) at x = (τ² / scale, σ_θ² / scale)."""
        tau2, var = x[:CHANNELS] * scatter_scale, float(x[CHANNELS]) * orientation_scale
        if var == 0.0:
            return evaluate_diagonal(np.maximum(se2 + rel2 * tau2, floor2), want_information)
        cov = var * ggt
        cov[:, index, index] += np.maximum(se2 + rel2 * tau2, floor2)
        try:
            chol = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            return np.inf, None, None
        inverse = np.linalg.inv(cov)
        u = np.einsum("nab,nb->na", inverse, r)
        log_det = 2.0 * np.sum(np.log(np.diagonal(chol, axis1=1, axis2=2)), axis=1)
        value = float(w @ (log_det + np.einsum("na,na->n", r, u) / dof_ratio))
        if not want_information:
            return value, None, None
        inverse_diag = inverse[:, index, index]
        inverse_g = inverse @ g  # C⁻¹ G (n, 6, 3)
        gtu = np.einsum("nab,na->nb", g, u)
        gradient = np.empty(CHANNELS + 1)
        gradient[:CHANNELS] = w @ (rel2 * (inverse_diag - u**2 / dof_ratio))
        gradient[CHANNELS] = w @ (np.einsum("nab,nab->n", g, inverse_g) - np.sum(gtu**2, axis=1) / dof_ratio)
        # expected Hessian Σ w tr(C⁻¹ D_j C⁻¹ D_k), D = ∂C/∂(τ_j², σ_θ²)
        information = np.empty((CHANNELS + 1, CHANNELS + 1))
        information[:CHANNELS, :CHANNELS] = np.einsum("n,nj,nk,njk->jk", w, rel2, rel2, inverse**2)
        projected = inverse_g @ inverse_g.transpose(0, 2, 1)  # C⁻¹ G Gᵀ C⁻¹
        information[:CHANNELS, CHANNELS] = information[CHANNELS, :CHANNELS] = w @ (rel2 * projected[:, index, index])
        gtcg = g.transpose(0, 2, 1) @ inverse_g  # Gᵀ C⁻¹ G (n, 3, 3)
        information[CHANNELS, CHANNELS] = w @ np.einsum("nab,nab->n", gtcg, gtcg)
        return value, gradient * scale, information * np.outer(scale, scale)

    def evaluate_diagonal(variance: np.ndarray, want_information: bool):
        """:func:`evaluate` at σ_θ² = 0, where C is diagonal (``variance`` (n, 6))."""
        inverse = 1.0 / variance
        u = r * inverse
        value = float(w @ (np.sum(np.log(variance), axis=1) + np.sum(r * u, axis=1) / dof_ratio))
        if not want_information:
            return value, None, None
        gtu = np.einsum("nab,na->nb", g, u)
        g2_rows = np.sum(g2, axis=2)  # Σ_b G_ab² (n, 6)
        gradient = np.empty(CHANNELS + 1)
        gradient[:CHANNELS] = w @ (rel2 * (inverse - u**2 / dof_ratio))
        gradient[CHANNELS] = w @ (np.sum(g2_rows * inverse, axis=1) - np.sum(gtu**2, axis=1) / dof_ratio)
        information = np.zeros((CHANNELS + 1, CHANNELS + 1))
        information[index, index] = w @ (rel2 * inverse) ** 2
        information[:CHANNELS, CHANNELS] = information[CHANNELS, :CHANNELS] = w @ (rel2 * inverse**2 * g2_rows)
        gtcg = np.einsum("nab,na,nac->nbc", g, inverse, g)
        information[CHANNELS, CHANNELS] = w @ np.einsum("nab,nab->n", gtcg, gtcg)
        return value, gradient * scale, information * np.outer(scale, scale)

    def fisher_scoring(x: np.ndarray, with_orientation: bool) -> tuple[np.ndarray, float]:
        """Projected Fisher scoring with step halving on x ≥ 0 (σ_θ² held at its start unless
        ``with_orientation``); return (x, objective)."""
        x = np.maximum(x, 0.0)
        allowed = np.ones(CHANNELS + 1, dtype=bool)
        allowed[CHANNELS] = with_orientation
        value, gradient, information = evaluate(x, True)
        if gradient is None:
            return x, np.inf
        for _ in range(MAX_SCORING_STEPS):
            free = ((x > 0.0) | (gradient < 0.0)) & allowed
            if not np.any(free):
                break
            step = np.zeros_like(x)
            sub = information[np.ix_(free, free)]
            try:
                step[free] = -np.linalg.solve(sub + 1e-12 * np.trace(sub) * np.eye(int(free.sum())), gradient[free])
            except np.linalg.LinAlgError:
                break
            length = 1.0
            while length >= 1e-4:
                candidate = np.maximum(x + length * step, 0.0)
                trial, _, _ = evaluate(candidate, False)
                if trial <= value:
                    break
                length *= 0.5
            else:
                break
            moved = np.abs(candidate - x)
            previous_value = value
            x = candidate
            value, gradient, information = evaluate(x, True)
            if previous_value - value <= LIKELIHOOD_TOLERANCE or np.all(moved <= SCORING_TOLERANCE * np.maximum(x, 1e-6)):
                break
        return x, value

    start = np.concatenate([np.asarray(start_scatter2) / scatter_scale, [start_orientation_variance / orientation_scale]])
    without, value_without = fisher_scoring(np.concatenate([start[:CHANNELS], [0.0]]), with_orientation=False)
    best_x, best_value = without, value_without
    starts = [] if not model_orientation else [start] if start_orientation_variance > 0.0 else [
        np.concatenate([start[:CHANNELS], [0.1]]),
        np.concatenate([0.1 * start[:CHANNELS], [1.0]]),  # "all of it is orientation error": the other basin
    ]
    for x0 in starts:
        x, value = fisher_scoring(x0, with_orientation=True)
        if value < best_value:
            best_x, best_value = x, value
    likelihood_ratio = max(value_without - best_value, 0.0)
    fitted_variance = float(best_x[CHANNELS]) * orientation_scale
    if likelihood_ratio < ORIENTATION_LIKELIHOOD_RATIO:
        best_x = without
    tau2, var = best_x[:CHANNELS] * scatter_scale, float(best_x[CHANNELS]) * orientation_scale
    if standard_error is None:  # noise from the residuals alone: pooled, so that no channel collapses (robust.py)
        tau2 = pool_channels(tau2, dof_ratio * float(np.sum(np.asarray(pose_weight, dtype=float))))
    channel_variance = np.maximum(se2_all + rel2_all * tau2, floor2)
    return NoiseModel(channel_variance, np.sqrt(tau2), var, sensitivity, likelihood_ratio, fitted_variance)


def fixed_noise(
    sensitivity: np.ndarray,
    standard_error: np.ndarray | None,
    relative: np.ndarray,
    floor: np.ndarray,
    scatter2: np.ndarray,
    orientation_variance_rad2: float,
) -> NoiseModel:
    """Return the noise model with given variance components (τ² (6,), σ_θ²) for the poses of ``sensitivity``
    (N, 6, 3): the noise estimated on a subsample, applied to every pose (arguments as in :func:`estimate_noise`)."""
    n = len(sensitivity)
    se2 = np.zeros((n, CHANNELS)) if standard_error is None else np.maximum(standard_error, floor) ** 2
    scatter2 = np.asarray(scatter2, dtype=float)
    channel_variance = np.maximum(se2 + np.asarray(relative, dtype=float) ** 2 * scatter2, floor**2)
    return NoiseModel(channel_variance, np.sqrt(scatter2), float(orientation_variance_rad2), sensitivity,
                      fitted_orientation_variance_rad2=float(orientation_variance_rad2))
