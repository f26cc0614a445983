"""Conditioning diagnostics: refuse pose sets that cannot identify the calibration, warn about weak ones.

Checks before fitting (cheap, from the orientations only): enough poses, more than one orientation, and
rotations about more than one axis (rotating about a single axis u leaves the weight's component along u
indistinguishable from the force bias). After fitting: the column-scaled Fisher matrix JᵀWJ (rank and
condition number) and the 1σ of each parameter against named thresholds.
"""

from __future__ import annotations

import numpy as np

from ftacq.errors import IdentificationError
from ftacq.identification.refine import PARAMETER_NAMES

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
}


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
    scale = np.sqrt(np.maximum(np.diag(information), 1e-300))
    scaled = information / np.outer(scale, scale)
    eigenvalues, eigenvectors = np.linalg.eigh(0.5 * (scaled + scaled.T))
    condition = float(eigenvalues[-1] / max(eigenvalues[0], 1e-300))
    weakest = eigenvectors[:, 0]
    involved = sorted(
        {PARAMETER_NAMES[int(k) // 3] for k in np.flatnonzero(np.abs(weakest) > 0.3)},
        key=PARAMETER_NAMES.index,
    )
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
