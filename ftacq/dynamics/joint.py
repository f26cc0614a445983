"""Every calibration parameter from one recorded motion: sensor rotation, force and torque biases, mass, centre of
mass, base tilt and inertia, with their 1σ and the conditioning (``ftacq calibrate --quick``, docs/quick.md).

Model (:mod:`ftacq.dynamics.model`, docs/dynamics.md), written in the frame O at the sensor origin with the
flange's orientation, so that the robot's motion is computed once and the sensor rotation acts afterwards:

    wrench_S = blkdiag(R, R) · (D(q, q̇, q̈) π_O + G(g_O) π_O) + bias            (1)
    D = −Y(v_O, a_O)                  (Pinocchio's body regressor, gravity left out; Y is linear in a)
    G(g) π = [m g ; h × g]            (gravity as an upward acceleration: −Y(0, −g) π)
    g_O = base_R_Oᵀ · g₀ · down(tilt)  (g₀ standard gravity; ‖gravity_base‖ = m g₀ as in the static model)

R = ``sensor_R_flange`` (the calibration's ``sensor_rotation``), π_O = [m, h = m c, I] about the sensor origin in
O. At rest (1) is the paper's static model (eqs 10-11: F = R m g_O, T = c_S × F). (1) is linear in
x = (π_O, bias) (16 numbers) for a given θ = (rotation increment, tilt increment) (5 numbers); the fit is
Gauss-Newton over all 21 with the analytic Jacobian (:meth:`JointModel.design`), x started by weighted linear
least squares at the start θ; it converges in a few iterations. The start comes from a quasi-static fit (the
inertial wrench is < 10 % of the weight at the CELL.toml speeds): F_S ≈ M g_O + b_F by linear least squares, R
the polar factor of M (as LROM/Wahba do at rest), the tilt at the nominal mount.

Weights (what limits the accuracy when motion and holds mix): the sensor's noise grows with the speed of the
arm (vibration, a real effect the simulated sensor shows too) and a timing error turns the inertial wrench into
residual, so rows are grouped by joint speed (still, then quantiles of the moving rows) and each group and channel
is weighted by the inverse of its own residual scatter, re-estimated once after the first fit. The still rows (the
holds) then carry the biases and the mass as they should; the moving rows carry the rest.

The lag between the streams is a 22nd parameter of the fit: the sensor row aligned at t + lag₀ reads the state at
t + lag₀ − lag_true, modelled as P − Ṗ δ (Ṗ the prediction's time derivative). The samples are re-aligned only
when δ exceeds :data:`REALIGN_S`: a box average moves in steps of the sensor's period, and a search over
re-aligned shifts (as :func:`ftacq.dynamics.identify.estimate_lag`) is biased by how many samples each box holds. Measuring the lag from the motion was what limited the accuracy: a lag error of 1 ms turns
gravity in the sensor frame by ω·1 ms while the wrist moves, 0.25 mrad of rotation and a few mdeg of tilt on the
simulated cell, and the fit's cost barely sees it; with the lag fitted jointly, its uncertainty enters the
rotation's and the tilt's 1σ. 1σ: the full Jacobian at the
optimum, (JᵀJ)⁻¹ scaled by χ²/dof, each parameter's σ enlarged where a block (cluster-robust) sandwich shows
errors correlated over consecutive rows, propagated to every reported parameter by central differences. The condition number is that of J with unit-norm
columns. Noise-free simulated motion recovers every parameter to ≤ 1e-6 relative (tests/test_quick_identify.py).

Just over 500 lines: the model, its Jacobian, the lag and the covariance share one state (the model re-centred at
each step, the rows' weights and stamp offsets); split apart, each piece would have to carry all of it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Callable

import numpy as np

from ftacq import STANDARD_GRAVITY_M_S2, __version__
from ftacq.calibration import Calibration
from ftacq.dynamics.drift_terms import drift_columns
from ftacq.dynamics.identify import MIN_ROWS, MotionRecord, aligned_rows
from ftacq.dynamics.model import SensorDynamics
from ftacq.dynamics.timing import box_average
from ftacq.errors import InputError
from ftacq.identification.tilt import tilt_deg, tilt_jacobian_deg
from ftacq.kinematics import URModel
from ftacq.so3 import rotation_from_rotvec

BLOCK_ROWS = 50
"""Rows per block of the cluster-robust covariance (0.1 s at 500 Hz: a stream's stall or a burst stays inside)."""
SPEED_BINS = 4
"""Moving rows are split into this many joint-speed quantiles, each weighted by its own residual scatter."""
STILL_SPEED_RAD_S = 0.01
"""Rows whose fastest joint is below this speed count as still (the holds)."""
NONLINEAR = 5
"""θ: rotation increment (3, sensor frame, rad) and tilt increment (2, rad, about two axes ⟂ the start's down)."""
LINEAR = 16
"""x: π_O (10: m, h, I_O in Pinocchio's order xx, xy, yy, xz, yz, zz) and the biases (6)."""
ACCELERATION_STEP_RAD_S2 = 0.1
"""A change of a joint's acceleration between two robot samples beyond this is a step (rows around it are not
fitted, :func:`_near_acceleration_steps`)."""
REALIGN_S = 0.002
"""A fitted lag shift beyond this re-aligns the sensor samples (the shift is modelled to first order), s ..."""
REALIGNMENTS = 3
"""... at most this many times."""
LAG_TOLERANCE_S = 1e-9
"""Gauss-Newton's lag step below which it has converged, s."""
MAX_ITERATIONS = 20
MAX_HALVINGS = 8
COST_TOLERANCE = 1e-12
"""Gauss-Newton has converged when a step lowers the weighted cost by less than this fraction ..."""
THETA_TOLERANCE_RAD = 1e-11
"""... or when no angle moves more than this (and no linear parameter by this fraction)."""
_STEP = 1e-6
"""Central-difference step of θ (rad) and of the propagated outputs (relative)."""
_FLOOR = 1e-12


@dataclass(frozen=True)
class JointResult:
    """The joint identification's outcome (SI units).

    Attributes:
        calibration: rotation, biases, gravity_base, centre of mass, inertia, sensor offset; ``uncertainty`` with
            the full run's keys plus ``inertia_kg_m2``; ``metadata['quick']`` the figures below.
        covariance: (21, 21) of (θ, x) at the optimum; sigma: 1σ of each reported parameter by file key.
        condition_number: of the weighted Jacobian with unit-norm columns. lag_s: sensor behind robot, s.
        rows: robot rows fitted. residual_rms: (6,) weighted-fit residual RMS [N, N·m] (all rows).
        still_noise, moving_noise: (6,) residual scatter of the still and the fastest moving rows.
    """

    calibration: Calibration
    covariance: np.ndarray
    sigma: dict[str, Any]
    condition_number: float
    lag_s: float
    rows: int
    residual_rms: np.ndarray
    still_noise: np.ndarray
    moving_noise: np.ndarray
    iterations: int
    parameters: Callable[[np.ndarray], Calibration] = field(repr=False, compare=False, default=None)  # type: ignore[assignment]
    """Calibration at a (21,) vector of (θ, x) (the covariance's coordinates); for the verdict's propagation."""
    optimum: np.ndarray = field(default_factory=lambda: np.zeros(NONLINEAR + LINEAR))

    def summary(self) -> dict[str, Any]:
        return {"lag_ms": 1e3 * self.lag_s, "rows": self.rows, "condition_number": self.condition_number,
                "residual_rms": self.residual_rms.tolist(), "still_noise": self.still_noise.tolist(),
                "moving_noise": self.moving_noise.tolist(), "iterations": self.iterations}


def _skew(v: np.ndarray) -> np.ndarray:
    """(…, 3) → (…, 3, 3) with skew(a) b = a × b."""
    x, y, z = np.moveaxis(v, -1, 0)
    zero = np.zeros_like(x)
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)


