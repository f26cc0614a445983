"""Re-estimating a calibration's biases with the tool on (tare), and the 1σ of a compensated wrench at rest.

A tare keeps the sensor rotation, the tool's weight and centre of mass (all of the model but the biases) and
re-estimates the force and torque biases from one or more still, contact-free poses i (model of
:mod:`ftacq.calibration`, paper eqs 10-13):

    y_i = wrench_i − [g_s,i ; c × g_s,i]          (the bias seen at pose i; g_s,i = S R_i g)
    b̂   = (Σ W_i)⁻¹ Σ W_i y_i,   W_i = C_i⁻¹      (generalised least squares over the poses)

Noise of a pose (6×6): C_i = diag(std_i² / count_i + τ²) + σ_θ² G_i G_iᵀ, with the sensor's scatter over the
averaging window (std/√count: samples taken as independent), the calibration's extra per-pose scatter τ and the
robot's orientation error σ_θ with its sensitivity G_i (both from the identification, ``metadata["noise"]``;
:mod:`ftacq.identification.pose_error`). The kept parameters θ (rotation, gravity_base, centre of mass) carry
their own error δθ, common to every pose; it enters the estimate as −A δθ with A = (Σ W_i)⁻¹ Σ W_i J_i
(J_i = ∂prediction/∂θ at pose i), so

    cov(b̂) = (Σ W_i)⁻¹ + A Σ_θ Aᵀ

with Σ_θ = D R D, D = diag(1σ) of the calibration file and R its ``model_correlation`` (the identification's
correlations between the kept parameters' errors; a file without it, or the biases, count as uncorrelated).
With two or more poses, χ²/dof of the poses' scatter about b̂ (model error included) is reported, and the
covariance is scaled by it when it exceeds 1 (the data say the noise is larger than the model assumed).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ftacq.calfile import MODEL_CORRELATION_KEY, MODEL_CORRELATION_PARAMETERS
from ftacq.calibration import Calibration
from ftacq.identification.pose_error import orientation_sensitivity
from ftacq.identification.refine import PARAMETER_SLICES, ModelParameters, jacobian
from ftacq.provenance import bias_entry, bias_history, with_bias_entry

MODEL_PARAMETERS = MODEL_CORRELATION_PARAMETERS
"""The parameters a tare keeps (their 1σ propagate into the new biases)."""
VARIANCE_FLOOR = 1e-18
"""Added to each channel's variance so exact (noise-free) data stay finite, N² and (N·m)²."""


@dataclass(frozen=True)
class BiasEstimate:
    """Re-estimated biases (sensor frame) with their covariance.

    Attributes:
        force_bias: (3,) N. torque_bias: (3,) N·m.
        covariance: (6, 6) [N², N²·m, (N·m)²]: noise part plus the kept parameters' error.
        previous: (6,) the calibration's biases before the tare, N and N·m.
        poses: number of poses used. residuals: (poses, 6) y_i − b̂ (N, N·m).
        chi2_per_dof: scatter of the poses about b̂ against their noise model (NaN with one pose).
        method: "tare, 1 pose" or "tare, N poses".
    """

    force_bias: np.ndarray
    torque_bias: np.ndarray
    covariance: np.ndarray
    previous: np.ndarray
    poses: int
    residuals: np.ndarray
    chi2_per_dof: float
    method: str

    @property
    def bias(self) -> np.ndarray:
        """(6,) [Fx, Fy, Fz, Tx, Ty, Tz] biases, N and N·m."""
        return np.concatenate([self.force_bias, self.torque_bias])

    @property
    def sigma(self) -> np.ndarray:
        """(6,) 1σ of the biases, N and N·m."""
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))

    @property
    def change(self) -> np.ndarray:
        """(6,) new minus previous biases, N and N·m."""
        return self.bias - self.previous


def _parameter_covariance(calibration: Calibration, names: tuple[str, ...]) -> np.ndarray:
    """Return the covariance of the named parameters' errors: their 1σ (zeros where the calibration gives none)
    with the file's ``model_correlation`` between the parameters it covers (module docstring), else uncorrelated."""
    sigma = []
    for name in names:
        value = calibration.uncertainty.get(name)
        array = np.zeros(3) if value is None else np.asarray(value, dtype=float).reshape(3)
        sigma.append(np.where(np.isfinite(array), array, 0.0))
    sd = np.concatenate(sigma)
    correlation = np.eye(len(sd))
    entry = calibration.metadata.get(MODEL_CORRELATION_KEY)
    if entry is not None:
        stored = np.asarray(entry["matrix"], dtype=float)
        index = {name: 3 * k for k, name in enumerate(MODEL_CORRELATION_PARAMETERS)}
        rows = np.array([index[name] + i if name in index else -1 for name in names for i in range(3)])
        covered = np.flatnonzero(rows >= 0)
        correlation[np.ix_(covered, covered)] = stored[np.ix_(rows[covered], rows[covered])]
    return correlation * np.outer(sd, sd)


