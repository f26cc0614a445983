"""Identifying the tool's inertia from a recorded motion: linear least squares on the body regressor, physically
consistent, with 1σ, conditioning and the error on held-out motion.

Model (:mod:`ftacq.dynamics.model`): wrench_S = R(q, q̇, q̈) π + bias, π = [m, m c, I_S] (ten parameters). The
static calibration already knows the sensor rotation, the biases, the gravity direction, and the mass and centre
of mass very well (at rest, many poses). So:

1. The sensor samples are averaged onto the robot's sample times (a box of one robot period; one host clock,
   :mod:`ftacq.dynamics.timing`), after the lag between the streams is measured (:func:`estimate_lag`: the shift
   that fits the model best).
2. Mass and centre of mass: a fit of all ten parameters with the static estimates as prior rows (their 1σ) tells
   whether the motion adds information; the motion's estimate replaces the static one only where its 1σ is
   at least :data:`IMPROVEMENT_RATIO` smaller (Kubus, Kröger & Wahl 2008 identify all ten from motion alone; at
   rest ftacq's static estimate is usually better).
3. Inertia: with m and c fixed, the six inertia parameters beside six bias offsets and a residual lag, each row
   weighted by its noise (:mod:`ftacq.dynamics.inertia_fit`); robot samples next to a step of q̈ left out. If the
   solution is not a physical body (the pseudo-inertia of Wensing, Kim & Slotine 2017 not positive definite), it is
   solved again over Σ_c = L Lᵀ (Σ_c = ½ tr(I_c) 𝟙 − I_c, L lower-triangular), consistent by construction
   (Traversaro et al. 2016 and Nadeau et al. 2022 constrain the same set).
4. 1σ from a block sandwich covariance with the static m, c 1σ propagated (:mod:`ftacq.dynamics.inertia_fit`
   says why the weighted normal equations were too small); the regressor's condition number (columns scaled to unit
   norm); the error of the static and of the dynamic model on the last :data:`HELD_OUT_FRACTION` of the motion,
   which the fit never saw.

The record's kinematics are the physical arm's (``actual_q``, ``actual_qd``, ``target_qdd`` of the servo lag
earlier: :mod:`ftacq.dynamics.acceleration`); the servo lag measured at recording is reported beside the sensor's.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ftacq import STANDARD_GRAVITY_M_S2
from ftacq.calibration import Calibration
from ftacq.dynamics.inertia_fit import fit_inertia, fixed_sensitivity, noise_weights
from ftacq.dynamics.model import SensorDynamics, gravity_vector, pseudo_inertia
from ftacq.dynamics.timing import box_average
from ftacq.errors import InputError
from ftacq.kinematics import URModel

HELD_OUT_FRACTION = 0.25
"""The last quarter of the motion (by time) validates; the fit uses the rest."""
IMPROVEMENT_RATIO = 0.9
"""Motion replaces the static mass (centre of mass) only when its 1σ is below this fraction of the static 1σ."""
LAG_SEARCH_S = 0.03
"""The lag between sensor and robot streams is searched within ± this, s."""
LAG_STEP_S = 0.0005
LAG_COARSE_STEP_S = 0.002
"""The lag's first grid, s (the model's fit changes smoothly over ms: the fine grid of LAG_STEP_S follows)."""
MIN_ROWS = 50
"""Fewest robot samples (with sensor samples around them) an identification accepts."""
_NOISE_FLOOR = 1e-12


@dataclass(frozen=True)
class MotionRecord:
    """A recorded motion, both streams on the host clock (:mod:`ftacq.dynamics.timing`), SI units.

    Attributes:
        sensor_time_s (N,), wrench (N, 6): raw sensor samples, sensor frame (N, N·m).
        robot_time_s (M,), q, qd, qdd (M, 6): joint positions (rad), speeds (rad/s), accelerations (rad/s²).
    """

    sensor_time_s: np.ndarray
    wrench: np.ndarray
    robot_time_s: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n, m = np.shape(self.sensor_time_s)[0], np.shape(self.robot_time_s)[0]
        if np.shape(self.wrench) != (n, 6):
            raise InputError(f"motion record: wrench has shape {np.shape(self.wrench)}, expected ({n}, 6)")
        for name in ("q", "qd", "qdd"):
            if np.shape(getattr(self, name)) != (m, 6):
                raise InputError(f"motion record: {name} has shape {np.shape(getattr(self, name))}, expected ({m}, 6)")

    @property
    def robot_period_s(self) -> float:
        return float(np.median(np.diff(self.robot_time_s))) if len(self.robot_time_s) > 1 else 0.002


@dataclass(frozen=True)
class DynamicsResult:
    """The identification's outcome (SI units, sensor frame).

    Attributes:
        calibration: the input calibration with ``inertia`` and ``sensor_offset`` (and mass / centre of mass where
            the motion improved on them), ``uncertainty['inertia_kg_m2']`` and ``metadata['dynamics']``.
        inertia, inertia_sigma: about the centre of mass (3, 3) and its 1σ (3, 3).
        mass_from_motion, com_from_motion: whether the motion's estimate replaced the static one.
        mass_sigma_static/motion, com_sigma_static/motion: the 1σ each source gives (kg; m, per axis).
        constrained: the unconstrained solution was not a physical body; the consistent one was kept.
        condition_number: of the inertia regressor, columns scaled to unit norm.
        lag_s: the sensor stream's lag behind the robot stream (host clock), as measured or given.
        servo_lag_s: how far the arm followed its target (``actual_*`` behind ``target_*``), measured when the motion
            was recorded (None: not known, e.g. an imported record); the record's q̈ is the physical arm's.
        bias_offset: the biases during the motion minus the calibration's (6,), N and N·m (fitted beside the
            inertia: drift since the static poses).
        rows, held_out_rows: robot samples used for the fit and for validation.
        held_out_rms_static, held_out_rms_dynamic, held_out_max_static, held_out_max_dynamic: (6,) error of the
            compensated wrench [N, N·m] on the held-out motion with each model.
    """

    calibration: Calibration
    inertia: np.ndarray
    inertia_sigma: np.ndarray
    mass_from_motion: bool
    com_from_motion: bool
    mass_sigma_static: float
    mass_sigma_motion: float
    com_sigma_static: np.ndarray
    com_sigma_motion: np.ndarray
    constrained: bool
    condition_number: float
    lag_s: float
    rows: int
    held_out_rows: int
    held_out_rms_static: np.ndarray
    held_out_rms_dynamic: np.ndarray
    held_out_max_static: np.ndarray
    held_out_max_dynamic: np.ndarray
    servo_lag_s: float | None = None
    bias_offset: np.ndarray = field(default_factory=lambda: np.zeros(6))

    def summary(self) -> dict[str, Any]:
        """JSON-serialisable figures for ``metadata['dynamics']`` and the report."""
        return {
            "lag_ms": 1e3 * self.lag_s,
            "servo_lag_ms": None if self.servo_lag_s is None else 1e3 * self.servo_lag_s,
            "bias_offset": self.bias_offset.tolist(), "rows": self.rows, "held_out_rows": self.held_out_rows,
            "condition_number": self.condition_number, "constrained": self.constrained,
            "mass_from_motion": self.mass_from_motion, "com_from_motion": self.com_from_motion,
            "mass_sigma_kg": {"static": self.mass_sigma_static, "motion": self.mass_sigma_motion},
            "com_sigma_m": {"static": self.com_sigma_static.tolist(), "motion": self.com_sigma_motion.tolist()},
            "held_out_rms": {"static": self.held_out_rms_static.tolist(), "dynamic": self.held_out_rms_dynamic.tolist()},
            "held_out_max": {"static": self.held_out_max_static.tolist(), "dynamic": self.held_out_max_dynamic.tolist()},
        }


def _vech_to_matrix(v: np.ndarray) -> np.ndarray:
    """(…, 6) in Pinocchio's order (xx, xy, yy, xz, yz, zz) → (…, 3, 3)."""
    xx, xy, yy, xz, yz, zz = np.moveaxis(np.asarray(v, dtype=float), -1, 0)
    return np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -2)


