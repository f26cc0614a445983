"""The sensor check: the force channels' gain/cross-talk matrix, and what gravity shows of the torque channels'.

The paper's model (eqs 10-11) trusts the sensor's own calibration matrix. Here the force channels read

    F_i = C v_i + F0,    v_i = S R_i g    (S = sensor_R_flange, R_i = flange_R_base_i, g = gravity_base)
    T_i = (c × v_i) + B v_i + T0

with C the force gain/cross-talk matrix (I for a perfect sensor) and B a symmetric 3×3 (m) that collects what the
torque channels add: a torque gain matrix D and a force→torque cross-talk K read D (c × v) + K v, whose
antisymmetric part is indistinguishable from the centre of mass c.

What gravity alone identifies (docs/method-notes.md "The sensor check"). The data fix the 6×3 map v ↦ (F, T) up
to the scale that trades with the tool's weight (M = C S: C/λ, λ g fit alike). Polar decomposition M = P U (P
symmetric positive definite, U a rotation): only P is seen, the rotation part of C is the mounting rotation S by
definition. So from the force channels the symmetric C is identified up to its scale (5 numbers: the three gains'
ratios and the three symmetric cross-talks); a reference weight (a known mass) fixes the scale (6). From the
torque channels: the symmetric part B of D[c]× + K (6 numbers; a uniform torque gain trades with |c|); for a
diagonal D, B[0,1] = (d_y − d_x) c_z / 2, B[0,2] = (d_x − d_z) c_y / 2, B[1,2] = (d_z − d_y) c_x / 2: the torque
gains' differences, each as well as the centre of mass's lever arm across the pair allows.

The fit runs beside the identification (it does not change the calibration): from the identified parameters and
C = I, B = 0, Gauss-Newton on the same poses with the identification's noise model and robust weights (each pose
whitened with its 6×6 noise covariance, pose_error.py), the rotation on SO(3), 1σ from (JᵀWJ)⁻¹ scaled by the
reduced χ² when that exceeds 1. Without a reference C is normalised to trace 3 (mean gain 1): the gains are then
relative to their mean. With a reference weight the constraint ‖g‖ = m_ref g0 enters as one more observation
with σ² = σ_m² g0² + (REFERENCE_GRAVITY_RELATIVE_SIGMA m_ref g0)² (the weight uses standard gravity).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.special import chdtrc  # χ² tails: scipy.stats's own functions, without its 1 s import

from ftacq import STANDARD_GRAVITY_M_S2
from ftacq.channels import TORQUE_AXES
from ftacq.identification.pose_error import orientation_sensitivity
from ftacq.identification.torque import skew
from ftacq.so3 import rotation_from_rotvec

if TYPE_CHECKING:
    from ftacq.identification.trend import ResidualTrend

SYMMETRIC_ENTRIES = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
"""The six independent entries of a symmetric 3×3, in the order of every 6-vector here."""
REFERENCE_GRAVITY_RELATIVE_SIGMA = 1.5e-3
"""1σ of local gravity against standard gravity (9.80665 m/s²): it lies within ±0.27 % of it anywhere on the ground
(equator to poles, sea level to 3 000 m); a uniform spread over that range has this σ. A reference weight's
absolute scale is known no better unless SIGMA says otherwise."""
NOISE_ROUNDS = 2
"""Times the noise model is estimated again from the check's residuals (the second changes C's 1σ by < 1 %)."""
MAX_ITERATIONS = 30
STEP_TOLERANCE_SIGMAS = 1e-4
SIGNIFICANCE_P = 1e-3
"""C ≠ I (and B ≠ 0) is significant when the χ² test of "a perfect sensor" has p below this."""

# the 15 (21 with drift) calibration parameters, then C's, then B's
_CAL = 15


def _symmetric(entries: np.ndarray) -> np.ndarray:
    """Return the symmetric 3×3 of a 6-vector in :data:`SYMMETRIC_ENTRIES` order."""
    out = np.zeros((3, 3))
    for value, (j, k) in zip(entries, SYMMETRIC_ENTRIES):
        out[j, k] = out[k, j] = value
    return out


_ENTRY_BASIS = np.array([_symmetric(np.eye(6)[k]) for k in range(6)])  # (6, 3, 3)
_TRACE_FREE = np.array([[1 / np.sqrt(2), 1 / np.sqrt(6), 0, 0, 0], [-1 / np.sqrt(2), 1 / np.sqrt(6), 0, 0, 0],
                        [0, -2 / np.sqrt(6), 0, 0, 0], [0, 0, 1, 0, 0], [0, 0, 0, 1, 0], [0, 0, 0, 0, 1]])
"""(6, 5): the entries of a trace-free symmetric matrix from 5 free parameters (orthonormal columns)."""


@dataclass(frozen=True)
class ReferenceWeight:
    """A known tool mass (kg) and its 1σ (kg): fixes C's scale."""

    mass_kg: float
    sigma_kg: float = 0.0

    def weight_sigma_n(self) -> float:
        """1σ of the reference weight m g0 in N (the mass's σ and local gravity's, REFERENCE_GRAVITY_RELATIVE_SIGMA)."""
        return float(np.hypot(self.sigma_kg, REFERENCE_GRAVITY_RELATIVE_SIGMA * self.mass_kg) * STANDARD_GRAVITY_M_S2)


