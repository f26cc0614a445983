"""Joint refinement: weighted least squares over all parameters, the rotation on SO(3) (beyond the paper).

Minimises Σ_i Σ_ch (r_i,ch / σ_i,ch)² · w_i (or, with the robot's orientation error modelled, Σ_i w_i r_iᵀ C_i⁻¹ r_i
with the full 6×6 noise covariance of pose_error.py) over θ = (sensor_rotation, gravity_base, force_bias,
center_of_mass, torque_bias), where r_i = measured − predicted wrench of the model (eqs 10-11):

    F_i = S R_i g + F0,   T_i = c × (S R_i g) + T0

σ_i,ch is the per-channel noise of pose i and w_i a robust weight (robust.py). The rotation is updated
multiplicatively, S ← exp([δ]×) S with δ a sensor-frame rotation vector, so it stays on SO(3). The
Jacobian is analytic (v_i = S R_i g, M_i = S R_i):

    ∂F/∂δ = −[v]×   ∂F/∂g = M        ∂F/∂F0 = I
    ∂T/∂δ = −[c]×[v]×   ∂T/∂g = [c]× M   ∂T/∂c = −[v]×   ∂T/∂T0 = I

Levenberg-Marquardt with Marquardt (diagonal) scaling on the 15×15 normal equations, vectorised over
poses, so 100 000 poses cost a few numpy passes per iteration.

Bias drift (beyond the paper; docs/method-notes.md): with ``ModelParameters.bias_rate`` set, the biases drift
linearly over the recording, F0(t) = F0 + Ḟ0 s_i, T0(t) = T0 + Ṫ0 s_i, where s_i is the pose's time relative to
the end of the recording (``OrientationBlock.drift_time``, ≤ 0): six more parameters (21 in all) with
∂F/∂Ḟ0 = s_i I, ∂T/∂Ṫ0 = s_i I, and ``force_bias``/``torque_bias`` are the biases at the end of the recording.
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
DRIFT_PARAMETER_NAMES = ("force_bias_rate", "torque_bias_rate")
"""The two 3-vectors appended (parameters 15-20) when the bias drift is modelled (per unit of drift time)."""
DRIFT_SLICE = slice(15, 21)

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
    bias_rate: np.ndarray | None = None  # (6,) N, N·m per unit of drift time, or None (no drift modelled)

    @property
    def size(self) -> int:
        """Number of parameters: 15, or 21 with the bias drift."""
        return 15 if self.bias_rate is None else 21

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
            None if self.bias_rate is None else self.bias_rate + step[DRIFT_SLICE],
        )


def gravity_in_sensor(params: ModelParameters, flange_R_base: np.ndarray) -> np.ndarray:
    """Return v_i = S R_i g (N, 3) [N]: the tool's weight in the sensor frame at (N, 3, 3) orientations."""
    return (flange_R_base @ params.gravity_base) @ params.sensor_rotation.T


def predict(params: ModelParameters, flange_R_base: np.ndarray, drift_time: np.ndarray | None = None) -> np.ndarray:
    """Return the predicted contact-free wrench (N, 6) at (N, 3, 3) orientations (eqs 10-11), with the drifted
    biases at ``drift_time`` (N,) when ``params.bias_rate`` is set."""
    gravity_sensor = gravity_in_sensor(params, flange_R_base)
    out = np.empty((len(gravity_sensor), 6))
    out[:, :3] = gravity_sensor + params.force_bias
    out[:, 3:] = gravity_sensor @ skew(params.center_of_mass).T + params.torque_bias  # c × g_s
    if params.bias_rate is not None and drift_time is not None:
        out += np.asarray(drift_time, dtype=float).reshape(-1, 1) * params.bias_rate
    return out


def jacobian(params: ModelParameters, flange_R_base: np.ndarray, drift_time: np.ndarray | None = None) -> np.ndarray:
    """Return ∂(predicted wrench)/∂θ, (N, 6, 15) (21 with the bias drift), θ ordered as :data:`PARAMETER_NAMES`
    (then :data:`DRIFT_PARAMETER_NAMES`)."""
    rotations_t = np.ascontiguousarray(np.asarray(flange_R_base, dtype=float).transpose(1, 2, 0))
    return _jacobian_t(params, rotations_t, drift_time).transpose(2, 1, 0)