def _matrix_to_vech(m: np.ndarray) -> np.ndarray:
    return np.array([m[0, 0], m[0, 1], m[1, 1], m[0, 2], m[1, 2], m[2, 2]])


def _steiner(mass_kg: float, com_m: np.ndarray) -> np.ndarray:
    """m (cᵀc 𝟙 − c cᵀ): the inertia about the sensor origin of a point mass at c (parallel-axis term)."""
    c = np.asarray(com_m, dtype=float)
    return mass_kg * (c @ c * np.eye(3) - np.outer(c, c))


def aligned_rows(record: MotionRecord, lag_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Return (index of robot samples with sensor data around them, the sensor wrench averaged there (K, 6))."""
    mean, count = box_average(record.sensor_time_s, record.wrench, np.asarray(record.robot_time_s) + lag_s,
                              record.robot_period_s)
    keep = np.nonzero(count > 0)[0]
    return keep, mean[keep]


def acceleration_steps(qdd: np.ndarray) -> np.ndarray:
    """(M,) True next to a step of q̈ (a moveJ's switches): the sensor samples averaged around such a state straddle
    the step, an error of half the step's wrench (a few N with a heavy tool) that no parameter explains. The quick
    run's rule (:func:`ftacq.dynamics.joint._near_acceleration_steps`), shared."""
    from ftacq.dynamics.joint import _near_acceleration_steps  # joint imports this module

    return _near_acceleration_steps(np.asarray(qdd, dtype=float))


def _channel_weights(residual: np.ndarray) -> np.ndarray:
    scatter = np.sqrt(np.mean(residual ** 2, axis=0))
    return 1.0 / np.maximum(scatter, _NOISE_FLOOR * max(float(scatter.max()), 1.0))


def _weighted_lstsq(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Solve a x ≈ b; return (x, covariance scaled by χ²/dof, condition number of a with unit-norm columns)."""
    x, *_ = np.linalg.lstsq(a, b, rcond=None)
    dof = max(a.shape[0] - a.shape[1], 1)
    chi2 = float(np.sum((b - a @ x) ** 2)) / dof
    covariance = np.linalg.pinv(a.T @ a) * chi2
    norms = np.linalg.norm(a, axis=0)
    condition = float(np.linalg.cond(a / np.where(norms > 0, norms, 1.0)))
    return x, covariance, condition


def estimate_lag(record: MotionRecord, regressor: np.ndarray, bias: np.ndarray, search_s: float = LAG_SEARCH_S,
                 step_s: float = LAG_STEP_S) -> float:
    """Return the lag (s) of the sensor stream behind the robot stream: the shift of the sensor samples that the
    ten-parameter model fits best (a grid of :data:`LAG_COARSE_STEP_S` over ± ``search_s``, then of ``step_s``
    around its best, refined by a parabola through the best three)."""

    smooth = ~acceleration_steps(record.qdd)

    def cost(shift: float) -> float:
        keep, wrench = aligned_rows(record, shift)
        keep, wrench = keep[smooth[keep]], wrench[smooth[keep]]
        if keep.size < MIN_ROWS:
            return np.inf
        a = regressor[keep].reshape(-1, 10)
        b = (wrench - bias).reshape(-1)
        scale = 1.0 / np.maximum(np.std(wrench - bias, axis=0), _NOISE_FLOOR)
        weights = np.tile(scale, keep.size)
        x, *_ = np.linalg.lstsq(a * weights[:, None], b * weights, rcond=None)
        return float(np.mean(((b - a @ x) * weights) ** 2))

    coarse = np.arange(-search_s, search_s + 0.5 * LAG_COARSE_STEP_S, LAG_COARSE_STEP_S)
    coarse_costs = np.array([cost(shift) for shift in coarse])
    if not np.isfinite(coarse_costs).any():
        raise InputError("motion record: the sensor and robot samples do not overlap in time")
    centre = float(coarse[int(np.argmin(coarse_costs))])
    shifts = centre + np.arange(-LAG_COARSE_STEP_S, LAG_COARSE_STEP_S + 0.5 * step_s, step_s)
    costs = np.array([cost(shift) for shift in shifts])
    best = int(np.argmin(costs))
    if 0 < best < len(shifts) - 1 and np.all(np.isfinite(costs[best - 1:best + 2])):
        c0, c1, c2 = costs[best - 1:best + 2]
        curvature = c0 - 2 * c1 + c2
        if curvature > 0:
            return float(shifts[best] + 0.5 * step_s * (c0 - c2) / curvature)
    return float(shifts[best])


def _consistent_inertia(a: np.ndarray, b: np.ndarray, start: np.ndarray, mass_kg: float, com_m: np.ndarray) -> np.ndarray:
    """Least squares over Σ_c = L Lᵀ (inertia about the centre of mass I_c = tr(Σ_c) 𝟙 − Σ_c): a physical body."""
    from scipy.optimize import least_squares

    steiner = _steiner(mass_kg, com_m)
    rows, cols = np.tril_indices(3)

    def inertia_about_sensor(params: np.ndarray) -> np.ndarray:
        lower = np.zeros((3, 3))
        lower[rows, cols] = params
        sigma = lower @ lower.T
        return _matrix_to_vech(np.trace(sigma) * np.eye(3) - sigma + steiner)

    inertia_c = _vech_to_matrix(start) - steiner
    sigma0 = 0.5 * np.trace(inertia_c) * np.eye(3) - inertia_c
    values, vectors = np.linalg.eigh(0.5 * (sigma0 + sigma0.T))
    floor = max(1e-6 * float(np.abs(values).max()), 1e-12)
    sigma0 = vectors @ np.diag(np.maximum(values, floor)) @ vectors.T
    x0 = np.linalg.cholesky(sigma0)[rows, cols]
    fit = least_squares(lambda p: a @ inertia_about_sensor(p) - b, x0, method="lm", xtol=1e-15, ftol=1e-15)
    return inertia_about_sensor(fit.x)


def _fixed_covariance(fit, regressor: np.ndarray, mass_kg: float, com_m: np.ndarray, mass_sigma_kg: float,
                      com_sigma_m: np.ndarray) -> np.ndarray:
    """Covariance (6, 6) of the inertia about the centre of mass (vech) that the 1σ of the fixed mass and centre of
    mass cause: through the fit (:func:`ftacq.dynamics.inertia_fit.fixed_sensitivity`) and the parallel-axis
    term, by first differences."""
    sensitivity = fixed_sensitivity(fit, regressor)  # d I_S / d (m, m c)

    def inertia_c(values: np.ndarray) -> np.ndarray:
        m, c = values[0], values[1:]
        shift = np.concatenate([[m], m * c]) - np.concatenate([[mass_kg], mass_kg * com_m])
        return fit.inertia_s + sensitivity @ shift - _matrix_to_vech(_steiner(m, c))

    centre = np.concatenate([[mass_kg], com_m])
    sigma = np.concatenate([[mass_sigma_kg], np.broadcast_to(com_sigma_m, (3,))])
    jacobian = np.empty((6, 4))
    for i in range(4):
        step = np.zeros(4)
        step[i] = max(float(sigma[i]), 1e-9)
        jacobian[:, i] = (inertia_c(centre + step) - inertia_c(centre - step)) / (2 * step[i])
    return jacobian @ np.diag(sigma ** 2) @ jacobian.T


def identify_dynamics(calibration: Calibration, record: MotionRecord, robot: URModel, *,
                      sensor_offset_m: np.ndarray | None = None, lag_s: float | None = None,
                      held_out_fraction: float = HELD_OUT_FRACTION) -> DynamicsResult:
    """Identify the tool's inertia (and mass / centre of mass where the motion improves on them) from ``record``.

    ``calibration`` is the static calibration (sensor rotation, biases, gravity, mass, centre of mass);
    ``sensor_offset_m`` the sensor origin in the flange frame (default: the calibration's, else zero). ``lag_s``
    None measures the lag (:func:`estimate_lag`). Raises InputError when the record is too short.
    """
    offset = sensor_offset_m if sensor_offset_m is not None else calibration.sensor_offset
    offset = np.zeros(3) if offset is None else np.asarray(offset, dtype=float)
    calibration = replace(calibration, sensor_offset=offset)
    dynamics = SensorDynamics.for_calibration(robot, calibration)
    gravity = gravity_vector(calibration)
    regressor = dynamics.regressor(record.q, record.qd, record.qdd, gravity)  # (M, 6, 10)
    bias = np.concatenate([calibration.force_bias, calibration.torque_bias])
    if lag_s is None:
        lag_s = estimate_lag(record, regressor, bias)
    keep, wrench = aligned_rows(record, lag_s)
    smooth = ~acceleration_steps(record.qdd)[keep]  # a box of sensor samples straddling a step of q̈: left out
    keep, wrench = keep[smooth], wrench[smooth]
    if keep.size < MIN_ROWS:
        raise InputError(f"motion record: only {keep.size} robot samples have sensor samples around them "
                         f"(need {MIN_ROWS}); record a longer motion")
    y = wrench - bias
    held = max(int(round(held_out_fraction * keep.size)), 1) if held_out_fraction > 0 else 0
    train = slice(0, keep.size - held)
    r_train, y_train = regressor[keep[train]], y[train]

    mass, com = calibration.mass_kg, np.asarray(calibration.center_of_mass)
    sigma = calibration.uncertainty
    given_mass_sigma, given_com_sigma = sigma.get("mass_kg"), sigma.get("center_of_mass_m")
    mass_sigma_static = float(np.ravel(given_mass_sigma)[0]) if given_mass_sigma is not None else 1e-6 * mass
    com_sigma_static = (np.asarray(given_com_sigma, dtype=float).reshape(3) if given_com_sigma is not None
                        else np.full(3, 1e-6))

    # weights per channel from a first unweighted ten-parameter fit
    x_first, *_ = np.linalg.lstsq(r_train.reshape(-1, 10), y_train.reshape(-1), rcond=None)
    weights = _channel_weights(y_train - r_train @ x_first)
    a_full = (r_train * weights[None, :, None]).reshape(-1, 10)
    b_full = (y_train * weights).reshape(-1)

    # 2. all ten with the static estimates as prior rows
    h = mass * com
    h_sigma = np.sqrt((com * mass_sigma_static) ** 2 + (mass * com_sigma_static) ** 2)
    prior_a = np.zeros((4, 10))
    prior_a[np.arange(4), np.arange(4)] = 1.0 / np.concatenate([[mass_sigma_static], h_sigma])
    prior_b = np.concatenate([[mass], h]) / np.concatenate([[mass_sigma_static], h_sigma])
    motion_only_cov = np.linalg.pinv(a_full.T @ a_full)
    _, fused_cov, _ = _weighted_lstsq(np.vstack([a_full, prior_a]), np.concatenate([b_full, prior_b]))
    x_fused, *_ = np.linalg.lstsq(np.vstack([a_full, prior_a]), np.concatenate([b_full, prior_b]), rcond=None)
    mass_sigma_motion = float(np.sqrt(max(motion_only_cov[0, 0], 0.0)))
    fused_mass, fused_h = float(x_fused[0]), x_fused[1:4]
    com_sigma_motion = np.sqrt(np.maximum(np.diag(motion_only_cov)[1:4], 0.0)) / max(fused_mass, 1e-12)
    mass_from_motion = bool(mass_sigma_motion < IMPROVEMENT_RATIO * mass_sigma_static)
    com_from_motion = bool(np.linalg.norm(com_sigma_motion) < IMPROVEMENT_RATIO * np.linalg.norm(com_sigma_static))
    if mass_from_motion:
        mass = fused_mass
    if com_from_motion:
        com = fused_h / fused_mass
    del fused_cov

    # 3. the inertia with m, c fixed, beside bias offsets and a residual lag; rows weighted by their noise; a
    #    block sandwich covariance and the 1σ of m, c propagated (ftacq.dynamics.inertia_fit)
    fixed = np.concatenate([[mass], mass * com])
    train_rows = keep[train]
    first_residual = y_train - r_train @ x_first
    row_weights = noise_weights(first_residual, np.linalg.norm(record.qd[train_rows], axis=1))
    train_time = np.asarray(record.robot_time_s, dtype=float)[train_rows]
    lag_column = np.gradient(r_train @ x_first, train_time, axis=0)
    fit = fit_inertia(r_train, y_train, fixed, row_weights, lag_column, train_time)
    inertia_s = fit.inertia_s
    a_inertia = fit.design[:, :, :6].reshape(-1, 6)
    b_inertia = (fit.target - fit.design[:, :, 6:] @ np.concatenate([fit.bias_offset, [fit.lag_correction_s]])
                 ).reshape(-1)
    norms = np.linalg.norm(a_inertia, axis=0)
    condition = float(np.linalg.cond(a_inertia / np.where(norms > 0, norms, 1.0)))
    parameters = np.concatenate([fixed, inertia_s])
    constrained = bool(np.linalg.eigvalsh(pseudo_inertia(parameters)).min() <= 0.0)
    if constrained:
        inertia_s = _consistent_inertia(a_inertia, b_inertia, inertia_s, mass, com)
        parameters = np.concatenate([fixed, inertia_s])
    inertia = _vech_to_matrix(inertia_s) - _steiner(mass, com)
    inertia = 0.5 * (inertia + inertia.T)
    mass_sigma = mass_sigma_motion if mass_from_motion else mass_sigma_static
    com_sigma = com_sigma_motion if com_from_motion else com_sigma_static
    covariance = fit.covariance + _fixed_covariance(fit, r_train, mass, com, mass_sigma, com_sigma)
    inertia_sigma = _vech_to_matrix(np.sqrt(np.maximum(np.diag(covariance), 0.0)))

    # 4. held-out motion: static and dynamic compensation error
    if held:
        test = slice(keep.size - held, keep.size)
        r_test, y_test = regressor[keep[test]], y[test]
        still = dynamics.regressor(record.q[keep[test]], np.zeros((held, 6)), np.zeros((held, 6)), gravity)
        error_dynamic = y_test - r_test @ parameters
        error_static = y_test - still @ parameters
    else:
        error_dynamic = error_static = np.zeros((1, 6))

    gravity_base = gravity / np.linalg.norm(gravity) * STANDARD_GRAVITY_M_S2 * mass
    result_uncertainty = dict(calibration.uncertainty)
    result_uncertainty["inertia_kg_m2"] = inertia_sigma.tolist()
    if mass_from_motion:
        result_uncertainty["mass_kg"] = mass_sigma_motion
    if com_from_motion:
        result_uncertainty["center_of_mass_m"] = com_sigma_motion.tolist()
    result = DynamicsResult(
        calibration=calibration, inertia=inertia, inertia_sigma=inertia_sigma, mass_from_motion=mass_from_motion,
        com_from_motion=com_from_motion, mass_sigma_static=mass_sigma_static, mass_sigma_motion=mass_sigma_motion,
        com_sigma_static=com_sigma_static, com_sigma_motion=com_sigma_motion, constrained=constrained,
        condition_number=condition, lag_s=float(lag_s), rows=keep.size - held, held_out_rows=held,
        held_out_rms_static=np.sqrt(np.mean(error_static ** 2, axis=0)),
        held_out_rms_dynamic=np.sqrt(np.mean(error_dynamic ** 2, axis=0)),
        held_out_max_static=np.abs(error_static).max(axis=0), held_out_max_dynamic=np.abs(error_dynamic).max(axis=0),
        servo_lag_s=None if record.metadata.get("servo_lag_s") is None else float(record.metadata["servo_lag_s"]),
        bias_offset=fit.bias_offset)
    metadata = dict(calibration.metadata)
    metadata["dynamics"] = result.summary()
    final = replace(calibration, gravity_base=gravity_base, center_of_mass=com, inertia=inertia, sensor_offset=offset,
                    uncertainty=result_uncertainty, metadata=metadata)
    return replace(result, calibration=final)
