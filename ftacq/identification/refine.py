"""Joint refinement: weighted least squares over all parameters, the rotation on SO(3) (beyond the paper).

Minimises Σ_i Σ_ch (r_i,ch / σ_i,ch)² · w_i over θ = (sensor_rotation, gravity_base, force_bias,
center_of_mass, torque_bias), where r_i = measured − predicted wrench of the model (eqs 10-11):

    F_i = S R_i g + F0,   T_i = c × (S R_i g) + T0

σ_i,ch is the per-channel noise of pose i and w_i a robust weight (robust.py). The rotation is updated
multiplicatively, S ← exp([δ]×) S with δ a sensor-frame rotation vector, so it stays on SO(3). The
Jacobian is analytic (v_i = S R_i g, M_i = S R_i):

    ∂F/∂δ = −[v]×   ∂F/∂g = M        ∂F/∂F0 = I
    ∂T/∂δ = −[c]×[v]×   ∂T/∂g = [c]× M   ∂T/∂c = −[v]×   ∂T/∂T0 = I

Levenberg-Marquardt with Marquardt (diagonal) scaling on the 15×15 normal equations, vectorised over
poses, so 100 000 poses cost a few numpy passes per iteration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftacq.calibration import Calibration
from ftacq.identification.torque import skew
from ftacq.so3 import rotation_from_rotvec

PARAMETER_NAMES = ("sensor_rotation_rad", "gravity_base", "force_bias", "center_of_mass_m", "torque_bias")
"""The five 3-vectors of the parameter vector, in order (the rotation as a sensor-frame increment, rad)."""
PARAMETER_SLICES = {name: slice(3 * k, 3 * k + 3) for k, name in enumerate(PARAMETER_NAMES)}

MAX_ITERATIONS = 50
DECREMENT_TOLERANCE = 1e-9
"""Stop when the Gauss-Newton step would lower the cost (χ² units) by less than this × max(cost, 1):
the step then moves every parameter by far less than its 1σ."""
INITIAL_DAMPING = 1e-8
MAX_DAMPING = 1e12


@dataclass(frozen=True)
class ModelParameters:
    """The model's parameters (SI; sensor frame unless stated)."""

    sensor_rotation: np.ndarray  # (3, 3)
    gravity_base: np.ndarray  # (3,) N, base frame
    force_bias: np.ndarray  # (3,) N
    center_of_mass: np.ndarray  # (3,) m
    torque_bias: np.ndarray  # (3,) N·m

    @staticmethod
    def from_calibration(calibration: Calibration) -> "ModelParameters":
        return ModelParameters(
            np.array(calibration.sensor_rotation),
            np.array(calibration.gravity_base),
            np.array(calibration.force_bias),
            np.array(calibration.center_of_mass),
            np.array(calibration.torque_bias),
        )

    def to_calibration(self, **kwargs) -> Calibration:
        return Calibration(
            sensor_rotation=self.sensor_rotation,
            force_bias=self.force_bias,
            torque_bias=self.torque_bias,
            gravity_base=self.gravity_base,
            center_of_mass=self.center_of_mass,
            **kwargs,
        )

    def updated(self, step: np.ndarray) -> "ModelParameters":
        """Return the parameters moved by a 15-vector step (rotation multiplicatively, the rest additively)."""
        rotation = rotation_from_rotvec(step[0:3]) @ self.sensor_rotation
        u, _, vt = np.linalg.svd(rotation)  # keep it exactly orthonormal over many steps
        rotation = u @ vt
        return ModelParameters(
            rotation,
            self.gravity_base + step[3:6],
            self.force_bias + step[6:9],
            self.center_of_mass + step[9:12],
            self.torque_bias + step[12:15],
        )


def predict(params: ModelParameters, flange_R_base: np.ndarray) -> np.ndarray:
    """Return the predicted contact-free wrench (N, 6) at (N, 3, 3) orientations (eqs 10-11)."""
    gravity_sensor = (flange_R_base @ params.gravity_base) @ params.sensor_rotation.T
    torque = np.cross(params.center_of_mass, gravity_sensor) + params.torque_bias
    return np.concatenate([gravity_sensor + params.force_bias, torque], axis=1)