def _tangent_basis(down: np.ndarray) -> np.ndarray:
    """Two unit vectors (2, 3) perpendicular to ``down`` and to each other."""
    helper = np.eye(3)[int(np.argmin(np.abs(down)))]
    e1 = np.cross(down, helper)
    e1 /= np.linalg.norm(e1)
    return np.vstack([e1, np.cross(down, e1)])


def _vech_to_matrix(v: np.ndarray) -> np.ndarray:
    xx, xy, yy, xz, yz, zz = v
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


@dataclass(frozen=True)
class RobotPart:
    """What equation (1) takes from the arm alone, over a motion's rows: the frame O's orientation base_R_o (N, 3, 3)
    and the motion's regressor D (N, 6, 10) in frame O (no gravity); one pass of Pinocchio over the rows, shared by
    the fits of one record (:func:`ftacq.dynamics.drift_terms.identify_with_drift` fits twice)."""

    base_R_o: np.ndarray
    motion_part: np.ndarray

    @classmethod
    def of(cls, robot: URModel, sensor_offset_m: np.ndarray, q: np.ndarray, qd: np.ndarray,
           qdd: np.ndarray) -> "RobotPart":
        dynamics = SensorDynamics(robot, np.eye(3), sensor_offset_m)
        motion = dynamics.motion(q, qd, qdd)  # the orientation depends on q alone
        return cls(motion.base_R_sensor, dynamics.regressor(q, qd, qdd, np.zeros(3), motion=motion))


