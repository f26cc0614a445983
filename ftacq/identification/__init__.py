"""Identify a calibration from a pose record: closed form (paper), then joint robust refinement (ftacq).

Steps (Yu, Shi & Lou 2021, Algorithm 1, with method.md's corrections):

1. Refuse degenerate pose sets (diagnostics.check_pose_set).
2. Find the special orientations (within ``special_tolerance_deg`` of a cube rotation). With all 24,
   gravity_base comes from SROM on them (eqs 14-23, the paper's best case 8); otherwise LROM on all
   poses (eqs 24-34, det > 0 sign rule). ``method`` forces either.
3. Sensor rotation and force bias by Wahba / Umeyama on all poses (eqs 35-42); centre of mass and torque
   bias by least squares (eqs 43-45). This closed form is repeated with robust pose weights when a pose
   looks disturbed.
4. Refinement (unless ``refine=False``): Levenberg-Marquardt over all 15 parameters, rotation on SO(3),
   each pose weighted by its noise (measured std/√count, scatter estimated from the residuals and, when the
   residuals show it, the robot's orientation error, which couples the channels: pose_error.py), inside an
   iteratively re-weighted loop that down-weights and names disturbed poses.
   With ``drift="linear"`` (or "auto" and a large, significant residual trend: trend.py) the refinement also
   fits a linear drift of both biases over the recording (refine.py ``bias_rate``); the biases are then those
   at the end of the recording.
5. 1σ of every parameter from (JᵀWJ)⁻¹ at the optimum; mass and base tilt (corrected eqs 46-48) with
   their 1σ, the tilt relative to a named mount; conditioning warnings.
6. With ``sensor_check``: the sensor's force gain/cross-talk matrix fitted beside (sensor_gain.py); it leaves the
   calibration as it is, and "auto" then decides on the drift from one fit of the drift and the gains together.

One function per step (``_prepare``, ``_robust_closed_form``, ``_refine``, ``_result``); over 500 lines because
steps 4-5 share one state (weights, noise model, parameters, their covariance) through one re-weighted loop; the
pieces that stand alone live in the sibling modules.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from ftacq import STANDARD_GRAVITY_M_S2, __version__
from ftacq.calfile import MODEL_CORRELATION_KEY, MODEL_CORRELATION_PARAMETERS
from ftacq.calibration import Calibration
from ftacq.channels import WRENCH_COLUMNS
from ftacq.errors import IdentificationError
from ftacq.fit_options import DRIFT_MODELS, METHODS
from ftacq.identification import diagnostics, robust, trend
from ftacq.identification.lrom import lrom
from ftacq.identification.pose_error import NoiseModel, estimate_noise, fixed_noise, orientation_sensitivity
from ftacq.identification.refine import (
    DRIFT_SLICE,
    PARAMETER_SLICES,
    ModelParameters,
    OrientationBlock,
    gravity_in_sensor,
    levenberg_marquardt,
    normal_equations,
    predict,
)
from ftacq.identification.srom import DEFAULT_SPECIAL_TOLERANCE_DEG, match_special, missing_special, srom_gravity_base
from ftacq.identification.tilt import nearest_mount, relative_tilt_deg, tilt_deg, tilt_jacobian_deg
from ftacq.identification.torque import torque_least_squares
from ftacq.identification.wahba import wahba
from ftacq.mounts import MOUNT_FORMS, MOUNTS, check_mount
from ftacq.plausibility import check_tool
from ftacq.posefile import PoseRecord

if TYPE_CHECKING:
    from ftacq.identification.sensor_gain import ReferenceWeight

CLOSED_FORM_ROBUST_PASSES = 3
"""Closed-form re-solves with robust weights when a pose looks disturbed."""
MAX_ROBUST_ITERATIONS = 40
INNER_ITERATIONS = 4
"""Levenberg-Marquardt iterations per re-weighting (the model is nearly linear near the optimum)."""
"""Outer iterations of the re-weighted refinement (weights and noise scales updated each time)."""
ROBUST_WEIGHT_TOLERANCE = 1e-4
"""The re-weighted loop stops when no pose weight changes more than this (and the parameters are still) ..."""
SETTLED_PARAMETER_SIGMAS = 0.05
"""... or when no parameter moved more than this fraction of its 1σ in the last re-weighting and no noise scale
by more than SETTLED_NOISE_CHANGE: on thousands of real poses a few poses sit on the outlier threshold and flip
in and out at every re-weighting (a 2-cycle that moved the YuMi recording's parameters by 0.015σ forever and
ran into the iteration limit after 68 s); such a change is far inside the uncertainty the result reports."""
SETTLED_NOISE_CHANGE = 1e-2
LARGE_SET_POSES = 3000
"""Above this many poses the re-weighted refinement first runs on an evenly spaced subsample of
PREFIT_POSES, whose noise model (τ², σ_θ²: 7 numbers from ~9 000 residuals) is then kept for all poses while
the parameters and the robust weights are refined on all of them. Re-estimating the noise at full size is what
made 13 802 real poses cycle (the inlier set, the noise and the parameters chasing each other through a 5-cycle
of 1-2σ) for 68 s without converging."""
PREFIT_POSES = 1500
ORIENTATION_MIN_POSES = 8
"""Fewer poses than this: the robot's orientation error is not estimated (6 poses leave 21 residual degrees of
freedom for 7 variance components; over 30 random 6-pose sets a spurious detection made the held-out torque error
7 % larger than without it, and nothing changed from 8 poses on)."""
PARTIAL_SPECIAL_WARN = 12
"""Warn about missing special orientations when at least this many of the 24 are present (a meant-SROM set)."""
MIN_RELATIVE_STANDARD_ERROR = 1e-3
"""A pose's std/√count below this fraction of the channel's median is replaced by the median."""
NOISE_SCALE_TOLERANCE = 1e-3
"""... and no noise scale σ changes by more than this fraction ..."""
PARAMETER_CHANGE_SIGMAS = 1e-4
"""... and no parameter moves more than this fraction of its 1σ."""

__all__ = ["IdentificationResult", "identify", "METHODS", "MOUNTS"]


@dataclass(frozen=True)
class IdentificationResult:
    """Everything an identification produced (arrays per pose are in the record's row order).

    Attributes:
        calibration: the final calibration, ``uncertainty`` and ``metadata`` filled.
        closed_form: the paper's closed-form estimate (SROM/LROM + Wahba + torque LS) before refinement.
        residuals: (N, 6) measured − predicted wrench of the final calibration [N, N·m].
        closed_form_residuals: (N, 6) the same for the closed form.
        weights: (N,) robust weight of each pose in [0, 1] (1 = fully trusted).
        noise: (N, 6) the 1σ sensor-side noise per pose and channel the fit used [N, N·m] (without the robot
            orientation error, whose σ is ``calibration.metadata["noise"]["orientation_error_deg"]``).
        pose_statistic: (N,) d² = rᵀ C⁻¹ r (≈ χ²₆ for a clean pose; C the pose's noise covariance).
        outliers: labels of the poses named as disturbed.
        warnings: conditioning and data warnings, one sentence each.
        method_used: "srom" or "lrom" (how gravity_base was first estimated), "+refine" when refined.
        labels, sets: the record's pose labels and set names.
        special_index: (N,) paper number − 1 of the matched special orientation, or −1.
        converged: refinement convergence flag (True when not refined).
        iterations: LM iterations in total.
        diagnostics: figures for the report (condition number, eigen gap, Wahba singular values, …).
        parameter_covariance: (15, 15) covariance of the parameters (JᵀWJ)⁻¹ in refine.PARAMETER_NAMES order
            (the rotation as a sensor-frame increment, rad); the verdict propagates it to held-out poses.
    """

    calibration: Calibration
    closed_form: Calibration
    residuals: np.ndarray
    closed_form_residuals: np.ndarray
    weights: np.ndarray
    noise: np.ndarray
    pose_statistic: np.ndarray
    outliers: tuple[str, ...]
    warnings: tuple[str, ...]
    method_used: str
    labels: tuple[str, ...]
    sets: tuple[str, ...]
    special_index: np.ndarray
    converged: bool = True
    iterations: int = 0
    mount: str | None = None
    diagnostics: dict = field(default_factory=dict)
    parameter_covariance: np.ndarray | None = None


def _closed_form(
    rotations: np.ndarray,
    wrench: np.ndarray,
    use_srom: bool,
    special_index: np.ndarray,
    force_weight: np.ndarray | None,
    torque_weight: np.ndarray | None,
) -> tuple[ModelParameters, dict]:
    """Return the closed-form parameters (steps 2-3) and figures for the report."""
    forces, torques = wrench[:, :3], wrench[:, 3:]
    info: dict = {}
    if use_srom:
        gravity_base = srom_gravity_base(rotations, forces, special_index, force_weight)
    else:
        result = lrom(rotations, forces, force_weight)
        gravity_base = result.gravity_base
        eig = result.eigenvalues
        info["lrom_eigen_gap"] = float(eig[1] / max(abs(eig[0]), 1e-300))
    fit = wahba(rotations, forces, gravity_base, force_weight)
    info["wahba_singular_values"] = fit.singular_values.tolist()
    info["wahba_unique"] = bool(fit.unique)
    gravity_sensor = (rotations @ gravity_base) @ fit.sensor_rotation.T
    center_of_mass, torque_bias = torque_least_squares(gravity_sensor, torques, torque_weight)
    params = ModelParameters(fit.sensor_rotation, gravity_base, fit.force_bias, center_of_mass, torque_bias)
    return params, info


def _closed_form_weights(pose_weight: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose weights for the force steps and per-channel weights for the torque step."""
    force = pose_weight / np.mean(sigma[:, :3] ** 2, axis=1)
    torque = pose_weight[:, None] / sigma[:, 3:] ** 2
    return force / force.max(), torque / torque.max()


def _relative_noise(record: PoseRecord) -> np.ndarray:
    """Return (N, 6) relative noise per pose and channel when no standard error is known (median 1 per channel).

    From ``count`` alone: 1/√count; from ``std`` alone: std; otherwise 1. The scale is estimated from the residuals.
    """
    n = len(record)
    if record.std is not None and record.count is None:
        relative = np.array(record.std, dtype=float)
    elif record.count is not None and record.std is None:
        relative = np.repeat((1.0 / np.sqrt(np.maximum(record.count, 1.0)))[:, None], 6, axis=1)
    else:
        return np.ones((n, 6))
    typical = np.median(relative, axis=0)
    if np.any(typical <= 0.0):
        return np.ones((n, 6))
    relative = relative / typical
    return np.clip(relative, MIN_RELATIVE_STANDARD_ERROR, 1.0 / MIN_RELATIVE_STANDARD_ERROR)


def _standard_error(record: PoseRecord) -> np.ndarray | None:
    """Return the record's standard errors (N, 6) as the fit uses them, or None: None when a whole channel's are
    zero (the noise is then estimated from the residuals); a zero or implausibly small one (one sample, a stuck
    channel) replaced by the channel's median, so that it cannot dominate the fit."""
    standard_error = record.standard_error
    if standard_error is None:
        return None
    typical = np.median(standard_error, axis=0)
    if np.any(typical <= 0.0):
        return None
    return np.where(standard_error < MIN_RELATIVE_STANDARD_ERROR * typical, typical, standard_error)


def _parameter_change(before: ModelParameters, after: ModelParameters) -> np.ndarray:
    """Return the 15-vector from ``before`` to ``after`` (rotation as a small sensor-frame rotation vector, rad)."""
    relative = after.sensor_rotation @ before.sensor_rotation.T
    rotation = 0.5 * np.array(
        [relative[2, 1] - relative[1, 2], relative[0, 2] - relative[2, 0], relative[1, 0] - relative[0, 1]]
    )
    parts = [
        rotation,
        after.gravity_base - before.gravity_base,
        after.force_bias - before.force_bias,
        after.center_of_mass - before.center_of_mass,
        after.torque_bias - before.torque_bias,
    ]
    if after.bias_rate is not None and before.bias_rate is not None:
        parts.append(after.bias_rate - before.bias_rate)
    return np.concatenate(parts)


def _covariance(params: ModelParameters, rotations: OrientationBlock, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (JᵀWJ, its inverse) at ``params`` with ``weight`` as in refine.normal_equations."""
    information, *_ = normal_equations(params, rotations, np.zeros((len(rotations), 6)), weight)
    try:
        covariance = np.linalg.inv(information)
    except np.linalg.LinAlgError:
        covariance = np.linalg.pinv(information)
    return information, covariance


def _uncertainty(params: ModelParameters, covariance: np.ndarray, mount: str | None) -> dict:
    """Return the 1σ of every parameter, keyed as in the calibration file."""
    sigma = {name: np.sqrt(np.maximum(np.diag(covariance)[s], 0.0)) for name, s in PARAMETER_SLICES.items()}
    g_cov = covariance[PARAMETER_SLICES["gravity_base"], PARAMETER_SLICES["gravity_base"]]
    g = params.gravity_base
    gradient_mass = g / max(np.linalg.norm(g), 1e-300) / STANDARD_GRAVITY_M_S2
    tilt_jac = tilt_jacobian_deg(g)
    tilt_cov = tilt_jac @ g_cov @ tilt_jac.T
    out = {
        "sensor_rotation_rad": sigma["sensor_rotation_rad"].tolist(),
        "force_bias": sigma["force_bias"].tolist(),
        "torque_bias": sigma["torque_bias"].tolist(),
        "gravity_base": sigma["gravity_base"].tolist(),
        "mass_kg": float(np.sqrt(max(gradient_mass @ g_cov @ gradient_mass, 0.0))),
        "center_of_mass_m": sigma["center_of_mass_m"].tolist(),
        "base_tilt_deg": np.sqrt(np.maximum(np.diag(tilt_cov), 0.0)).tolist(),
    }
    if mount is not None:
        out["base_tilt_relative_deg"] = list(out["base_tilt_deg"])
    if params.bias_rate is not None:
        out["bias_rate"] = np.sqrt(np.maximum(np.diag(covariance)[DRIFT_SLICE], 0.0)).tolist()
    return out


def _model_correlation(covariance: np.ndarray) -> dict:
    """Return the ``model_correlation`` entry of the calibration file (ftacq.calfile): the correlations of the
    kept parameters' errors, from the parameter covariance (JᵀWJ)⁻¹."""
    columns = np.concatenate([np.arange(PARAMETER_SLICES[name].start, PARAMETER_SLICES[name].stop)
                              for name in MODEL_CORRELATION_PARAMETERS])
    block = covariance[np.ix_(columns, columns)]
    sigma = np.sqrt(np.maximum(np.diag(block), 1e-300))
    correlation = np.clip(block / np.outer(sigma, sigma), -1.0, 1.0)
    np.fill_diagonal(correlation, 1.0)
    return {"parameters": list(MODEL_CORRELATION_PARAMETERS), "matrix": (0.5 * (correlation + correlation.T)).tolist()}


def identify(
    record: PoseRecord,
    *,
    mount: str | None = None,
    method: str = "auto",
    refine: bool = True,
    special_tolerance_deg: float = DEFAULT_SPECIAL_TOLERANCE_DEG,
    orientation_error: bool = True,
    drift: str = "auto",
    drift_warn: tuple[float, float] | None = None,
    sensor_check: bool = False,
    reference: "ReferenceWeight | None" = None,
    sensor_accuracy_percent: float | None = None,
) -> IdentificationResult:
    """Identify the calibration from a pose record (see the module docstring for the steps).

    Args:
        record: still poses with their mean wrenches (contact-free, except for poses to be named outliers).
        mount: "floor", "wall", "ceiling" or a spec (``tilted:ALPHA,BETA``, ``gravity:X,Y,Z``, ftacq.mounts) to
            also report the tilt relative to that mount.
        method: "auto" (SROM when all 24 special orientations are present, else LROM), "srom" or "lrom".
        refine: run the joint robust refinement (True) or stop at the closed form (False).
        special_tolerance_deg: how close (geodesic angle) a pose must be to a cube rotation to count as special.
        orientation_error: estimate the robot's orientation error and weight each pose with its full noise
            covariance when the residuals show it (pose_error.py); False: independent channels only.
        drift: one of :data:`ftacq.fit_options.DRIFT_MODELS` (a linear bias drift over the recording; needs ``refine``).
        drift_warn: (N, N·m) change over the recording above which "auto" models a significant trend
            (default: CELL.toml ``sampling.drift_warn_force_n`` / ``drift_warn_torque_nm``).
        sensor_check: also fit the sensor's force gain/cross-talk matrix (sensor_gain.py) beside the parameters;
            it does not change the calibration, it lands in ``metadata["sensor_check"]``, and "auto" decides on a
            drift from a fit of the drift and the gains together (a gain error is not a drift, nor the reverse).
        reference: a known tool mass (sensor_gain.ReferenceWeight) that fixes the gains' absolute scale.
        sensor_accuracy_percent: the sensor's stated accuracy the verdict judges the check against (stored with it;
            default CELL.toml ``sensor.accuracy_percent``).

    Raises:
        IdentificationError: a value that is not finite or beyond what a robot or sensor reports, a tolerance
            outside (0, 45)°, too few poses, a degenerate pose set, SROM forced without the 24 special
            orientations, a tool whose weight is lost in the noise, or a tool no wrist carries (a centre of mass or
            mass beyond ftacq.plausibility's bounds: most likely a unit mistake, which the message names).
    """
    if method not in METHODS:
        raise IdentificationError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if drift not in DRIFT_MODELS:
        raise IdentificationError(f"unknown drift model {drift!r}; choose one of {', '.join(DRIFT_MODELS)}")
    if drift == "linear" and not refine:
        raise IdentificationError("a linear drift is fitted by the refinement: --drift linear needs it (drop "
                                  "--no-refine)")
    if mount is not None:
        try:
            mount = check_mount(mount)
        except ValueError:
            raise IdentificationError(f"unknown mount {mount!r}; give {MOUNT_FORMS}") from None
    special_tolerance_deg = diagnostics.check_special_tolerance(special_tolerance_deg)
    # every number checked before any linear algebra: extreme values can make LAPACK spin for minutes
    diagnostics.check_record_values(record.pose, record.wrench, record.labels, record.std, record.count)
    if drift_warn is None:
        from ftacq.settings import SamplingConfig

        drift_warn = (SamplingConfig.drift_warn_force_n, SamplingConfig.drift_warn_torque_nm)
    times = trend.pose_times(record)
    try:
        if drift == "linear":
            result = _identify(record, mount, method, refine, special_tolerance_deg, orientation_error, times,
                               "asked for (--drift linear)", drift_warn)
        else:
            result = _identify(record, mount, method, refine, special_tolerance_deg, orientation_error, None,
                               "asked for (--drift none)" if drift == "none"
                               else "not needed: no large, significant trend", drift_warn)
            found = trend.ResidualTrend.from_dict(result.diagnostics["trend"])
            if sensor_check and drift == "auto" and refine:  # drift and gains in one fit: told apart
                joint = _sensor_check(result, record, reference, with_drift=True)
                if joint is not None:
                    from ftacq.identification.sensor_gain import drift_trend

                    found = drift_trend(joint[0], record)
            if drift == "auto" and refine and found.significant and found.large(*drift_warn):
                reason = (f"chosen automatically: the residuals trend with time, p = {found.p_value:.2g}, "
                          f"{np.linalg.norm(found.change[:3]):.3g} N and {np.linalg.norm(found.change[3:]):.3g} N·m "
                          "over the recording")
                result = _identify(record, mount, method, refine, special_tolerance_deg, orientation_error, times,
                                   reason, drift_warn)
        if sensor_check:
            check = _sensor_check(result, record, reference)
            result = (_with_sensor_check(result, check, sensor_accuracy_percent) if check is not None else
                      replace(result, warnings=result.warnings + ("the sensor check could not be fitted on these poses "
                                                                  "(numerically degenerate); it was left out",)))
    except np.linalg.LinAlgError as error:  # a last guard: LAPACK failing on a set that passed the checks above
        raise IdentificationError(f"the fit is numerically degenerate ({error}); check the record's values") from None
    check_tool(result.calibration.mass_kg, result.calibration.center_of_mass)  # a unit mistake, named
    return result


def _sensor_check(result: IdentificationResult, record: PoseRecord, reference, with_drift: bool = False
                  ) -> tuple | None:
    """The sensor check (sensor_gain.py), or None when it cannot be fitted: it never costs the calibration."""
    from ftacq.identification.sensor_gain import check_identification

    try:
        with np.errstate(all="ignore"):
            fit, found = check_identification(result, record, reference, with_drift)
    except (np.linalg.LinAlgError, ValueError, FloatingPointError):
        return None
    if not np.all(np.isfinite(fit.force_gain)) or not np.all(np.isfinite(fit.force_gain_covariance)):
        return None
    return fit, found


def _with_sensor_check(result: IdentificationResult, check: tuple,
                       accuracy_percent: float | None) -> IdentificationResult:
    """Attach the sensor check: ``metadata["sensor_check"]``; the trend the verdict judges is that of its residuals
    (the paper model's is kept as ``trend_paper_model``)."""
    fit, found = check
    if accuracy_percent is None:
        from ftacq.settings import SensorConfig

        accuracy_percent = SensorConfig.accuracy_percent
    metadata = {**result.calibration.metadata,
                "sensor_check": {**fit.to_dict(), "trend": found, "accuracy_percent": float(accuracy_percent)}}
    diagnostics = {**result.diagnostics, "trend": found, "trend_paper_model": result.diagnostics.get("trend")}
    return replace(result, calibration=replace(result.calibration, metadata=metadata), diagnostics=diagnostics)


@dataclass
class _Problem:
    """Steps 1-2: the record as the fit sees it, its noise inputs and how gravity_base starts."""

    record: PoseRecord
    rotations: np.ndarray
    """(N, 3, 3) flange_R_base of each pose."""
    wrench: np.ndarray
    times: trend.PoseTimes | None
    """Given: the fit has a linear bias drift over these times (refine.py ``bias_rate``)."""
    standard_error: np.ndarray | None
    relative: np.ndarray
    floor: np.ndarray
    special_index: np.ndarray
    special_angle: np.ndarray
    missing: list[int]
    use_srom: bool
    pose_set_info: dict
    warnings: list[str]

    @property
    def n(self) -> int:
        return len(self.record)

    @property
    def drift_time(self) -> np.ndarray | None:
        return None if self.times is None else self.times.drift_time

    @property
    def dof_ratio(self) -> float:
        return max((6.0 * self.n - 15.0) / (6.0 * self.n), 1e-3)

    def channel_noise(self, residual: np.ndarray, pose_weight: np.ndarray, dof: float, statistic: str):
        """σ (N, 6) and τ (6,): measured standard errors + scatter, or a scale × relative noise per pose."""
        if self.standard_error is not None:
            return robust.channel_noise(residual, self.standard_error, pose_weight, dof, self.floor, statistic)
        scale, tau = robust.channel_noise(residual / self.relative, None, pose_weight, dof, self.floor, statistic)
        return scale * self.relative, tau


@dataclass
class _Refined:
    """Step 4's outcome: the parameters, the noise model and robust weights they were fitted with."""

    params: ModelParameters
    orientations: OrientationBlock
    sigma: np.ndarray
    tau: np.ndarray
    pose_weight: np.ndarray
    noise: NoiseModel | None
    """The full noise model (pose_error.py), once the refinement had residuals to estimate it from."""
    converged: bool = True
    iterations: int = 0
    reweightings: int = 0
    moved_sigmas: float = 0.0


def _identify(record: PoseRecord, mount: str | None, method: str, refine: bool, special_tolerance_deg: float,
              orientation_error: bool, times: trend.PoseTimes | None = None, drift_text: str = "not asked for",
              drift_warn: tuple[float, float] = (np.inf, np.inf)) -> IdentificationResult:
    """One identification; ``times`` given: with a linear bias drift over them (refine.py ``bias_rate``)."""
    problem = _prepare(record, method, special_tolerance_deg, times)
    closed_params, closed_info = _robust_closed_form(problem)
    refined = _refine(problem, closed_params, refine, special_tolerance_deg, orientation_error, drift_text, drift_warn)
    return _result(problem, closed_params, closed_info, refined, mount, refine, drift_text, drift_warn)


def _prepare(record: PoseRecord, method: str, special_tolerance_deg: float, times: trend.PoseTimes | None
             ) -> _Problem:
    """Steps 1-2: refuse a degenerate pose set, match the special orientations, choose SROM or LROM, and read the
    record's noise (measured standard errors, or relative weights whose scale the residuals give)."""
    rotations = record.flange_R_base
    n = len(record)
    warnings: list[str] = []
    pose_set_info = diagnostics.check_pose_set(rotations)

    special_index, special_angle = match_special(rotations, special_tolerance_deg)
    missing = missing_special(special_index)
    if method == "srom" and missing:
        raise IdentificationError(
            f"--method srom needs all 24 special orientations within {special_tolerance_deg}° of a cube rotation; "
            f"missing paper number(s) {', '.join(map(str, missing))}"
        )
    use_srom = method == "srom" or (method == "auto" and not missing)
    if method == "auto" and PARTIAL_SPECIAL_WARN <= 24 - len(missing) < 24:
        warnings.append(
            f"{24 - len(missing)} of the 24 special orientations present (missing {', '.join(map(str, missing))}): "
            "gravity_base started from LROM"
        )

    standard_error = _standard_error(record)
    relative = _relative_noise(record) if standard_error is not None or record.standard_error is None else np.ones((n, 6))
    if record.std is not None and record.count is None:
        warnings.append(
            "std_* columns without a count column: std used as relative weights, the noise scale estimated from "
            "the residuals"
        )
    if standard_error is None and record.standard_error is not None:
        warnings.append("std_* columns are zero for a whole channel: noise estimated from the residuals instead")
    return _Problem(record, rotations, record.wrench, times, standard_error, relative,
                    robust.noise_floor(record.wrench), special_index, special_angle, missing, use_srom, pose_set_info,
                    warnings)


def _robust_closed_form(problem: _Problem) -> tuple[ModelParameters, dict]:
    """Steps 2-3: the closed form, repeated with robust weights if a pose looks disturbed."""
    rotations, wrench, n = problem.rotations, problem.wrench, problem.n
    params, closed_info = _closed_form(rotations, wrench, problem.use_srom, problem.special_index, None, None)
    pose_weight = np.ones(n)
    for _ in range(CLOSED_FORM_ROBUST_PASSES):
        residual = wrench - predict(params, rotations)
        sigma, _ = problem.channel_noise(residual, np.ones(n), problem.dof_ratio, "median")
        new_weight = robust.robust_weights(robust.pose_statistic(residual, sigma))
        if np.all(new_weight >= 1.0) and np.all(pose_weight >= 1.0):
            break
        pose_weight = new_weight
        force_w, torque_w = _closed_form_weights(pose_weight, sigma)
        params, closed_info = _closed_form(rotations, wrench, problem.use_srom, problem.special_index, force_w,
                                           torque_w)
    return params, closed_info


def _prefit(problem: _Problem, special_tolerance_deg: float, orientation_error: bool, drift_text: str,
            drift_warn: tuple[float, float]) -> tuple[ModelParameters, np.ndarray, float]:
    """Step 4 on a large set (LARGE_SET_POSES): refine an evenly spaced subsample first; return its parameters, its
    extra scatter τ² and its orientation error variance (rad²), the noise model kept for all poses."""
    times = problem.times
    subsample = np.linspace(0, problem.n - 1, PREFIT_POSES).astype(int)
    sub_times = None if times is None else replace(times, drift_time=times.drift_time[subsample])
    prefit = _identify(problem.record.select(subsample), None, "lrom", True, special_tolerance_deg, orientation_error,
                       sub_times, drift_text, drift_warn)
    params = ModelParameters.from_calibration(prefit.calibration)
    if times is not None:
        params = replace(params, bias_rate=np.asarray(prefit.calibration.metadata["drift_model"]["bias_rate"]))
    start_scatter2 = np.asarray(prefit.calibration.metadata["noise"]["extra_scatter"]) ** 2
    start_orientation_variance = float(np.radians(prefit.calibration.metadata["noise"]["orientation_error_deg"]) ** 2)
    return params, start_scatter2, start_orientation_variance


def _refine(problem: _Problem, closed_params: ModelParameters, refine: bool, special_tolerance_deg: float,
            orientation_error: bool, drift_text: str, drift_warn: tuple[float, float]) -> _Refined:
    """Step 4: the robust joint refinement from the closed form (or, with ``refine=False``, the closed form's own
    noise scale and robust weights, for its uncertainty)."""
    rotations, wrench, n, drift_time = problem.rotations, problem.wrench, problem.n, problem.drift_time
    standard_error, floor = problem.standard_error, problem.floor
    params = closed_params
    residual = wrench - predict(closed_params, rotations)
    start_scatter2, start_orientation_variance = None, 0.0
    if refine and n > LARGE_SET_POSES:  # a subsample first (LARGE_SET_POSES)
        params, start_scatter2, start_orientation_variance = _prefit(problem, special_tolerance_deg,
                                                                     orientation_error, drift_text, drift_warn)
        residual = wrench - predict(params, rotations, drift_time)
    sigma, tau = problem.channel_noise(residual, np.ones(n), problem.dof_ratio, "median")
    pose_weight = robust.robust_weights(robust.pose_statistic(residual, sigma))
    robust_sigma = sigma  # includes the scatter the measured noise does not explain: picks the first inliers
    if standard_error is not None:
        # start from the measured noise alone: the closed form's residuals overstate the noise of the
        # channels it fits sub-optimally; extra scatter τ is re-estimated after each refit
        sigma = np.sqrt(np.maximum(standard_error, floor) ** 2)
    if problem.times is not None and params.bias_rate is None:
        params = replace(params, bias_rate=np.zeros(6))  # the closed form has none: the refinement fits it
    orientations = OrientationBlock(rotations, drift_time)
    if not refine:  # noise scale of the closed form itself, for its uncertainty
        inlier = robust.pose_statistic(residual, sigma) <= robust.outlier_threshold(n)
        sigma, tau = problem.channel_noise(residual, inlier.astype(float), problem.dof_ratio, "mean")
        pose_weight = robust.robust_weights(robust.pose_statistic(residual, sigma))
        return _Refined(params, orientations, sigma, tau, pose_weight, None)

    converged, iterations, reweightings, moved_sigmas = False, 0, 0, 0.0
    covariance = None
    noise = None  # the full noise model (pose_error.py), once the refinement has residuals to estimate it from
    weight = pose_weight[:, None] / sigma**2
    total_sigma = sigma
    if start_scatter2 is not None:  # the subsample's noise model and robust weights from the start
        noise = fixed_noise(orientation_sensitivity(gravity_in_sensor(params, rotations), params.center_of_mass),
                            standard_error, problem.relative, floor, start_scatter2, start_orientation_variance)
        pose_weight = robust.robust_weights(noise.pose_statistic(residual))
        weight = noise.weight(pose_weight)
        total_sigma = np.sqrt(noise.total_variance)
    for _ in range(MAX_ROBUST_ITERATIONS):
        result = levenberg_marquardt(params, orientations, wrench, weight, max_iterations=INNER_ITERATIONS)
        iterations += result.iterations
        reweightings += 1
        moved_sigmas = np.inf if covariance is None else float(np.max(
            np.abs(_parameter_change(params, result.params)) / np.sqrt(np.maximum(np.diag(covariance), 1e-300))))
        step_ok = covariance is None or bool(
            np.all(
                np.abs(_parameter_change(params, result.params))
                <= PARAMETER_CHANGE_SIGMAS * np.sqrt(np.maximum(np.diag(covariance), 1e-300))
            )
        )
        params = result.params
        residual = wrench - predict(params, rotations, drift_time)
        if noise is not None:
            statistic = noise.pose_statistic(residual)
        else:
            statistic = robust.pose_statistic(residual, robust_sigma)
        inlier = statistic <= robust.outlier_threshold(n)
        # the noise comes from the clean poses; if too few look clean, from all of them with their robust weights
        noise_weight = inlier.astype(float) if inlier.sum() >= diagnostics.MIN_POSES else pose_weight
        n_in = max(int(np.count_nonzero(noise_weight)), 3)
        sensitivity = orientation_sensitivity(gravity_in_sensor(params, rotations), params.center_of_mass)
        if start_scatter2 is not None:  # noise estimated on the subsample (LARGE_SET_POSES), kept
            noise = fixed_noise(sensitivity, standard_error, problem.relative, floor, start_scatter2,
                                start_orientation_variance)
        else:
            noise = estimate_noise(
                residual,
                sensitivity,
                standard_error,
                problem.relative,
                noise_weight,
                max((6.0 * n_in - 15.0) / (6.0 * n_in), 1e-3),
                floor,
                start_scatter2=tau**2 if noise is None else noise.scatter**2,
                start_orientation_variance=0.0 if noise is None else noise.fitted_orientation_variance_rad2,
                model_orientation=orientation_error and n >= ORIENTATION_MIN_POSES,
            )
        sigma, tau = noise.channel_sigma, noise.scatter
        previous_total, total_sigma = total_sigma, np.sqrt(noise.total_variance)
        sigma_change = float(np.max(np.abs(total_sigma / previous_total - 1.0)))
        new_weight = robust.robust_weights(noise.pose_statistic(residual))
        weight_change = float(np.max(np.abs(new_weight - pose_weight)))
        pose_weight = new_weight
        weight = noise.weight(pose_weight)
        _, covariance = _covariance(params, orientations, weight)
        settled = moved_sigmas <= SETTLED_PARAMETER_SIGMAS and sigma_change <= SETTLED_NOISE_CHANGE
        if result.converged and (settled or (weight_change <= ROBUST_WEIGHT_TOLERANCE
                                             and sigma_change <= NOISE_SCALE_TOLERANCE and step_ok)):
            converged = True
            break
    return _Refined(params, orientations, sigma, tau, pose_weight, noise, converged, iterations, reweightings,
                    moved_sigmas)


def _result(problem: _Problem, closed_params: ModelParameters, closed_info: dict, refined: _Refined,
            mount: str | None, refine: bool, drift_text: str, drift_warn: tuple[float, float]) -> IdentificationResult:
    """Step 5: the uncertainty of every parameter, the named outliers, the warnings and the calibration's metadata."""
    record, rotations, wrench, n = problem.record, problem.rotations, problem.wrench, problem.n
    params, noise, sigma, pose_weight = refined.params, refined.noise, refined.sigma, refined.pose_weight
    warnings = list(problem.warnings)
    residual = wrench - predict(params, rotations, problem.drift_time)
    d2 = noise.pose_statistic(residual) if noise is not None else robust.pose_statistic(residual, sigma)
    weight = noise.weight(pose_weight) if noise is not None else pose_weight[:, None] / sigma**2
    information, covariance = _covariance(params, refined.orientations, weight)
    conditioning = diagnostics.fisher_conditioning(information)
    uncertainty = _uncertainty(params, covariance, mount)
    mass_kg = float(np.linalg.norm(params.gravity_base) / STANDARD_GRAVITY_M_S2)
    diagnostics.check_weight_detectable(mass_kg, uncertainty["mass_kg"])
    warnings += diagnostics.parameter_warnings(uncertainty, mass_kg, conditioning)
    if not closed_info.get("wahba_unique", True):
        warnings.append("Wahba step: the rotation is not unique (repeated smallest singular value with a reflection)")
    if not refined.converged:
        warnings.append("refinement did not converge within the iteration limit; the result may be inaccurate")
    outlier_mask = d2 > robust.outlier_threshold(n)
    outliers = tuple(label for label, flag in zip(record.labels, outlier_mask) if flag)
    for index in np.flatnonzero(outlier_mask):
        force_error = float(np.linalg.norm(residual[index, :3]))
        torque_error = float(np.linalg.norm(residual[index, 3:]))
        warnings.append(
            f"pose {record.labels[index]} looks disturbed (contact or motion while sampling): residual "
            f"{force_error:.3g} N, {torque_error:.3g} N·m; down-weighted to {pose_weight[index]:.2g}"
        )
    if n - len(outliers) < diagnostics.MIN_POSES:
        raise IdentificationError(
            f"too few undisturbed poses: {n - len(outliers)} of {n} after naming outliers {', '.join(outliers)}"
        )

    record_times = problem.times if problem.times is not None else trend.pose_times(record)
    variance = noise.total_variance if noise is not None else sigma**2
    found = trend.residual_trend(residual, variance, pose_weight, record_times.drift_time, record_times.unit)
    metadata = _metadata(problem, closed_params, closed_info, refined, mount, refine, residual, uncertainty,
                         covariance, conditioning, outliers, warnings, record_times, found, drift_text, drift_warn)
    calibration = params.to_calibration(uncertainty=uncertainty, metadata=metadata)
    closed_form = closed_params.to_calibration(metadata={"method": "srom" if problem.use_srom else "lrom"})
    return IdentificationResult(
        calibration=calibration,
        closed_form=closed_form,
        residuals=residual,
        closed_form_residuals=wrench - predict(closed_params, rotations),
        weights=pose_weight,
        noise=sigma,
        pose_statistic=d2,
        outliers=outliers,
        warnings=tuple(warnings),
        method_used=metadata["method"],
        labels=record.labels,
        sets=record.sets,
        special_index=problem.special_index,
        converged=refined.converged,
        iterations=refined.iterations,
        mount=mount,
        diagnostics={**metadata["diagnostics"], "tilt_deg": list(tilt_deg(params.gravity_base)),
                     "special_angle_deg": problem.special_angle, "trend": found.to_dict()},
        parameter_covariance=covariance,
    )


def _metadata(problem: _Problem, closed_params: ModelParameters, closed_info: dict, refined: _Refined,
              mount: str | None, refine: bool, residual: np.ndarray, uncertainty: dict, covariance: np.ndarray,
              conditioning: dict, outliers: tuple[str, ...], warnings: list[str], record_times: trend.PoseTimes,
              found: trend.ResidualTrend, drift_text: str, drift_warn: tuple[float, float]) -> dict:
    """Step 5: the calibration file's ``metadata`` (method, mount and tilt, noise, residuals, drift model,
    correlations, diagnostics, the closed form); a tilt from the declared mount is added to ``warnings``."""
    record, params, noise, pose_weight = problem.record, refined.params, refined.noise, refined.pose_weight
    use_srom = problem.use_srom
    nearest, nearest_angle = nearest_mount(params.gravity_base)
    metadata: dict = {
        "method": ("srom" if use_srom else "lrom") + ("+refine" if refine else ""),
        "method_detail": (
            ("SROM on the 24 special orientations (eqs 14-23)" if use_srom else "LROM on all poses (eqs 24-34, det>0 sign)")
            + ", Wahba/Umeyama (eqs 35-42), torque least squares (eqs 43-45)"
            + (", joint weighted refinement on SO(3) with robust re-weighting" if refine else "")
        ),
        "software_version": f"ftacq {__version__}",
        "nearest_mount": nearest,
        "tilt_from_nearest_mount_deg": nearest_angle,
    }
    if mount is not None:
        alpha_rel, beta_rel, total = relative_tilt_deg(params.gravity_base, mount)
        metadata["mount"] = mount
        metadata["base_tilt_relative_deg"] = [alpha_rel, beta_rel]
        metadata["tilt_from_mount_deg"] = total
        if total > diagnostics.NOMINAL_TILT_WARN_DEG:
            warnings.append(
                f"the base is tilted {total:.1f}° from a nominal {mount} mount (nearest nominal mount: {nearest}); "
                "is --mount right? If the base is mounted so, declare it: --gravity-direction "
                + ",".join(f"{v:.3f}" for v in params.gravity_base / np.linalg.norm(params.gravity_base))
            )
    if problem.standard_error is not None:
        noise_text = "measured std/√count"
    elif record.count is not None and record.std is None:
        noise_text = "estimated from the residuals, relative weights 1/√count"
    elif record.std is not None and record.count is None:
        noise_text = "estimated from the residuals, relative weights from std"
    else:
        noise_text = "estimated from the residuals"
    metadata["noise"] = {
        "source": noise_text,
        "extra_scatter": refined.tau.tolist(),
        "orientation_error_deg": noise.orientation_error_deg if noise is not None else 0.0,
        "rms_residual": np.sqrt(np.mean(residual[pose_weight > 0.5] ** 2, axis=0)).tolist()
        if np.any(pose_weight > 0.5)
        else [],
    }
    metadata["residuals"] = {
        "columns": list(WRENCH_COLUMNS),
        "labels": list(record.labels),
        "values": residual.tolist(),
        "weights": pose_weight.tolist(),
    }
    drift_model: dict = {"model": "linear" if params.bias_rate is not None else "none", "chosen": drift_text,
                         **record_times.to_dict(), "span": found.span,
                         "warn_force_n": float(drift_warn[0]), "warn_torque_nm": float(drift_warn[1])}
    if params.bias_rate is not None:
        drift_model.update({
            "bias_rate": params.bias_rate.tolist(), "bias_rate_sigma": uncertainty["bias_rate"],
            "bias_at": "end of the recording: force_bias and torque_bias are the biases at the last pose; "
                       "compensation uses them",
        })
    metadata["drift_model"] = drift_model
    metadata[MODEL_CORRELATION_KEY] = _model_correlation(covariance)
    metadata["outliers"] = list(outliers)
    metadata["warnings"] = list(warnings)
    moved_sigmas = refined.moved_sigmas
    metadata["diagnostics"] = {
        "poses": problem.n,
        "special_orientations_present": 24 - len(problem.missing),
        "condition_number": conditioning["condition_number"],
        "weakest_parameters": conditioning["weakest_parameters"],
        "converged": refined.converged,
        "iterations": refined.iterations,
        "reweightings": refined.reweightings,
        "max_reweightings": MAX_ROBUST_ITERATIONS,
        "last_change_sigmas": moved_sigmas if np.isfinite(moved_sigmas) else None,
        "resolution": (np.sqrt(12.0) * robust.resolution_floor(problem.wrench)).tolist(),
        **problem.pose_set_info,
        **closed_info,
    }
    metadata["closed_form"] = {
        "sensor_rotation": closed_params.sensor_rotation.tolist(),
        "force_bias": closed_params.force_bias.tolist(),
        "torque_bias": closed_params.torque_bias.tolist(),
        "gravity_base": closed_params.gravity_base.tolist(),
        "center_of_mass_m": closed_params.center_of_mass.tolist(),
    }
    return metadata