def jacobian(params: ModelParameters, flange_R_base: np.ndarray) -> np.ndarray:
    """Return ∂(predicted wrench)/∂θ, (N, 6, 15), θ ordered as :data:`PARAMETER_NAMES`."""
    n = len(flange_R_base)
    m = params.sensor_rotation @ flange_R_base  # (N, 3, 3) = S R_i
    v = m @ params.gravity_base  # (N, 3)
    skew_v = skew(v)
    skew_c = skew(params.center_of_mass)
    jac = np.zeros((n, 6, 15))
    jac[:, 0:3, 0:3] = -skew_v
    jac[:, 0:3, 3:6] = m
    jac[:, 0:3, 6:9] = np.eye(3)
    jac[:, 3:6, 0:3] = -(skew_c @ skew_v)
    jac[:, 3:6, 3:6] = skew_c @ m
    jac[:, 3:6, 9:12] = -skew_v
    jac[:, 3:6, 12:15] = np.eye(3)
    return jac


def normal_equations(
    params: ModelParameters, flange_R_base: np.ndarray, wrench: np.ndarray, weight: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Return (JᵀWJ (15, 15), JᵀW r (15,), cost Σ W r², residuals r (N, 6)); ``weight`` (N, 6) = w_i / σ²."""
    residual = wrench - predict(params, flange_R_base)
    jac = jacobian(params, flange_R_base).reshape(-1, 15)
    w = weight.reshape(-1)
    weighted = jac * w[:, None]
    return weighted.T @ jac, weighted.T @ residual.reshape(-1), float(np.sum(w * residual.reshape(-1) ** 2)), residual


def cost(params: ModelParameters, flange_R_base: np.ndarray, wrench: np.ndarray, weight: np.ndarray) -> float:
    """Return Σ W r² at ``params``."""
    residual = wrench - predict(params, flange_R_base)
    return float(np.sum(weight * residual**2))


@dataclass(frozen=True)
class RefineResult:
    """Outcome of :func:`levenberg_marquardt`: the optimum, convergence flag and iteration count."""

    params: ModelParameters
    converged: bool
    iterations: int
    cost: float


def levenberg_marquardt(
    params: ModelParameters,
    flange_R_base: np.ndarray,
    wrench: np.ndarray,
    weight: np.ndarray,
    max_iterations: int = MAX_ITERATIONS,
) -> RefineResult:
    """Minimise Σ weight · r² from ``params`` (``weight`` (N, 6) = w_i / σ_i,ch²); return the optimum."""
    damping = INITIAL_DAMPING
    jtj, jtr, current, _ = normal_equations(params, flange_R_base, wrench, weight)
    for iteration in range(1, max_iterations + 1):
        scale = np.sqrt(np.maximum(np.diag(jtj), 1e-300))
        scaled = jtj / np.outer(scale, scale)
        accepted = False
        while damping <= MAX_DAMPING:
            try:
                step = np.linalg.solve(scaled + damping * np.eye(15), jtr / scale) / scale
            except np.linalg.LinAlgError:
                damping *= 10.0
                continue
            candidate = params.updated(step)
            trial = cost(candidate, flange_R_base, wrench, weight)
            if trial <= current:
                accepted = True
                break
            damping *= 10.0
        if not accepted:
            return RefineResult(params, True, iteration, current)  # no descent possible: at the optimum
        predicted_decrease = float(step @ jtr)
        params = candidate
        damping = max(damping / 10.0, 1e-15)
        jtj, jtr, current, _ = normal_equations(params, flange_R_base, wrench, weight)
        if predicted_decrease <= DECREMENT_TOLERANCE * max(current, 1.0):
            return RefineResult(params, True, iteration, current)
    return RefineResult(params, False, max_iterations, current)