class JointModel:
    """Equation (1) over a motion's rows: the robot's part computed once, θ and x applied per call.

    Args:
        robot: the arm. sensor_offset_m: sensor origin in the flange frame. q, qd, qdd: (N, 6) joint states.
        rotation0: start ``sensor_R_flange``; down0: start unit gravity direction in the base frame.
    """

    def __init__(self, robot: URModel, sensor_offset_m: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                 rotation0: np.ndarray, down0: np.ndarray, robot_part: "RobotPart | None" = None) -> None:
        if robot_part is None:
            robot_part = RobotPart.of(robot, sensor_offset_m, q, qd, qdd)
        self.base_R_o = robot_part.base_R_o  # (N, 3, 3)
        self.motion_part = robot_part.motion_part  # D (N, 6, 10), frame O
        self.offset = np.asarray(sensor_offset_m, dtype=float)
        self.rotation0 = np.asarray(rotation0, dtype=float)
        self.down0 = np.asarray(down0, dtype=float) / np.linalg.norm(down0)
        self.tangent = _tangent_basis(self.down0)
        self.drift_time_h: np.ndarray | None = None  # per robot row: a linear bias drift's 6 columns (drift_terms.py)

    def rotation(self, theta: np.ndarray) -> np.ndarray:
        """sensor_R_flange = exp([δr]×) R₀ (the increment in the sensor frame, as the full run's covariance)."""
        return rotation_from_rotvec(theta[:3]) @ self.rotation0

    def down(self, theta: np.ndarray) -> np.ndarray:
        return rotation_from_rotvec(theta[3:5] @ self.tangent) @ self.down0

    def regressor(self, theta: np.ndarray, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """A (N, 6, 16): wrench_S = A x, x = (π_O, bias)."""
        gravity_o = self.base_R_o[rows].transpose(0, 2, 1) @ (STANDARD_GRAVITY_M_S2 * self.down(theta))
        a_o = self.motion_part[rows]
        if isinstance(rows, slice):  # a view: the gravity terms are added below (an index array already copies)
            a_o = a_o.copy()
        a_o[:, :3, 0] += gravity_o
        a_o[:, 3:, 1:4] -= _skew(gravity_o)
        r = self.rotation(theta)
        extra = drift_columns(self.drift_time_h, rows, a_o.shape[0])
        out = np.empty((a_o.shape[0], 6, LINEAR + extra.shape[2]))
        np.matmul(r, a_o[:, :3], out=out[:, :3, :10])
        np.matmul(r, a_o[:, 3:], out=out[:, 3:, :10])
        out[:, :, 10:LINEAR] = np.eye(6)
        out[:, :, LINEAR:] = extra
        return out

    def predict(self, theta: np.ndarray, x: np.ndarray, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """(N, 6) A x without building A (:meth:`regressor`; the same sums, a tenth of the work: the fit's cost is
        evaluated at every trial step)."""
        gravity_o = self.base_R_o[rows].transpose(0, 2, 1) @ (STANDARD_GRAVITY_M_S2 * self.down(theta))
        motion = self.motion_part[rows]
        y_o = (motion.reshape(-1, motion.shape[2]) @ x[:10]).reshape(-1, 6)
        y_o[:, :3] += gravity_o * x[0]
        y_o[:, 3:] -= np.cross(gravity_o, x[1:4])
        r = self.rotation(theta)
        out = np.empty_like(y_o)
        np.matmul(y_o[:, :3], r.T, out=out[:, :3])
        np.matmul(y_o[:, 3:], r.T, out=out[:, 3:])
        out += x[10:LINEAR]
        if self.drift_time_h is not None and x.size > LINEAR:
            out += np.asarray(self.drift_time_h, dtype=float)[rows][:, None] * x[LINEAR:LINEAR + 6]
        return out

    def recentre(self, theta: np.ndarray) -> None:
        """Move the start to θ: afterwards θ = 0 is that point (rotation and down as increments of it)."""
        self.rotation0, self.down0 = self.rotation(theta), self.down(theta)
        self.tangent = _tangent_basis(self.down0)

    def moved(self, theta: np.ndarray) -> "JointModel":
        """A shallow copy re-centred at θ (the robot's part shared)."""
        other = object.__new__(JointModel)
        other.__dict__.update(self.__dict__)
        other.recentre(theta)
        return other

    def design(self, x: np.ndarray, rows: np.ndarray | slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """(A (N, 6, 16), J (N, 6, 21)) at θ = 0: the regressor and the Jacobian of A x in (θ, x).

        Rotation increment (left, sensor frame): ∂(exp([δ]×) R u)/∂δ = −[R u]× for the force and the torque u.
        Tilt increment t_i about the tangent e_i: ġ_O = base_R_Oᵀ g₀ (e_i × down), and A x moves by
        R [m ġ_O; h × ġ_O]."""
        a = self.regressor(np.zeros(NONLINEAR), rows)
        wrench = a[:, :, :10] @ x[:10]  # R y_O (N, 6)
        jacobian = np.empty((a.shape[0], 6, NONLINEAR + a.shape[2]))
        jacobian[:, :3, :3] = -_skew(wrench[:, :3])
        jacobian[:, 3:, :3] = -_skew(wrench[:, 3:])
        r = self.rotation0
        for i in range(2):
            turn = np.cross(self.tangent[i], self.down0) * STANDARD_GRAVITY_M_S2
            g_dot = self.base_R_o[rows].transpose(0, 2, 1) @ turn  # (N, 3)
            jacobian[:, :3, 3 + i] = (x[0] * g_dot) @ r.T
            jacobian[:, 3:, 3 + i] = np.cross(x[1:4], g_dot) @ r.T
        jacobian[:, :, NONLINEAR:] = a
        return a, jacobian

    def calibration(self, vector: np.ndarray, uncertainty: dict | None = None,
                    metadata: dict | None = None) -> Calibration:
        """The calibration of (θ, x) (21,): inertia about the centre of mass, sensor frame."""
        theta, x = vector[:NONLINEAR], vector[NONLINEAR:]
        r = self.rotation(theta)
        mass = float(x[0])
        com_o = x[1:4] / mass
        inertia_o = _vech_to_matrix(x[4:10]) - mass * (com_o @ com_o * np.eye(3) - np.outer(com_o, com_o))
        return Calibration(sensor_rotation=r, force_bias=x[10:13], torque_bias=x[13:16],
                           gravity_base=mass * STANDARD_GRAVITY_M_S2 * self.down(theta), center_of_mass=r @ com_o,
                           uncertainty=uncertainty or {}, metadata=metadata or {}, sensor_offset=self.offset,
                           inertia=r @ (0.5 * (inertia_o + inertia_o.T)) @ r.T)


def _solve_linear(a: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least squares of y ≈ A x (rows (N, 6), weights (N, 6)) by scaled normal equations."""
    aw = (a * w[:, :, None]).reshape(-1, a.shape[2])
    yw = (y * w).reshape(-1)
    scale = np.linalg.norm(aw, axis=0)
    scale[scale == 0] = 1.0
    aw /= scale
    return np.linalg.solve(aw.T @ aw, aw.T @ yw) / scale


def _start(model: "JointModel | _Rows", y: np.ndarray) -> np.ndarray:
    """Quasi-static start (module docstring): rotation by the polar factor, tilt at the nominal mount, x by LS."""
    gravity_o = np.einsum("nji,j->ni", model.base_R_o, STANDARD_GRAVITY_M_S2 * model.down0)
    design = np.hstack([gravity_o, np.ones((len(y), 1))])
    solution, *_ = np.linalg.lstsq(design, y[:, :3], rcond=None)
    m_matrix = solution[:3].T  # F ≈ M g_O + b, M = m R
    u, s, vt = np.linalg.svd(m_matrix)
    rotation = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    model.rotation0 = rotation
    return np.zeros(NONLINEAR)


def _row_weights(residual: np.ndarray, speed: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weights (N, 6): 1 / the residual scatter of the row's speed group and channel; and the still and the
    fastest group's scatter (6,) each."""
    groups = np.zeros(len(speed), dtype=int)
    moving = speed >= STILL_SPEED_RAD_S
    if moving.any():
        edges = np.quantile(speed[moving], np.linspace(0, 1, SPEED_BINS + 1)[1:-1])
        groups[moving] = 1 + np.searchsorted(edges, speed[moving], side="right")
    scatter = np.zeros((SPEED_BINS + 1, 6))
    overall = np.sqrt(np.mean(residual ** 2, axis=0))
    for g in range(SPEED_BINS + 1):
        members = groups == g
        scatter[g] = np.sqrt(np.mean(residual[members] ** 2, axis=0)) if members.sum() > 10 else overall
    scatter = np.maximum(scatter, _FLOOR * max(float(overall.max()), 1.0))
    return 1.0 / scatter[groups], scatter[0], scatter[-1]


def identify_joint(record: MotionRecord, robot: URModel, sensor_offset_m: np.ndarray, nominal_down: np.ndarray, *,
                   rows: np.ndarray | None = None, lag_s: float | None = None,
                   rotation_start: np.ndarray | None = None, metadata: dict | None = None,
                   drift_time_h: np.ndarray | None = None, robot_part: RobotPart | None = None) -> JointResult:
    """Identify every parameter of ``record`` (module docstring).

    ``nominal_down``: the mount's unit gravity direction in the base frame (the start of the tilt).
    ``rows``: a boolean mask over the robot samples to fit (default all; the stage leaves the validation holds
    out). ``lag_s`` None measures it. ``rotation_start`` skips the quasi-static start of the rotation.
    ``drift_time_h`` (M,) per robot sample: a linear bias drift is fitted too (:mod:`ftacq.dynamics.drift_terms`).
    ``robot_part``: :meth:`RobotPart.of` this record's states and ``sensor_offset_m``, when the caller has it.
    Raises InputError when the record is too short or does not excite every parameter.
    """
    if len(record.robot_time_s) < MIN_ROWS:
        raise InputError(f"motion record: only {len(record.robot_time_s)} robot samples (need {MIN_ROWS})")
    mask = np.ones(len(record.robot_time_s), dtype=bool) if rows is None else np.asarray(rows, dtype=bool)
    model = JointModel(robot, sensor_offset_m, record.q, record.qd, record.qdd,
                       np.eye(3) if rotation_start is None else rotation_start, nominal_down, robot_part)
    model.drift_time_h = drift_time_h
    mask = mask & ~_near_acceleration_steps(record.qdd)

    def align(lag: float) -> tuple[np.ndarray, np.ndarray]:
        keep, wrench = aligned_rows(record, lag)
        inside = mask[keep]
        return keep[inside], wrench[inside]

    def timing(lag: float, rows: np.ndarray) -> _Timing | None:
        if not fit_lag:
            return None
        at = record.robot_time_s[rows] + lag
        stamps, _ = box_average(record.sensor_time_s, record.sensor_time_s, at, record.robot_period_s)
        return _Timing(record.robot_time_s[rows], stamps[:, 0] - at)

    keep, wrench = align(0.0 if lag_s is None else lag_s)
    if keep.size < MIN_ROWS:
        raise InputError(f"motion record: only {keep.size} robot samples have sensor samples around them")
    if rotation_start is None:
        _start(_Rows(model, keep), wrench)
    speed = np.max(np.abs(record.qd), axis=1)
    theta = np.zeros(NONLINEAR)
    fit_lag = lag_s is None
    lag_start = 0.0 if lag_s is None else float(lag_s)
    weights = np.ones((keep.size, 6)) / np.maximum(np.std(wrench, axis=0), _FLOOR)
    x = _solve_linear(model.regressor(theta, keep), wrench, weights)
    times = timing(lag_start, keep)
    shift, iterations = 0.0, 0
    for stage in range(REALIGNMENTS + 2):
        # a fit; the lag's shift beyond REALIGN_S re-aligns the samples; re-weight by speed group once
        x, shift, used = _gauss_newton(model, keep, wrench, weights, x, times, shift)
        iterations += used
        if fit_lag and abs(shift) > REALIGN_S and stage < REALIGNMENTS:
            lag_start, shift = lag_start + shift, 0.0
            keep, wrench = align(lag_start)
            times = timing(lag_start, keep)
        weights, still_noise, moving_noise = _row_weights(wrench - _predict(model, keep, x, times, shift),
                                                          speed[keep])
    x, shift, used = _gauss_newton(model, keep, wrench, weights, x, times, shift)
    iterations += used
    lag_s = lag_start + shift
    optimum = np.concatenate([theta, x])  # θ = 0: the model is centred on the optimum

    # 1σ: (JᵀJ)⁻¹ χ²/dof of the weighted Jacobian at the optimum (its columns scaled to unit norm), the lag
    # included when it was fitted (it is correlated with the rotation and the tilt: a late sensor turns gravity)
    jacobian = _jacobian(model, keep, x, times, shift)
    residual = wrench - _predict(model, keep, x, times, shift)
    columns = jacobian.shape[2]
    jacobian = (jacobian * weights[:, :, None]).reshape(-1, columns)
    norms = np.linalg.norm(jacobian, axis=0)
    norms[norms == 0] = 1.0
    information = (jacobian.T @ jacobian) / np.outer(norms, norms)
    eigen = np.linalg.eigvalsh(information)
    condition = float(np.sqrt(eigen[-1] / max(eigen[0], 1e-300)))
    dof = max(jacobian.shape[0] - jacobian.shape[1], 1)
    chi2 = float(np.sum((residual * weights) ** 2)) / dof
    inverse = np.linalg.pinv(information) / np.outer(norms, norms)
    full_covariance = inverse * chi2
    # errors correlated over consecutive rows (a late or stalled stream, vibration) make (JᵀJ)⁻¹ χ² too small:
    # the block (cluster-robust) sandwich H⁻¹ (Σ_b g_b g_bᵀ) H⁻¹, g_b the score of a block of rows (Liang & Zeger
    # 1986), says by how much; each parameter's σ grows by that factor where it is above 1 (the correlations kept)
    scores = np.einsum("nak,na->nk", jacobian.reshape(keep.size, 6, columns), residual * weights)
    blocks = np.add.reduceat(scores, np.arange(0, keep.size, BLOCK_ROWS), axis=0)
    robust = inverse @ (blocks.T @ blocks) @ inverse
    inflation = np.sqrt(np.maximum(np.diag(robust) / np.maximum(np.diag(full_covariance), 1e-300), 1.0))
    full_covariance = full_covariance * np.outer(inflation, inflation)
    covariance = full_covariance[:NONLINEAR + x.size, :NONLINEAR + x.size]
    lag_sigma = float(np.sqrt(max(full_covariance[-1, -1], 0.0))) if fit_lag else 0.0
    sigma = _propagate(model, optimum, covariance)
    summary = {"method": "quick (joint fit of the motion)", "lag_ms": 1e3 * float(lag_s),
               "lag_sigma_ms": 1e3 * lag_sigma, "rows": int(keep.size),
               "servo_lag_ms": None if record.metadata.get("servo_lag_s") is None
               else 1e3 * float(record.metadata["servo_lag_s"]),
               "sigma_inflation_max": float(inflation.max()),
               "condition_number": condition, "chi2_per_dof": chi2,
               "residual_rms": np.sqrt(np.mean(residual ** 2, axis=0)).tolist(),
               "still_noise": still_noise.tolist(), "moving_noise": moving_noise.tolist()}
    meta = {"software": f"ftacq {__version__}", "method": "quick", **(metadata or {}), "quick": summary}
    calibration = model.calibration(optimum, uncertainty=sigma, metadata=meta)
    return JointResult(calibration=calibration, covariance=covariance, sigma=sigma, condition_number=condition,
                       lag_s=float(lag_s), rows=int(keep.size), residual_rms=np.sqrt(np.mean(residual ** 2, axis=0)),
                       still_noise=still_noise, moving_noise=moving_noise, iterations=iterations,
                       parameters=model.calibration, optimum=optimum)


@dataclass(frozen=True)
class _Timing:
    """The fitted rows' robot times (N,) s and, per row, how much later than its aligned time (robot time + lag₀)
    the sensor samples averaged there were stamped on average (N,) s (half a sensor period at most: the box
    [t − T/2, t + T/2) holds whole samples)."""

    time_s: np.ndarray
    offset_s: np.ndarray

    @cached_property
    def _weights(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """numpy.gradient's coefficients along these times (second order inside, first order at both ends), once:
        the fit differentiates arrays of (N, 6, 22) a few dozen times over the same rows."""
        dx = np.diff(self.time_s)
        previous, following = np.empty(len(self.time_s)), np.empty(len(self.time_s))
        current = np.empty(len(self.time_s))
        d1, d2 = dx[:-1], dx[1:]
        previous[1:-1] = -d2 / (d1 * (d1 + d2))
        current[1:-1] = (d2 - d1) / (d1 * d2)
        following[1:-1] = d1 / (d2 * (d1 + d2))
        previous[0], current[0], following[0] = 0.0, -1.0 / dx[0], 1.0 / dx[0]
        previous[-1], current[-1], following[-1] = -1.0 / dx[-1], 1.0 / dx[-1], 0.0
        return previous, current, following

    def derivative(self, values: np.ndarray) -> np.ndarray:
        """d values / dt along axis 0 (what ``np.gradient(values, time_s, axis=0)`` gives, without its
        temporaries)."""
        return self.shifted(values, None)

    def shifted(self, values: np.ndarray, shift: float | None) -> np.ndarray:
        """values − (d values / dt) (shift − offset_s) along axis 0, in three passes over ``values`` (the
        Jacobian of (N, 6, 22) is the fit's largest array); ``shift`` None: the derivative alone."""
        previous, current, following = self._weights
        if shift is None:
            scale, base = np.ones(len(self.time_s)), 0.0
        else:
            scale, base = -(shift - self.offset_s), 1.0
        shape = (-1,) + (1,) * (values.ndim - 1)
        out = values * (base + current * scale).reshape(shape)
        buffer = np.empty_like(values[1:])
        np.multiply(values[:-1], (previous[1:] * scale[1:]).reshape(shape), out=buffer)
        out[1:] += buffer
        np.multiply(values[1:], (following[:-1] * scale[:-1]).reshape(shape), out=buffer)
        out[:-1] += buffer
        return out


def _near_acceleration_steps(qdd: np.ndarray) -> np.ndarray:
    """(M,) True within two robot samples of a step of the joint acceleration (a moveJ's profile switching): there
    the sensor's box average and the model's instantaneous state differ by the step itself, which no lag or
    parameter explains."""
    step = np.zeros(len(qdd), dtype=bool)
    if len(qdd) > 1:
        jumps = np.flatnonzero(np.max(np.abs(np.diff(qdd, axis=0)), axis=1) > ACCELERATION_STEP_RAD_S2)
        for offset in range(-1, 3):
            index = jumps + offset
            step[index[(index >= 0) & (index < len(qdd))]] = True
    return step


def _predict(model: JointModel, rows: np.ndarray, x: np.ndarray, timing: _Timing | None,
             shift: float) -> np.ndarray:
    """The model (1) at the rows as the sensor samples averaged there see it: P − Ṗ (δ − o) with δ = lag − lag₀ and
    o the row's stamp offset (:class:`_Timing`); Ṗ by central differences along the robot's time (first order: δ
    stays within :data:`REALIGN_S`). ``timing`` None: P."""
    prediction = model.predict(np.zeros(NONLINEAR), x, rows)
    if timing is None:
        return prediction
    return timing.shifted(prediction, shift)


def _jacobian(model: JointModel, rows: np.ndarray, x: np.ndarray, timing: _Timing | None,
              shift: float = 0.0) -> np.ndarray:
    """(N, 6, 21 or 22): the Jacobian of :func:`_predict`: :meth:`JointModel.design`'s, shifted like the prediction
    (J − J̇ (δ − o)), and the lag's column −Ṗ when ``timing`` is given.

    The lag: the sensor row aligned at t + lag₀ reads the state at t + lag₀ + o − lag_true, so a true lag larger
    by δ shows the prediction P δ later: −Ṗ δ. Fitting δ in the model instead of re-aligning the samples keeps the
    cost smooth in the lag (a re-aligned box average moves in steps of the sensor's period)."""
    a, jacobian = model.design(x, rows)
    if timing is None:
        return jacobian
    jacobian = timing.shifted(jacobian, shift)
    lag = -timing.derivative(a @ x)
    return np.concatenate([jacobian, lag[:, :, None]], axis=2)


def _gauss_newton(model: JointModel, rows: np.ndarray, wrench: np.ndarray, weights: np.ndarray,
                  x: np.ndarray, times: _Timing | None, shift: float) -> tuple[np.ndarray, float, int]:
    """Gauss-Newton over all 21 parameters (and the lag's ``shift`` when ``times`` is given) with the analytic
    Jacobian (:func:`_jacobian`), the model re-centred on each step (θ stays 0); a step that raises the cost is
    halved. Stops when no angle moves more than :data:`THETA_TOLERANCE_RAD`, no linear parameter by more than that
    fraction and the lag by less than :data:`LAG_TOLERANCE_S`, or after :data:`MAX_ITERATIONS`.
    Returns (x, shift, iterations)."""
    def cost(m: JointModel, values: np.ndarray, lag: float) -> float:
        return float(np.sum(((wrench - _predict(m, rows, values, times, lag)) * weights) ** 2))

    current = cost(model, x, shift)
    for iteration in range(1, MAX_ITERATIONS + 1):
        jacobian = _jacobian(model, rows, x, times, shift)
        jw = (jacobian * weights[:, :, None]).reshape(-1, jacobian.shape[2])
        rw = ((wrench - _predict(model, rows, x, times, shift)) * weights).reshape(-1)
        scale = np.maximum(np.linalg.norm(jw, axis=0), _FLOOR)
        scaled = jw / scale
        delta = np.linalg.solve(scaled.T @ scaled, scaled.T @ rw) / scale
        if times is None:
            delta = np.append(delta, 0.0)
        for _ in range(MAX_HALVINGS):
            trial = cost(model.moved(delta[:NONLINEAR]), x + delta[NONLINEAR:-1], shift + delta[-1])
            if trial <= current:
                break
            delta *= 0.5
        else:
            return x, shift, iteration  # no step lowers the cost: at the optimum within rounding
        model.recentre(delta[:NONLINEAR])
        x, shift = x + delta[NONLINEAR:-1], shift + float(delta[-1])
        previous, current = current, trial
        if previous - current <= COST_TOLERANCE * previous:
            return x, shift, iteration
        if (np.max(np.abs(delta[:NONLINEAR])) < THETA_TOLERANCE_RAD and abs(delta[-1]) < LAG_TOLERANCE_S
                and np.all(np.abs(delta[NONLINEAR:-1]) <= THETA_TOLERANCE_RAD * (np.abs(x) + 1e-9))):
            return x, shift, iteration
    return x, shift, MAX_ITERATIONS


class _Rows:
    """A :class:`JointModel` restricted to some rows (the fitted ones)."""

    def __init__(self, model: JointModel, rows: np.ndarray) -> None:
        self.model, self.rows = model, rows
        self.base_R_o = model.base_R_o[rows]
        self.down0 = model.down0

    @property
    def rotation0(self) -> np.ndarray:
        return self.model.rotation0

    @rotation0.setter
    def rotation0(self, value: np.ndarray) -> None:
        self.model.rotation0 = value

    def regressor(self, theta: np.ndarray) -> np.ndarray:
        return self.model.regressor(theta, self.rows)


def reported_vector(calibration: Calibration, reference_rotation: np.ndarray) -> np.ndarray:
    """Every reported parameter as one vector (for the 1σ propagation): rotation increment against
    ``reference_rotation`` (sensor frame, rad), biases, gravity_base, mass, centre of mass, tilt (deg), inertia."""
    from ftacq.so3 import rotvec_from_rotation

    return np.concatenate([rotvec_from_rotation(calibration.sensor_rotation @ reference_rotation.T),
                           calibration.force_bias, calibration.torque_bias, calibration.gravity_base,
                           [calibration.mass_kg], calibration.center_of_mass, tilt_deg(calibration.gravity_base),
                           np.ravel(calibration.inertia if calibration.inertia is not None else np.zeros((3, 3)))])


REPORTED = (("sensor_rotation_rad", 0, 3), ("force_bias", 3, 6), ("torque_bias", 6, 9), ("gravity_base", 9, 12),
            ("mass_kg", 12, 13), ("center_of_mass_m", 13, 16), ("base_tilt_deg", 16, 18), ("inertia_kg_m2", 18, 27))
"""Slices of :func:`reported_vector`, keyed as the calibration file's ``uncertainty``."""


def _propagate(model: JointModel, optimum: np.ndarray, covariance: np.ndarray) -> dict[str, Any]:
    """1σ of every reported parameter: central differences of :func:`reported_vector` against (θ, x)."""
    reference = model.calibration(optimum).sensor_rotation
    columns = []
    for i in range(optimum.size):
        step = _STEP * max(abs(optimum[i]), 1e-3)
        plus, minus = optimum.copy(), optimum.copy()
        plus[i] += step
        minus[i] -= step
        columns.append((reported_vector(model.calibration(plus), reference)
                        - reported_vector(model.calibration(minus), reference)) / (2 * step))
    jac = np.stack(columns, axis=1)
    variance = np.einsum("ij,jk,ik->i", jac, covariance, jac)
    sigma = np.sqrt(np.maximum(variance, 0.0))
    out: dict[str, Any] = {}
    for name, lo, hi in REPORTED:
        value = sigma[lo:hi]
        out[name] = float(value[0]) if name == "mass_kg" else (
            value.reshape(3, 3).tolist() if name == "inertia_kg_m2" else value.tolist())
    g_cov = (jac[9:12] @ covariance @ jac[9:12].T)
    tilt_jac = tilt_jacobian_deg(model.calibration(optimum).gravity_base)
    out["base_tilt_deg"] = np.sqrt(np.maximum(np.diag(tilt_jac @ g_cov @ tilt_jac.T), 0.0)).tolist()
    return out


__all__ = ["JointModel", "JointResult", "identify_joint", "reported_vector", "REPORTED"]
