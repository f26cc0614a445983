"""Conditioning diagnostics: refuse pose sets that cannot identify the calibration, warn about weak ones.

Checks before any linear algebra (:func:`check_record_values`): every number finite and within what a robot
and an F/T sensor can report, the readings not all equal; a value of 1e30 or more would otherwise reach
``np.linalg.svd``, which can spin for minutes on it without answering Ctrl-C. Then, cheap and from the
orientations only: enough poses, more than one orientation, and rotations about more than one axis (rotating about a single axis u leaves the weight's component along u
indistinguishable from the force bias). After fitting: the column-scaled Fisher matrix JᵀWJ (rank and
condition number) and the 1σ of each parameter against named thresholds.
"""

from __future__ import annotations

import numpy as np

from ftacq.channels import WRENCH_COLUMNS
from ftacq.errors import IdentificationError
from ftacq.identification.refine import DRIFT_PARAMETER_NAMES, PARAMETER_NAMES
from ftacq.validation import MAX_FORCE_N, MAX_POSITION_M, MAX_ROTATION_VECTOR_RAD, MAX_TORQUE_NM

MIN_POSES = 6
"""Fewest poses accepted: 6 × 6 = 36 equations for 15 parameters (LROM alone needs ≥ 5)."""
ONE_ORIENTATION_DEG = 2.0
"""If every pose is within this angle of the first, the set has one orientation."""
ONE_AXIS_RELATIVE_SPREAD = 0.01
"""The set turns about one axis only if its RMS rotation off the dominant axis is below this fraction of the
RMS rotation about it ..."""
ONE_AXIS_MIN_SPREAD_DEG = 0.05
"""... or below this absolute RMS angle (deg). A small cone is not refused here: the Fisher conditioning judges it."""
SINGULAR_CONDITION = 1e13
"""Scaled condition number of JᵀWJ above which a parameter is unidentifiable: refuse."""
WEAK_CONDITION = 1e6
"""Scaled condition number above which the report warns that the pose set is weak."""
COM_SIGMA_WARN_M = 0.002
"""Warn when the centre of mass has a 1σ above 2 mm on any axis (light tool, little tilt)."""
MASS_RELATIVE_SIGMA_WARN = 0.01
"""Warn when the mass 1σ is above 1 % of the mass."""
ROTATION_SIGMA_WARN_DEG = 0.5
"""Warn when the sensor rotation 1σ is above 0.5° about any axis."""
MASS_DETECTION_SIGMAS = 5.0
"""Refuse when the tool's weight is below this many σ: nothing orients the sensor rotation."""
NOMINAL_TILT_WARN_DEG = 5.0
"""Warn when the base is tilted more than this from the named nominal mount (wrong --mount?)."""

_PARAMETER_TEXT = {
    "sensor_rotation_rad": "sensor rotation",
    "gravity_base": "tool weight in the base frame",
    "force_bias": "force bias",
    "center_of_mass_m": "centre of mass",
    "torque_bias": "torque bias",
    "force_bias_rate": "force bias drift",
    "torque_bias_rate": "torque bias drift",
}


MIN_FORCE_SPREAD_N = 1e-9
"""Readings whose every force channel varies less than this over the poses carry no gravity signal."""
MAX_SPECIAL_TOLERANCE_DEG = 45.0
"""Cube rotations are 90° apart: a special-orientation tolerance must stay below half of that."""


def _first_bad(mask: np.ndarray) -> tuple[int, int]:
    row, column = np.argwhere(mask)[0]
    return int(row), int(column)