def _columns(names: tuple[str, ...]) -> np.ndarray:
    return np.concatenate([np.arange(PARAMETER_SLICES[n].start, PARAMETER_SLICES[n].stop) for n in names])


def pose_noise_covariance(calibration: Calibration, flange_R_base: np.ndarray,
                          channel_variance: np.ndarray) -> np.ndarray:
    """Return C_i (N, 6, 6): ``channel_variance`` (N, 6) + τ² on the diagonal, plus σ_θ² G_i G_iᵀ (module docstring)."""
    rotations = np.asarray(flange_R_base, dtype=float).reshape(-1, 3, 3)
    noise = dict(calibration.metadata.get("noise") or {})
    tau = np.asarray(noise.get("extra_scatter") or np.zeros(6), dtype=float).reshape(6)
    variance = np.asarray(channel_variance, dtype=float).reshape(-1, 6) + tau**2 + VARIANCE_FLOOR
    covariance = np.zeros((len(rotations), 6, 6))
    covariance[:, np.arange(6), np.arange(6)] = variance
    sigma_theta_rad = np.radians(float(noise.get("orientation_error_deg") or 0.0))
    if sigma_theta_rad > 0.0:
        g = orientation_sensitivity(calibration.gravity_in_sensor(rotations), calibration.center_of_mass)
        covariance += sigma_theta_rad**2 * g @ g.transpose(0, 2, 1)
    return covariance


def model_jacobian(calibration: Calibration, flange_R_base: np.ndarray,
                   names: tuple[str, ...] = MODEL_PARAMETERS) -> np.ndarray:
    """Return ∂(predicted wrench)/∂θ (N, 6, 3·len(names)) for the named parameters (refine's parameterisation)."""
    rotations = np.asarray(flange_R_base, dtype=float).reshape(-1, 3, 3)
    return jacobian(ModelParameters.from_calibration(calibration), rotations)[:, :, _columns(names)]


def compensation_sigma(calibration: Calibration, flange_R_base: np.ndarray, include_biases: bool = True) -> np.ndarray:
    """Return the 1σ (6,) [N, N·m] of the compensated wrench at rest at one orientation that the calibration's
    own uncertainty predicts: every parameter's 1σ (the biases' only if ``include_biases``) through the model,
    plus τ and σ_θ.

    The parameters' errors are correlated as the file's ``model_correlation`` says (uncorrelated without it,
    which overstates the error where the identification's correlations cancel).
    """
    parameters, per_pose = compensation_variance_parts(calibration, flange_R_base, include_biases)
    return np.sqrt(parameters + per_pose)