class OrientationBlock:
    """Orientations laid out for vectorised refinement: ``rotations_t`` (3, 3, N) contiguous per element, and
    each pose's drift time s_i (N,) when the bias drift is modelled (else None)."""

    def __init__(self, flange_R_base: np.ndarray, drift_time: np.ndarray | None = None) -> None:
        self.flange_R_base = np.asarray(flange_R_base, dtype=float)
        self.rotations_t = np.ascontiguousarray(self.flange_R_base.transpose(1, 2, 0))
        self.drift_time = None if drift_time is None else np.asarray(drift_time, dtype=float).reshape(-1)

    def __len__(self) -> int:
        return self.rotations_t.shape[2]


def _gravity_terms(params: ModelParameters, rotations_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (M (3, 3, N) = S R_i, v (3, N) = S R_i g) for a (3, 3, N) block of orientations."""
    n = rotations_t.shape[2]
    m = (params.sensor_rotation @ rotations_t.reshape(3, 3 * n)).reshape(3, 3, n)
    v = np.einsum("abn,b->an", m, params.gravity_base)
    return m, v


def _predict_t(params: ModelParameters, rotations_t: np.ndarray, drift_time: np.ndarray | None = None) -> np.ndarray:
    """Return the predicted wrench (6, N) for a (3, 3, N) block (drifted biases at ``drift_time`` (N,))."""
    gravity_flange = np.einsum("abn,b->an", rotations_t, params.gravity_base)
    v = params.sensor_rotation @ gravity_flange
    out = np.empty((6, v.shape[1]))
    out[:3] = v + params.force_bias[:, None]
    out[3:] = skew(params.center_of_mass) @ v + params.torque_bias[:, None]
    if params.bias_rate is not None and drift_time is not None:
        out += params.bias_rate[:, None] * drift_time[None, :]
    return out


def _jacobian_t(params: ModelParameters, rotations_t: np.ndarray, drift_time: np.ndarray | None = None) -> np.ndarray:
    """Return the Jacobian as (15, 6, N) (21 with the bias drift): [parameter, channel, pose]."""
    m, v = _gravity_terms(params, rotations_t)
    n = v.shape[1]
    c = params.center_of_mass
    jac = np.zeros((params.size, 6, n))
    if params.bias_rate is not None:
        for k in range(6):
            jac[15 + k, k] = 0.0 if drift_time is None else drift_time
    v0, v1, v2 = v
    # −[v]× as J[b, a] = −skew(v)[a, b], for the rotation increment on F (cols 0-2) and the centre of mass on T
    for base, channel in ((0, 0), (9, 3)):
        jac[base + 1, channel + 0] = v2
        jac[base + 2, channel + 0] = -v1
        jac[base + 0, channel + 1] = -v2
        jac[base + 2, channel + 1] = v0
        jac[base + 0, channel + 2] = v1
        jac[base + 1, channel + 2] = -v0
    jac[3:6, 0:3] = m.transpose(1, 0, 2)  # ∂F_a/∂g_b = M[a, b]
    jac[6, 0] = jac[7, 1] = jac[8, 2] = 1.0  # ∂F/∂F0 = I
    # ∂T_a/∂δ_b = −(v_a c_b − δ_ab c·v)
    jac[0:3, 3:6] = -c[:, None, None] * v[None, :, :]
    c_dot_v = c @ v
    for b in range(3):
        jac[b, 3 + b] += c_dot_v
    cm = (skew(c) @ m.reshape(3, 3 * n)).reshape(3, 3, n)
    jac[3:6, 3:6] = cm.transpose(1, 0, 2)  # ∂T_a/∂g_b = ([c]× M)[a, b]
    jac[12, 3] = jac[13, 4] = jac[14, 5] = 1.0  # ∂T/∂T0 = I
    return jac


CHUNK_POSES = 2048
"""Poses per block when accumulating the normal equations (bounds the Jacobian block's memory)."""


def _as_orientation_block(flange_R_base: np.ndarray | OrientationBlock) -> OrientationBlock:
    return flange_R_base if isinstance(flange_R_base, OrientationBlock) else OrientationBlock(flange_R_base)


def normal_equations(
    params: ModelParameters, flange_R_base: np.ndarray | OrientationBlock, wrench: np.ndarray, weight: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Return (JᵀWJ (15, 15), JᵀW r (15,), cost rᵀW r, residuals r (N, 6)).

    ``weight`` is (N, 6) = w_i / σ_i,ch² (independent channels) or (N, 6, 6) whitening matrices
    A_i = √w_i L_i⁻¹ with L_i L_iᵀ = C_i the pose's full noise covariance (pose_error.py): W_i = A_iᵀ A_i.
    ``flange_R_base`` is (N, 3, 3) or a :class:`OrientationBlock` (reused across calls).
    """
    poses = _as_orientation_block(flange_R_base)
    n = len(poses)
    full = weight.ndim == 3
    size = params.size
    information = np.zeros((size, size))
    gradient = np.zeros(size)
    residual = np.empty((n, 6))
    total = 0.0
    for start in range(0, n, CHUNK_POSES):
        block = slice(start, min(start + CHUNK_POSES, n))
        rotations_t = poses.rotations_t[:, :, block]
        drift_time = None if poses.drift_time is None else poses.drift_time[block]
        r_t = wrench[block].T - _predict_t(params, rotations_t, drift_time)
        residual[block] = r_t.T
        jac = _jacobian_t(params, rotations_t, drift_time)
        if full:
            whitened_jac = (weight[block] @ jac.transpose(2, 1, 0)).reshape(-1, size)  # (n·6, size)
            whitened_r = (weight[block] @ r_t.T[:, :, None]).reshape(-1)
            information += whitened_jac.T @ whitened_jac
            gradient += whitened_jac.T @ whitened_r
            total += float(whitened_r @ whitened_r)
        else:
            jac = jac.reshape(size, -1)
            weighted = jac * weight[block].T.reshape(-1)
            information += weighted @ jac.T
            gradient += weighted @ r_t.reshape(-1)
            total += float(np.sum(weight[block].T * r_t**2))
    return information, gradient, total, residual


def cost(params: ModelParameters, flange_R_base: np.ndarray | OrientationBlock, wrench: np.ndarray,
         weight: np.ndarray) -> float:
    """Return rᵀ W r at ``params`` (``weight`` as in :func:`normal_equations`)."""
    poses = _as_orientation_block(flange_R_base)
    residual = wrench.T - _predict_t(params, poses.rotations_t, poses.drift_time)
    if weight.ndim == 3:
        whitened = weight @ residual.T[:, :, None]
        return float(np.sum(whitened**2))
    return float(np.sum(weight.T * residual**2))


@dataclass(frozen=True)
class RefineResult:
    """Outcome of :func:`levenberg_marquardt`: the optimum, convergence flag and iteration count."""

    params: ModelParameters
    converged: bool
    iterations: int
    cost: float


def levenberg_marquardt(
    params: ModelParameters,
    flange_R_base: np.ndarray | OrientationBlock,
    wrench: np.ndarray,
    weight: np.ndarray,
    max_iterations: int = MAX_ITERATIONS,
) -> RefineResult:
    """Minimise rᵀ W r from ``params`` (``weight`` (N, 6) = w_i / σ_i,ch² or (N, 6, 6) whitening matrices, as in
    :func:`normal_equations`); return the optimum. ``flange_R_base`` as in :func:`normal_equations`."""
    poses = _as_orientation_block(flange_R_base)
    damping = INITIAL_DAMPING
    jtj, jtr, current, _ = normal_equations(params, poses, wrench, weight)
    for iteration in range(1, max_iterations + 1):
        scale = np.sqrt(np.maximum(np.diag(jtj), 1e-300))
        scaled = jtj / np.outer(scale, scale)
        accepted = False
        while damping <= MAX_DAMPING:
            try:
                step = np.linalg.solve(scaled + damping * np.eye(len(jtr)), jtr / scale) / scale
            except np.linalg.LinAlgError:
                damping *= 10.0
                continue
            candidate = params.updated(step)
            trial = cost(candidate, poses, wrench, weight)
            if trial <= current:
                accepted = True
                break
            damping *= 10.0
        if not accepted:
            return RefineResult(params, True, iteration, current)  # no descent possible: at the optimum
        predicted_decrease = float(step @ jtr)
        params = candidate
        damping = max(damping / 10.0, 1e-15)
        jtj, jtr, current, _ = normal_equations(params, poses, wrench, weight)
        if predicted_decrease <= DECREMENT_TOLERANCE * max(current, 1.0):
            return RefineResult(params, True, iteration, current)
    return RefineResult(params, False, max_iterations, current)