@dataclass(frozen=True)
class SensorGainFit:
    """The sensor check's result (module docstring). Matrices in the sensor frame.

    Attributes:
        force_gain: C (3, 3), symmetric; trace 3 without a reference (gains relative to their mean).
        force_gain_covariance: (6, 6) covariance of C's entries (:data:`SYMMETRIC_ENTRIES` order).
        torque_lever: B (3, 3) symmetric, m. torque_lever_covariance: (6, 6).
        reference: the reference weight used, or None.
        chi2, dof, p_value: the test of C = I (trace-free part without a reference) and B = 0.
        mass_kg, mass_sigma_kg: the tool's mass of this fit (with C's scale: mean gain 1 without a reference).
        center_of_mass: (3,) m of this fit. residual: (N, 6) measured − predicted. reduced_chi2: of the fit.
        converged: whether Gauss-Newton settled. parameter_covariance: (P, P) of all parameters.
        gravity_sensor: (N, 3) v_i of this fit. noise: the noise model the check's weights came from.
        drift_rate: (6,) the linear bias drift fitted beside (zeros when none was), per unit of drift time.
    """

    force_gain: np.ndarray
    force_gain_covariance: np.ndarray
    torque_lever: np.ndarray
    torque_lever_covariance: np.ndarray
    reference: ReferenceWeight | None
    chi2: float
    dof: int
    p_value: float
    mass_kg: float
    mass_sigma_kg: float
    center_of_mass: np.ndarray
    residual: np.ndarray
    reduced_chi2: float
    converged: bool
    parameter_covariance: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 0)))
    gravity_sensor: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 3)))
    drift_rate: np.ndarray = field(default_factory=lambda: np.zeros(6))
    noise: dict = field(default_factory=dict)

    @property
    def significant(self) -> bool:
        """Whether the data show the sensor is not perfect (p < :data:`SIGNIFICANCE_P`)."""
        return bool(self.p_value < SIGNIFICANCE_P)

    def force_gain_sigma(self) -> np.ndarray:
        """(3, 3) 1σ of C's entries."""
        return _symmetric(np.sqrt(np.maximum(np.diag(self.force_gain_covariance), 0.0)))

    def torque_gain_differences(self) -> list[dict]:
        """The torque gains' differences d_j − d_k that B shows (module docstring), with 1σ, for each pair:
        ``{"axes": ("Tx", "Ty"), "value", "sigma", "lever_m"}`` (value = d_k − d_j for the pair (j, k))."""
        out = []
        sigma = np.sqrt(np.maximum(np.diag(self.torque_lever_covariance), 0.0))
        for index, (j, k), lever_axis, sign in ((3, (0, 1), 2, 1.0), (4, (0, 2), 1, -1.0), (5, (1, 2), 0, 1.0)):
            lever = float(self.center_of_mass[lever_axis])
            if abs(lever) < 1e-9:
                continue
            value = sign * 2.0 * self.torque_lever[j, k] / lever
            out.append({"axes": (TORQUE_AXES[j], TORQUE_AXES[k]), "value": float(value),
                        "sigma": float(2.0 * sigma[index] / abs(lever)), "lever_m": lever})
        return out

    def to_dict(self) -> dict:
        """The ``sensor_check`` entry of the calibration's metadata (ftacq.sensor_check judges it)."""
        return {
            "force_gain": self.force_gain.tolist(), "force_gain_sigma": self.force_gain_sigma().tolist(),
            "force_gain_covariance": self.force_gain_covariance.tolist(),
            "torque_lever_m": self.torque_lever.tolist(),
            "torque_lever_sigma_m": _symmetric(np.sqrt(np.maximum(np.diag(self.torque_lever_covariance), 0.0))).tolist(),
            "torque_gain_differences": [{**d, "axes": list(d["axes"])} for d in self.torque_gain_differences()],
            "scale": "absolute (reference weight)" if self.reference else "relative: mean force gain 1 (no reference)",
            "reference_mass_kg": None if self.reference is None else self.reference.mass_kg,
            "reference_sigma_kg": None if self.reference is None else self.reference.sigma_kg,
            "chi2": self.chi2, "dof": self.dof, "p_value": self.p_value, "significant": self.significant,
            "mass_kg": self.mass_kg, "mass_sigma_kg": self.mass_sigma_kg,
            "center_of_mass_m": self.center_of_mass.tolist(), "reduced_chi2": self.reduced_chi2,
            "converged": self.converged, **self.noise,
        }