def compensation_variance_parts(calibration: Calibration, flange_R_base: np.ndarray,
                                include_biases: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Return the two parts of :func:`compensation_sigma`'s variance (6,) each [N², (N·m)²]: the parameters'
    (one set of errors for every orientation) and the per-pose part (τ and σ_θ, drawn afresh at each pose)."""
    rotations = np.asarray(flange_R_base, dtype=float).reshape(-1, 3, 3)[:1]
    names = MODEL_PARAMETERS + (("force_bias", "torque_bias") if include_biases else ())
    j = model_jacobian(calibration, rotations, names)[0]
    parameters = np.diag(j @ _parameter_covariance(calibration, names) @ j.T)
    per_pose = np.diag(pose_noise_covariance(calibration, rotations, np.zeros((1, 6)))[0])
    return np.maximum(parameters, 0.0), np.maximum(per_pose, 0.0)


def estimate_biases(calibration: Calibration, flange_R_base: np.ndarray, wrench: np.ndarray,
                    std: np.ndarray | None = None, count: np.ndarray | None = None,
                    sensor_noise: np.ndarray | None = None) -> BiasEstimate:
    """Re-estimate the biases from still, contact-free poses, keeping every other parameter (module docstring).

    Args:
        calibration: the calibration whose rotation, weight and centre of mass are kept.
        flange_R_base: (N, 3, 3) or (3, 3) orientation of each pose.
        wrench: (N, 6) or (6,) mean wrench of each pose, N and N·m, sensor frame.
        std: (N, 6) sample standard deviation over each pose's averaging window (None: ``sensor_noise``).
        count: (N,) samples averaged per pose (None: 1).
        sensor_noise: (6,) per-sample 1σ used when ``std`` is None (None: zero, i.e. exact data).
    """
    rotations = np.asarray(flange_R_base, dtype=float).reshape(-1, 3, 3)
    y = np.asarray(wrench, dtype=float).reshape(-1, 6)
    n = len(y)
    if n == 0 or len(rotations) != n:
        raise ValueError(f"estimate_biases: {len(rotations)} orientations for {n} wrenches")
    previous = np.concatenate([calibration.force_bias, calibration.torque_bias])
    seen = y - (calibration.predict(rotations) - previous)
    counts = np.ones(n) if count is None else np.maximum(np.asarray(count, dtype=float).reshape(n), 1.0)
    if std is not None:
        per_sample = np.asarray(std, dtype=float).reshape(n, 6)
    elif sensor_noise is not None:
        per_sample = np.broadcast_to(np.asarray(sensor_noise, dtype=float).reshape(6), (n, 6))
    else:
        per_sample = np.zeros((n, 6))
    covariance_i = pose_noise_covariance(calibration, rotations, per_sample**2 / counts[:, None])
    weight_i = np.linalg.inv(covariance_i)
    information = weight_i.sum(axis=0)
    noise_covariance = np.linalg.inv(information)
    bias = noise_covariance @ np.einsum("nij,nj->i", weight_i, seen)
    j = model_jacobian(calibration, rotations)
    parameter_covariance = _parameter_covariance(calibration, MODEL_PARAMETERS)
    sensitivity = noise_covariance @ np.einsum("nij,njk->ik", weight_i, j)
    covariance = noise_covariance + sensitivity @ parameter_covariance @ sensitivity.T
    residuals = seen - bias
    chi2_per_dof = float("nan")
    if n >= 2:
        total_i = covariance_i + j @ parameter_covariance @ j.transpose(0, 2, 1)
        chi2 = float(np.einsum("ni,nij,nj->", residuals, np.linalg.inv(total_i), residuals))
        chi2_per_dof = chi2 / (6.0 * (n - 1))
        covariance = covariance * max(1.0, chi2_per_dof)
    return BiasEstimate(force_bias=bias[:3], torque_bias=bias[3:], covariance=covariance, previous=previous,
                        poses=n, residuals=residuals, chi2_per_dof=chi2_per_dof,
                        method=f"tare, {n} pose{'s' if n != 1 else ''}")


def with_biases(calibration: Calibration, force_bias: np.ndarray, torque_bias: np.ndarray,
                force_sigma: np.ndarray | None, torque_sigma: np.ndarray | None, method: str,
                time: str | None = None, **history_extra: Any) -> Calibration:
    """Return the calibration with new biases (and their 1σ), the change recorded in ``bias_history``."""
    uncertainty = dict(calibration.uncertainty)
    if force_sigma is not None and torque_sigma is not None:
        uncertainty["force_bias"] = [float(v) for v in force_sigma]
        uncertainty["torque_bias"] = [float(v) for v in torque_sigma]
    metadata = dict(calibration.metadata)
    entry = bias_entry(method, force_bias, torque_bias, force_sigma, torque_sigma, time=time, **history_extra)
    metadata["bias_history"] = with_bias_entry(bias_history(calibration), entry)
    return replace(calibration, force_bias=np.asarray(force_bias, dtype=float),
                   torque_bias=np.asarray(torque_bias, dtype=float), uncertainty=uncertainty, metadata=metadata)


def apply_estimate(calibration: Calibration, estimate: BiasEstimate, time: str | None = None,
                   **history_extra: Any) -> Calibration:
    """Return the calibration with the estimate's biases and 1σ, the tare recorded in ``bias_history`` (with
    ``history_extra``, e.g. ``sensor``: the serial number of the sensor it was tared on)."""
    sigma = estimate.sigma
    extra: dict[str, Any] = {"poses": estimate.poses, **history_extra}
    if np.isfinite(estimate.chi2_per_dof):
        extra["chi2_per_dof"] = estimate.chi2_per_dof
    return with_biases(calibration, estimate.force_bias, estimate.torque_bias, sigma[:3], sigma[3:],
                       estimate.method, time=time, **extra)


def format_bias_change(change) -> str:
    """The biases' change (6,) (N, N·m) in one line: ``F [+0.0123, …] N, T [+0.00045, …] N·m``."""
    return ("F [" + ", ".join(f"{v:+.4f}" for v in change[:3]) + "] N, T ["
            + ", ".join(f"{v:+.5f}" for v in change[3:]) + "] N·m")


__all__ = ["format_bias_change", "BiasEstimate", "estimate_biases", "apply_estimate", "with_biases", "compensation_sigma",
           "compensation_variance_parts",
           "pose_noise_covariance", "model_jacobian"]
