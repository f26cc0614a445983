"""The technician's text report of an identification: parameters with 1σ and units, residuals, warnings."""

from __future__ import annotations

import numpy as np

from ftacq.channels import WRENCH_COLUMNS
from ftacq.identification.diagnostics import NOMINAL_TILT_WARN_DEG
from ftacq.mounts import MOUNTS

MAX_RESIDUAL_ROWS = 100
"""Longer records list only the poses with the largest residuals (outliers always included)."""
SUMMARY_ROWS = 10
"""The console summary (``limit``) lists at most this many poses per list (outliers, disturbed poses, and the
residuals of a record longer than :data:`SUMMARY_ALL_RESIDUALS`): the worst; the full report has the rest."""
SUMMARY_ALL_RESIDUALS = 64
"""The summary still lists every pose's residual up to this many poses (a full calibration run)."""
DISTURBED = "looks disturbed"
"""The words of a per-pose outlier warning (ftacq.identification), grouped in the summary."""


def _vector(values, sigmas, scale: float = 1.0, digits: int = 4) -> str:
    return "[" + ", ".join(f"{v * scale:+.{digits}f} ± {s * scale:.{digits}f}" for v, s in zip(values, sigmas)) + "]"


def _zyx_deg(rotation: np.ndarray) -> tuple[float, float, float]:
    """Return (yaw Z, pitch Y, roll X) in degrees of R = Rz Ry Rx (the paper's Table I convention)."""
    pitch = np.degrees(np.arcsin(np.clip(-rotation[2, 0], -1.0, 1.0)))
    yaw = np.degrees(np.arctan2(rotation[1, 0], rotation[0, 0]))
    roll = np.degrees(np.arctan2(rotation[2, 1], rotation[2, 2]))
    return float(yaw), float(pitch), float(roll)


def validation_errors(calibration, record) -> dict:
    """Return the compensation errors on held-out contact-free poses: labels, errors (M, 6), max |e| and RMS per axis.

    ``record`` is a :class:`ftacq.posefile.PoseRecord`; the error is the compensated wrench (ideally 0), with the
    bias of the pose's own time when the calibration models a bias drift (ftacq.identification.trend).
    """
    from ftacq.identification.trend import bias_drift_at

    errors = calibration.compensate(record.wrench, record.flange_R_base) - bias_drift_at(calibration, record)
    return {
        "labels": list(record.labels),
        "columns": list(WRENCH_COLUMNS),
        "errors": errors.tolist(),
        "max_abs": np.abs(errors).max(axis=0).tolist(),
        "rms": np.sqrt(np.mean(errors**2, axis=0)).tolist(),
        "max_force_norm": float(np.linalg.norm(errors[:, :3], axis=1).max()),
        "max_torque_norm": float(np.linalg.norm(errors[:, 3:], axis=1).max()),
    }