def whitening(noise_sigma: np.ndarray, orientation_error_rad: float, gravity_sensor: np.ndarray,
              center_of_mass: np.ndarray, pose_weight: np.ndarray) -> np.ndarray:
    """Return (N, 6, 6) √w_i L_i⁻¹ with L_i L_iᵀ = diag(σ_i²) + σ_θ² G_i G_iᵀ (the identification's noise model)."""
    n = len(noise_sigma)
    covariance = np.zeros((n, 6, 6))
    index = np.arange(6)
    covariance[:, index, index] = np.asarray(noise_sigma, dtype=float) ** 2
    if orientation_error_rad > 0.0:
        g = orientation_sensitivity(gravity_sensor, center_of_mass)
        covariance += orientation_error_rad**2 * (g @ g.transpose(0, 2, 1))
    inverse = np.linalg.inv(np.linalg.cholesky(covariance))
    return np.sqrt(np.maximum(np.asarray(pose_weight, dtype=float), 0.0))[:, None, None] * inverse


def _model(state: dict, rotations: np.ndarray, drift_time: np.ndarray | None) -> tuple[np.ndarray, np.ndarray,
                                                                                          np.ndarray]:
    """Return (predicted wrench (N, 6), M_i = S R_i (N, 3, 3), v_i (N, 3))."""
    m = np.einsum("ab,nbc->nac", state["S"], rotations)
    v = m @ state["g"]
    c_matrix = np.eye(3) + _symmetric(state["eC"])
    torque_matrix = skew(state["c"]) + _symmetric(state["eB"])
    out = np.empty((len(v), 6))
    out[:, :3] = v @ c_matrix.T + state["F0"]
    out[:, 3:] = v @ torque_matrix.T + state["T0"]
    if state.get("rate") is not None and drift_time is not None:
        out += drift_time[:, None] * state["rate"]
    return out, m, v


def _jacobian(state: dict, m: np.ndarray, v: np.ndarray, drift_time: np.ndarray | None, c_basis: np.ndarray
              ) -> np.ndarray:
    """Return (N, 6, P) ∂(predicted)/∂θ; θ = (δ, g, F0, c, T0, [Ḟ0, Ṫ0], C's free parameters, B's 6 entries)."""
    n = len(v)
    drift = state.get("rate") is not None
    k_c = c_basis.shape[1]
    p = _CAL + (6 if drift else 0) + k_c + 6
    jac = np.zeros((n, 6, p))
    c_matrix = np.eye(3) + _symmetric(state["eC"])
    torque_matrix = skew(state["c"]) + _symmetric(state["eB"])
    v_cross = skew(v)  # (N, 3, 3)
    jac[:, :3, 0:3] = -c_matrix @ v_cross
    jac[:, 3:, 0:3] = -torque_matrix @ v_cross
    jac[:, :3, 3:6] = c_matrix @ m
    jac[:, 3:, 3:6] = torque_matrix @ m
    jac[:, 0:3, 6:9] = np.eye(3)
    jac[:, 3:, 9:12] = -v_cross
    jac[:, 3:6, 12:15] = np.eye(3)
    col = _CAL
    if drift:
        t = np.zeros(n) if drift_time is None else drift_time
        for k in range(6):
            jac[:, k, col + k] = t
        col += 6
    entry_effect = np.einsum("kab,nb->nak", _ENTRY_BASIS, v)  # (N, 3, 6): ∂(E v)/∂(entry k)
    jac[:, :3, col:col + k_c] = entry_effect @ c_basis
    jac[:, 3:, col + k_c:col + k_c + 6] = entry_effect
    return jac