def check_record_values(pose: np.ndarray, wrench: np.ndarray, labels, std: np.ndarray | None = None,
                        count: np.ndarray | None = None) -> None:
    """Refuse (IdentificationError naming the pose, the column and the value) what identification cannot handle.

    ``pose`` (N, 6) [x, y, z (m), rx, ry, rz (rad)], ``wrench`` (N, 6) [N, N·m], ``std`` (N, 6) ≥ 0 or None,
    ``count`` (N,) ≥ 1 or None. Bounds: :data:`ftacq.validation.MAX_POSITION_M`, ``MAX_ROTATION_VECTOR_RAD``
    (norm), ``MAX_FORCE_N``, ``MAX_TORQUE_NM`` (beyond any sensor's range). Runs before any linear algebra.
    """
    columns = ("x", "y", "z", "rx", "ry", "rz") + WRENCH_COLUMNS
    values = np.column_stack([np.asarray(pose, dtype=float).reshape(-1, 6), np.asarray(wrench, dtype=float).reshape(-1, 6)])
    limits = np.array([MAX_POSITION_M] * 3 + [MAX_ROTATION_VECTOR_RAD] * 3 + [MAX_FORCE_N] * 3 + [MAX_TORQUE_NM] * 3)
    with np.errstate(invalid="ignore", over="ignore"):
        bad = ~np.isfinite(values) | (np.abs(values) > limits)
    if bad.any():
        row, column = _first_bad(bad)
        value = values[row, column]
        why = "is not finite" if not np.isfinite(value) else (
            f"is beyond what a robot or an F/T sensor reports (|value| ≤ {limits[column]:g}); wrong units?")
        raise IdentificationError(f"pose {labels[row]}, column {columns[column]!r}: value {float(value)!r} {why}")
    rotation_norm = np.linalg.norm(values[:, 3:6], axis=1)
    if np.any(rotation_norm > MAX_ROTATION_VECTOR_RAD):
        row = int(np.argmax(rotation_norm > MAX_ROTATION_VECTOR_RAD))
        raise IdentificationError(f"pose {labels[row]}: rotation vector of length {rotation_norm[row]:.4g} rad is longer "
                                  f"than {MAX_ROTATION_VECTOR_RAD:.4g} rad (two turns); not a robot orientation")
    if std is not None:
        std = np.asarray(std, dtype=float).reshape(-1, 6)
        std_limits = limits[6:]
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(std) | (std < 0) | (std > std_limits)
        if bad.any():
            row, column = _first_bad(bad)
            raise IdentificationError(f"pose {labels[row]}, column 'std_{columns[6 + column]}': value {std[row, column]!r} "
                                      f"must be a finite standard deviation in [0, {std_limits[column]:g}]")
    if count is not None:
        count = np.asarray(count, dtype=float).reshape(-1)
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(count) | (count < 1) | (count > 1e15)
        if bad.any():
            row = int(np.argmax(bad))
            raise IdentificationError(f"pose {labels[row]}, column 'count': value {count[row]!r} must be a sample "
                                      "count in [1, 1e15]")
    if len(values) and np.all(np.ptp(values[:, 6:9], axis=0) < MIN_FORCE_SPREAD_N):
        raise IdentificationError(
            "degenerate record: the force readings are the same at every pose (no gravity signal); is the sensor "
            "streaming, and was the record made while the tool was tilted?")


def check_special_tolerance(special_tolerance_deg: float) -> float:
    """Refuse a special-orientation tolerance that is not a finite angle in (0°, 45°)."""
    try:
        value = float(special_tolerance_deg)
    except (TypeError, ValueError):
        value = float("nan")
    if not (np.isfinite(value) and 0.0 < value < MAX_SPECIAL_TOLERANCE_DEG):
        raise IdentificationError(f"special-orientation tolerance {special_tolerance_deg!r}°: must be a finite angle "
                                  f"in (0, {MAX_SPECIAL_TOLERANCE_DEG:g})° (cube rotations are 90° apart)")
    return value


def relative_rotation_axes(flange_R_base: np.ndarray) -> np.ndarray:
    """Return (N, 3) axis·sin(angle) of each pose's rotation relative to the first, in the base frame.

    For base_R_flange_i = Rot(u, θ_i) B₀ (turning about a fixed axis u, in the base or the flange) these
    are all parallel, which :func:`check_pose_set` detects.
    """
    rotations = np.asarray(flange_R_base, dtype=float)
    relative = np.swapaxes(rotations, -1, -2) @ rotations[0]  # base_R_flange_i flange_R_base_0
    return 0.5 * np.stack(
        [relative[:, 2, 1] - relative[:, 1, 2], relative[:, 0, 2] - relative[:, 2, 0], relative[:, 1, 0] - relative[:, 0, 1]],
        axis=1,
    )


def check_pose_set(flange_R_base: np.ndarray) -> dict:
    """Refuse (IdentificationError with the reason) a pose set that cannot identify the calibration.

    Returns a dict of figures for the report: ``max_rotation_deg`` from the first pose and
    ``off_axis_rms_deg`` (rotation away from the dominant axis).
    """
    rotations = np.asarray(flange_R_base, dtype=float)
    n = len(rotations)
    if n < MIN_POSES:
        raise IdentificationError(
            f"too few poses: {n} (at least {MIN_POSES} distinct orientations are needed for the 15 parameters)"
        )
    traces = np.einsum("nab,ab->n", rotations, rotations[0])
    angles = np.degrees(np.arccos(np.clip((traces - 1.0) / 2.0, -1.0, 1.0)))
    max_angle = float(angles.max())
    if max_angle < ONE_ORIENTATION_DEG:
        raise IdentificationError(
            f"degenerate pose set: all {n} poses share one orientation (largest rotation between them "
            f"{max_angle:.2f}°); the weight cannot be separated from the bias"
        )
    # RMS rotation along the dominant axis and off it, from two reference poses (a pose at 180° from a
    # reference has a zero sin-axis vector, so one reference alone can miss it)
    far = int(np.argmax(angles))
    main_rms_deg, off_axis_rms_deg = 0.0, 0.0
    for reference in (rotations, np.concatenate([rotations[far : far + 1], rotations])):
        singular = np.linalg.svd(relative_rotation_axes(reference), compute_uv=False)
        main_rms_deg = max(main_rms_deg, float(np.degrees(np.arcsin(min(1.0, singular[0] / np.sqrt(n))))))
        off = np.sqrt((singular[1] ** 2 + singular[2] ** 2) / n)
        off_axis_rms_deg = max(off_axis_rms_deg, float(np.degrees(np.arcsin(min(1.0, off)))))
    if off_axis_rms_deg < max(ONE_AXIS_RELATIVE_SPREAD * main_rms_deg, ONE_AXIS_MIN_SPREAD_DEG):
        raise IdentificationError(
            f"degenerate pose set: all {n} poses turn about one axis only (off-axis spread "
            f"{off_axis_rms_deg:.2f}° RMS against {main_rms_deg:.1f}° about the axis); the weight's component along "
            "that axis cannot be separated from the force bias: tilt the tool about a second axis"
        )
    return {"max_rotation_deg": max_angle, "off_axis_rms_deg": off_axis_rms_deg}