def format_identification_report(result, validation: dict | None = None, limit: int | None = None) -> str:
    """Return a plain-text report of an :class:`ftacq.identification.IdentificationResult`.

    ``validation`` (from :func:`validation_errors`) adds the compensation error on held-out poses. ``limit``
    (the console's summary, e.g. :data:`SUMMARY_ROWS`): each per-pose list (outliers, disturbed-pose warnings,
    the residuals beyond :data:`SUMMARY_ALL_RESIDUALS` poses) shows its ``limit`` worst poses and counts the rest,
    which the full report (no limit) lists.
    """
    cal = result.calibration
    unc = cal.uncertainty
    meta = cal.metadata
    diag = result.diagnostics
    n = len(result.labels)
    lines: list[str] = []
    add = lines.append
    add(f"ftacq identification — {n} poses, method {result.method_used}")
    add(f"  {meta.get('method_detail', '')}")
    if "refine" in result.method_used:
        refinement = f"refinement {'converged' if result.converged else 'NOT converged'} ({result.iterations} iterations)"
    else:
        refinement = "no refinement (the paper's closed form)"
    add(
        f"  special orientations found: {diag.get('special_orientations_present', 0)} of 24; "
        f"outliers: {len(result.outliers)}; {refinement}"
    )
    add("")
    add("Calibration (value ± 1σ)")
    rotation = cal.sensor_rotation
    rot_sigma_deg = np.degrees(np.asarray(unc.get("sensor_rotation_rad", [0.0] * 3)))
    add("  sensor_rotation (sensor_R_flange):")
    for row in rotation:
        add("      [" + ", ".join(f"{v:+.6f}" for v in row) + "]")
    yaw, pitch, roll = _zyx_deg(rotation)
    add(
        f"    as Z-Y-X angles: {yaw:+.3f}°, {pitch:+.3f}°, {roll:+.3f}°; "
        f"1σ about sensor x, y, z: {rot_sigma_deg[0]:.3f}°, {rot_sigma_deg[1]:.3f}°, {rot_sigma_deg[2]:.3f}°"
    )
    add(f"  force_bias        N    {_vector(cal.force_bias, unc.get('force_bias', [0] * 3))}")
    add(f"  torque_bias       N·m  {_vector(cal.torque_bias, unc.get('torque_bias', [0] * 3), digits=5)}")
    add(f"  gravity_base      N    {_vector(cal.gravity_base, unc.get('gravity_base', [0] * 3))}")
    add(f"  mass              kg   {cal.mass_kg:.5f} ± {unc.get('mass_kg', 0.0):.5f}")
    add(
        f"  center_of_mass    mm   {_vector(cal.center_of_mass, unc.get('center_of_mass_m', [0] * 3), 1000.0, 3)}"
    )
    alpha, beta = cal.base_tilt_deg
    tilt_sigma = unc.get("base_tilt_deg", [0.0, 0.0])
    add(f"  base_tilt (α, β)  deg  {alpha:+.4f} ± {tilt_sigma[0]:.4f}, {beta:+.4f} ± {tilt_sigma[1]:.4f}")
    if "mount" in meta:
        rel = meta["base_tilt_relative_deg"]
        kind = "nominal" if meta["mount"] in MOUNTS else "declared"
        add(
            f"  tilt relative to the {kind} {meta['mount']} mount: α {rel[0]:+.4f}°, β {rel[1]:+.4f}° "
            f"(gravity {meta['tilt_from_mount_deg']:.4f}° off the {kind} direction)"
        )
    else:
        off = meta.get("tilt_from_nearest_mount_deg", 0.0)
        direction = np.asarray(cal.gravity_base) / max(float(np.linalg.norm(cal.gravity_base)), 1e-300)
        declare = "" if off <= NOMINAL_TILT_WARN_DEG else (
            "; a mount like this is declared with --gravity-direction " + ",".join(f"{v:.3f}" for v in direction))
        add(f"  nearest nominal mount: {meta.get('nearest_mount')} ({off:.3f}° off{declare})")
    noise = meta.get("noise", {})
    if noise:
        rms = noise.get("rms_residual", [])
        if rms:
            add(
                "  residual RMS (inliers): F "
                + ", ".join(f"{v:.4f}" for v in rms[:3])
                + " N; T "
                + ", ".join(f"{v:.5f}" for v in rms[3:])
                + f" N·m; noise {noise.get('source', '')}"
            )
        orientation_deg = noise.get("orientation_error_deg", 0.0)
        add(
            f"  robot orientation error: {orientation_deg:.4f}° (1σ per axis, estimated; modelled in the weights)"
            if orientation_deg > 0.0
            else "  robot orientation error: not detected in the residuals"
        )
    drift = meta.get("drift_model", {})
    if drift.get("model") == "linear":
        per = "h" if drift.get("unit") == "h" else "row"
        rate = np.asarray(drift.get("bias_rate", np.zeros(6)), dtype=float)
        add(f"  bias drift linear, {drift.get('chosen', '')}: F "
            + ", ".join(f"{v:+.4g}" for v in rate[:3]) + f" N/{per}; T "
            + ", ".join(f"{v:+.4g}" for v in rate[3:]) + f" N·m/{per}; biases above are those at the end of the "
            "recording")
    elif drift:
        add(f"  bias drift: not modelled ({drift.get('chosen', '')})")
    add(f"  conditioning: scaled condition number {diag.get('condition_number', float('nan')):.3g}")
    add("")
    add("Per-pose residuals (measured − predicted; |F| N, |T| N·m; weight 1 = fully trusted)")
    residual = np.asarray(result.residuals)
    force_norm = np.linalg.norm(residual[:, :3], axis=1)
    torque_norm = np.linalg.norm(residual[:, 3:], axis=1)
    order = np.arange(n)
    outlier_set = set(result.outliers)
    rows = limit if limit is not None and n > SUMMARY_ALL_RESIDUALS else MAX_RESIDUAL_ROWS
    statistic = np.asarray(result.pose_statistic, dtype=float)
    if n > rows:
        worst = np.argsort(-statistic)[:rows]
        order = np.sort(worst)
        add(f"  (the {rows} poses with the largest residuals of {n})")
    add(f"  {'label':<10} {'set':<4} {'fx':>9} {'fy':>9} {'fz':>9} {'tx':>9} {'ty':>9} {'tz':>9} {'|F|':>8} {'|T|':>8} {'weight':>6}")
    for i in order:
        label = result.labels[i]
        flag = "  OUTLIER" if label in outlier_set else ""
        add(
            f"  {label:<10} {result.sets[i]:<4} "
            + " ".join(f"{v:+9.4f}" for v in residual[i, :3])
            + " "
            + " ".join(f"{v:+9.5f}" for v in residual[i, 3:])
            + f" {force_norm[i]:8.4f} {torque_norm[i]:8.5f} {result.weights[i]:6.3f}{flag}"
        )
    if validation is not None:
        add("")
        add(f"Validation: compensation error on {len(validation['labels'])} held-out poses (sets V, D; ideally 0)")
        add("  max |e|  F " + ", ".join(f"{v:.4f}" for v in validation["max_abs"][:3]) + " N; T "
            + ", ".join(f"{v:.5f}" for v in validation["max_abs"][3:]) + " N·m")
        add("  RMS      F " + ", ".join(f"{v:.4f}" for v in validation["rms"][:3]) + " N; T "
            + ", ".join(f"{v:.5f}" for v in validation["rms"][3:]) + " N·m")
        add(f"  max |F| {validation['max_force_norm']:.4f} N, max |T| {validation['max_torque_norm']:.5f} N·m")
    add("")
    rank = {label: -statistic[i] for i, label in enumerate(result.labels)}
    outliers = list(result.outliers)
    if limit is not None and len(outliers) > limit:
        shown_outliers = sorted(outliers, key=lambda label: rank.get(label, 0.0))[:limit]
        add(f"Outliers: {len(outliers)} of {n} poses; the {limit} worst: {', '.join(shown_outliers)}")
    else:
        add("Outliers: " + (", ".join(outliers) if outliers else "none"))
    warnings = list(result.warnings)
    disturbed = [w for w in warnings if DISTURBED in w]
    if limit is not None and len(disturbed) > limit:
        def pose_rank(warning: str) -> float:
            return rank.get(warning.split()[1], 0.0)

        kept = set(sorted(disturbed, key=pose_rank)[:limit])
        warnings = [w for w in warnings if DISTURBED not in w or w in kept]
        warnings.append(f"… and {len(disturbed) - limit} more poses look disturbed (the {limit} worst above)")
    if warnings:
        add("Warnings:")
        for warning in warnings:
            add(f"  - {warning}")
    else:
        add("Warnings: none")
    return "\n".join(lines) + "\n"