def fit_sensor_gain(rotations: np.ndarray, wrench: np.ndarray, start: dict, whiten: np.ndarray,
                    drift_time: np.ndarray | None = None, reference: ReferenceWeight | None = None) -> SensorGainFit:
    """Fit C and B beside the calibration's parameters (module docstring).

    ``rotations`` (N, 3, 3) flange_R_base; ``wrench`` (N, 6); ``start``: the identified parameters
    (``S`` (3, 3), ``g``, ``F0``, ``c``, ``T0`` (3,), and ``rate`` (6,) or None for a linear bias drift over
    ``drift_time`` (N,)); ``whiten`` (N, 6, 6) as :func:`whitening`; ``reference``: a known tool mass.
    """
    rotations = np.asarray(rotations, dtype=float)
    wrench = np.asarray(wrench, dtype=float)
    c_basis = np.eye(6) if reference is not None else _TRACE_FREE
    k_c = c_basis.shape[1]
    state: dict[str, Any] = {"S": np.array(start["S"], dtype=float), "g": np.array(start["g"], dtype=float),
             "F0": np.array(start["F0"], dtype=float), "c": np.array(start["c"], dtype=float),
             "T0": np.array(start["T0"], dtype=float), "eC": np.zeros(6), "eB": np.zeros(6),
             "rate": None if start.get("rate") is None else np.array(start["rate"], dtype=float)}
    drift = state["rate"] is not None
    drift_time = None if drift_time is None else np.asarray(drift_time, dtype=float).reshape(-1)

    def normal(state: dict) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        predicted, m, v = _model(state, rotations, drift_time)
        residual = wrench - predicted
        jac = _jacobian(state, m, v, drift_time, c_basis)
        white_jac = (whiten @ jac).reshape(-1, jac.shape[2])
        white_r = (whiten @ residual[:, :, None]).reshape(-1)
        # einsum, not a BLAS product: a few µs of work that a multi-threaded BLAS turns into 0.2 s on a busy machine
        information = np.einsum("np,nq->pq", white_jac, white_jac)
        gradient, cost = np.einsum("np,n->p", white_jac, white_r), float(white_r @ white_r)
        if reference is not None:
            sigma = max(reference.weight_sigma_n(), 1e-9 * reference.mass_kg)
            norm = float(np.linalg.norm(state["g"]))
            row = np.zeros(jac.shape[2])
            row[3:6] = state["g"] / norm / sigma
            r_ref = (reference.mass_kg * STANDARD_GRAVITY_M_S2 - norm) / sigma
            information += np.outer(row, row)
            gradient += row * r_ref
            cost += r_ref**2
        return information, gradient, cost, residual

    def moved(state: dict, step: np.ndarray) -> dict:
        col = _CAL + (6 if drift else 0)
        new = dict(state)
        new["S"] = rotation_from_rotvec(step[0:3]) @ state["S"]
        u, _, vt = np.linalg.svd(new["S"])
        new["S"] = u @ vt
        new["g"], new["F0"] = state["g"] + step[3:6], state["F0"] + step[6:9]
        new["c"], new["T0"] = state["c"] + step[9:12], state["T0"] + step[12:15]
        if drift:
            new["rate"] = state["rate"] + step[_CAL:_CAL + 6]
        new["eC"] = state["eC"] + c_basis @ step[col:col + k_c]
        new["eB"] = state["eB"] + step[col + k_c:col + k_c + 6]
        return new

    information, gradient, cost, residual = normal(state)
    converged = False
    for _ in range(MAX_ITERATIONS):
        scale = np.sqrt(np.maximum(np.diag(information), 1e-300))
        step = np.linalg.lstsq(information / np.outer(scale, scale), gradient / scale, rcond=1e-12)[0] / scale
        factor, accepted = 1.0, False
        while factor > 1e-4:
            candidate = moved(state, factor * step)
            trial = normal(candidate)
            if trial[2] <= cost * (1.0 + 1e-12):
                accepted = True
                break
            factor *= 0.5
        if not accepted:
            converged = True
            break
        state, (information, gradient, cost, residual) = candidate, trial
        covariance = np.linalg.pinv(information)
        if np.all(np.abs(factor * step) <= STEP_TOLERANCE_SIGMAS * np.sqrt(np.maximum(np.diag(covariance), 1e-300))):
            converged = True
            break
    covariance = np.linalg.pinv(information)
    n_parameters = information.shape[0] - (1 if reference is None else 0)  # the trace constraint holds one back
    dof = max(int(np.count_nonzero(np.any(whiten != 0.0, axis=(1, 2)))) * 6 - n_parameters, 1)
    reduced = cost / dof
    covariance = covariance * max(reduced, 1.0)
    col = _CAL + (6 if drift else 0)
    block = covariance[col:col + k_c, col:col + k_c]
    c_covariance = c_basis @ block @ c_basis.T
    b_block = covariance[col + k_c:col + k_c + 6, col + k_c:col + k_c + 6]
    # the test of a perfect sensor: C's free parameters and B's entries jointly zero
    free = np.concatenate([np.linalg.lstsq(c_basis, state["eC"], rcond=None)[0], state["eB"]])
    joint = np.zeros((k_c + 6, k_c + 6))
    joint[:k_c, :k_c], joint[k_c:, k_c:] = block, b_block
    joint[:k_c, k_c:] = covariance[col:col + k_c, col + k_c:col + k_c + 6]
    joint[k_c:, :k_c] = joint[:k_c, k_c:].T
    chi2 = float(free @ np.linalg.pinv(joint) @ free)
    g_cov = covariance[3:6, 3:6]
    g = state["g"]
    gradient_mass = g / max(np.linalg.norm(g), 1e-300) / STANDARD_GRAVITY_M_S2
    return SensorGainFit(
        force_gain=np.eye(3) + _symmetric(state["eC"]), force_gain_covariance=c_covariance,
        torque_lever=_symmetric(state["eB"]), torque_lever_covariance=b_block, reference=reference,
        chi2=chi2, dof=k_c + 6, p_value=float(chdtrc(k_c + 6, chi2)),
        mass_kg=float(np.linalg.norm(g) / STANDARD_GRAVITY_M_S2),
        mass_sigma_kg=float(np.sqrt(max(gradient_mass @ g_cov @ gradient_mass, 0.0))),
        center_of_mass=np.array(state["c"]), residual=residual, reduced_chi2=float(reduced), converged=converged,
        parameter_covariance=covariance, gravity_sensor=_model(state, rotations, drift_time)[2],
        drift_rate=np.zeros(6) if state["rate"] is None else np.array(state["rate"]))