def fisher_conditioning(information: np.ndarray) -> dict:
    """Return the scaled condition number of JᵀWJ and its weakest direction; refuse if singular."""
    if not np.all(np.isfinite(information)):
        raise IdentificationError("degenerate fit: the information matrix JᵀWJ is not finite (extreme residuals "
                                  "or weights)")
    scale = np.sqrt(np.maximum(np.diag(information), 1e-300))
    scaled = information / np.outer(scale, scale)
    try:
        eigenvalues, eigenvectors = np.linalg.eigh(0.5 * (scaled + scaled.T))
    except np.linalg.LinAlgError as error:
        raise IdentificationError(f"degenerate fit: the information matrix has no eigen-decomposition ({error})") \
            from None
    condition = float(eigenvalues[-1] / max(eigenvalues[0], 1e-300))
    weakest = eigenvectors[:, 0]
    names = PARAMETER_NAMES + DRIFT_PARAMETER_NAMES
    involved = sorted({names[int(k) // 3] for k in np.flatnonzero(np.abs(weakest) > 0.3)}, key=names.index)
    text = ", ".join(_PARAMETER_TEXT[name] for name in involved)
    if condition > SINGULAR_CONDITION or not np.isfinite(condition):
        raise IdentificationError(
            f"degenerate pose set: the parameters cannot be told apart (scaled condition number {condition:.2e}; "
            f"weakest combination: {text}); add poses tilted in other directions"
        )
    return {"condition_number": condition, "weakest_parameters": involved, "weakest_text": text}


def parameter_warnings(uncertainty: dict, mass_kg: float, conditioning: dict) -> list[str]:
    """Return warnings for parameters the pose set determines poorly (thresholds are module constants)."""
    warnings: list[str] = []
    if conditioning["condition_number"] > WEAK_CONDITION:
        warnings.append(
            f"weak pose set: scaled condition number {conditioning['condition_number']:.2e} "
            f"(weakest: {conditioning['weakest_text']}); tilt the tool over a wider range of orientations"
        )
    com_sigma = np.asarray(uncertainty["center_of_mass_m"])
    if np.max(com_sigma) > COM_SIGMA_WARN_M:
        warnings.append(
            f"centre of mass poorly determined (1σ up to {1000 * np.max(com_sigma):.1f} mm): the tool is light for "
            "the torque noise or the poses tilt too little"
        )
    mass_sigma = float(uncertainty["mass_kg"])
    if mass_kg > 0 and mass_sigma > MASS_RELATIVE_SIGMA_WARN * mass_kg:
        warnings.append(
            f"tool mass poorly determined: {mass_kg:.4f} ± {mass_sigma:.4f} kg ({100 * mass_sigma / mass_kg:.1f} %)"
        )
    rotation_sigma_deg = np.degrees(np.max(uncertainty["sensor_rotation_rad"]))
    if rotation_sigma_deg > ROTATION_SIGMA_WARN_DEG:
        warnings.append(f"sensor rotation poorly determined (1σ up to {rotation_sigma_deg:.2f}°)")
    return warnings


def check_weight_detectable(mass_kg: float, mass_sigma_kg: float) -> None:
    """Refuse when the tool's weight is indistinguishable from zero (no gravity signal to orient the sensor)."""
    if mass_kg < MASS_DETECTION_SIGMAS * mass_sigma_kg:
        raise IdentificationError(
            f"the tool's weight is lost in the noise: mass {mass_kg:.4f} ± {mass_sigma_kg:.4f} kg; "
            "the sensor rotation cannot be identified without a load"
        )