def check_identification(result, record, reference: ReferenceWeight | None = None,
                         with_drift: bool = False) -> tuple[SensorGainFit, dict]:
    """Run the sensor check beside an identification: ``result`` the :class:`ftacq.identification.
    IdentificationResult` of ``record`` (its parameters, robust weights and drift model are the start). The noise
    model (per-channel scatter, robot orientation error: pose_error.py) is estimated again from the check's own
    residuals (:data:`NOISE_ROUNDS` times): a gain error inflates the paper model's scatter, and C's 1σ would be
    overstated with it. Return the fit and the straight-line trend of its residuals against time (trend.py
    ``ResidualTrend.to_dict``): a drift the paper's model showed only because the gains are off is not in it.
    ``with_drift``: fit a linear bias drift too (from zero when the calibration has none), so that a drift and a
    gain error are told apart in one fit (:func:`drift_trend` reads the drift off it)."""
    from ftacq.identification import ORIENTATION_MIN_POSES, _relative_noise, _standard_error, robust, trend
    from ftacq.identification.pose_error import estimate_noise

    cal = result.calibration
    rotations = np.asarray(record.flange_R_base, dtype=float)
    wrench = np.asarray(record.wrench, dtype=float)
    n = len(rotations)
    drift_model = dict(cal.metadata.get("drift_model", {}) or {})
    times = trend.pose_times(record)
    linear = drift_model.get("model") == "linear"
    rate = np.asarray(drift_model["bias_rate"], dtype=float) if linear else np.zeros(6) if with_drift else None
    start: dict[str, Any] = {"S": np.array(cal.sensor_rotation), "g": np.array(cal.gravity_base), "F0": np.array(cal.force_bias),
             "c": np.array(cal.center_of_mass), "T0": np.array(cal.torque_bias), "rate": rate}
    linear = rate is not None
    noise_meta = dict(cal.metadata.get("noise", {}) or {})
    orientation_rad = float(np.radians(float(noise_meta.get("orientation_error_deg", 0.0))))
    scatter2 = np.asarray(noise_meta.get("extra_scatter") or np.zeros(6), dtype=float) ** 2
    pose_weight = np.asarray(result.weights, dtype=float)
    gravity_sensor = np.einsum("ab,nbc,c->na", start["S"], rotations, start["g"])
    whiten = whitening(np.asarray(result.noise, dtype=float), orientation_rad, gravity_sensor, start["c"], pose_weight)
    standard_error = _standard_error(record)
    relative = (_relative_noise(record) if standard_error is not None or record.standard_error is None
                else np.ones((n, 6)))
    floor = robust.noise_floor(wrench)
    drift_time = times.drift_time if linear else None
    fit = fit_sensor_gain(rotations, wrench, start, whiten, drift_time, reference)
    noise = None
    for _ in range(NOISE_ROUNDS):
        sensitivity = orientation_sensitivity(fit.gravity_sensor, fit.center_of_mass)
        n_parameters = fit.parameter_covariance.shape[0]
        noise = estimate_noise(fit.residual, sensitivity, standard_error, relative, pose_weight,
                               max((6.0 * n - n_parameters) / (6.0 * n), 1e-3), floor, scatter2,
                               orientation_rad**2, model_orientation=n >= ORIENTATION_MIN_POSES)
        weight = noise.weight(pose_weight)
        whiten = weight if weight.ndim == 3 else np.sqrt(weight)[:, :, None] * np.eye(6)
        scatter2, orientation_rad = noise.scatter**2, float(np.radians(noise.orientation_error_deg))
        fit = fit_sensor_gain(rotations, wrench, start, whiten, drift_time, reference)
    variance = noise.total_variance if noise is not None else np.asarray(result.noise, dtype=float) ** 2
    found = trend.residual_trend(fit.residual, variance, pose_weight, times.drift_time, times.unit)
    extra = {"extra_scatter": np.sqrt(scatter2).tolist(), "orientation_error_deg": float(np.degrees(orientation_rad))}
    return replace(fit, noise=extra), found.to_dict()


def drift_trend(fit: SensorGainFit, record) -> "ResidualTrend":
    """Return the bias drift of a check fitted ``with_drift`` as a trend.py ``ResidualTrend`` (rates, their 1σ
    from the joint fit, the χ²₆ test of "no drift"): the identification's "auto" decides on it, so that a gain
    error does not pass for a drift nor a drift for a gain error."""
    from ftacq.identification import trend

    times = trend.pose_times(record)
    rate = fit.drift_rate
    covariance = fit.parameter_covariance[_CAL:_CAL + 6, _CAL:_CAL + 6]
    chi2 = float(rate @ np.linalg.pinv(covariance) @ rate)
    return trend.ResidualTrend(rate, np.sqrt(np.maximum(np.diag(covariance), 0.0)), chi2,
                               float(chdtrc(6, chi2)), float(np.ptp(times.drift_time)), times.unit)


__all__ = ["check_identification", "drift_trend", "ReferenceWeight", "SensorGainFit", "fit_sensor_gain", "whitening",
           "SYMMETRIC_ENTRIES", "REFERENCE_GRAVITY_RELATIVE_SIGMA", "SIGNIFICANCE_P"]
