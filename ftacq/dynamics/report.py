"""Plain-text report of a dynamics identification (printed by ``ftacq calibrate --dynamic`` and ``ftacq identify
--motion``), with the truth beside it when the cell is simulated."""

from __future__ import annotations

import numpy as np

from ftacq.dynamics.identify import DynamicsResult


def _matrix_lines(name: str, matrix: np.ndarray, scale: float, unit: str) -> list[str]:
    rows = [" ".join(f"{scale * v:+9.4f}" for v in row) for row in np.asarray(matrix)]
    return [f"  {name:<22}[{rows[0]}]  {unit}"] + [f"  {'':<22}[{row}]" for row in rows[1:]]


def format_dynamics(result: DynamicsResult, truth_inertia: np.ndarray | None = None,
                    truth_mass_kg: float | None = None, truth_com_m: np.ndarray | None = None) -> str:
    """Return the report: inertia (and its 1σ, and the truth if given), mass / centre of mass source, lag,
    conditioning, held-out error static vs dynamic."""
    cal = result.calibration
    lines = ["tool inertia about its centre of mass (sensor frame), identified from motion:"]
    lines += _matrix_lines("identified", result.inertia, 1e3, "g·m²")
    lines += _matrix_lines("1σ", result.inertia_sigma, 1e3, "g·m²")
    if truth_inertia is not None:
        truth = np.asarray(truth_inertia, dtype=float)
        lines += _matrix_lines("true (simulation)", truth, 1e3, "g·m²")
        error = np.linalg.norm(result.inertia - truth) / np.linalg.norm(truth)
        lines.append(f"  inertia error (Frobenius): {100 * error:.2f} % of the true inertia")
    moments = np.linalg.eigvalsh(result.inertia)
    lines.append("  principal moments: " + ", ".join(f"{1e3 * m:.4f}" for m in moments) + " g·m²"
                 + (" (the unconstrained fit was not a physical body: constrained)" if result.constrained else
                    " (physically consistent without constraint)"))
    mass_source = "motion" if result.mass_from_motion else "static poses"
    com_source = "motion" if result.com_from_motion else "static poses"
    lines.append(f"mass {cal.mass_kg:.5f} kg (from {mass_source}: 1σ static {result.mass_sigma_static:.2g} kg, "
                 f"motion {result.mass_sigma_motion:.2g} kg); centre of mass from {com_source} "
                 f"(1σ static {1e3 * np.linalg.norm(result.com_sigma_static):.3g} mm, motion "
                 f"{1e3 * np.linalg.norm(result.com_sigma_motion):.3g} mm)")
    if truth_mass_kg is not None and truth_com_m is not None:
        lines.append(f"  true (simulation): mass {truth_mass_kg:.5f} kg, centre of mass "
                     + " ".join(f"{1e3 * v:+.3f}" for v in truth_com_m) + " mm")
    servo = ("" if result.servo_lag_s is None else
             f"; the arm followed its target {1e3 * result.servo_lag_s:.2f} ms late (actual_qd against target_qd)")
    lines.append(f"sensor lag behind the arm: {1e3 * result.lag_s:+.2f} ms (measured from the motion){servo}")
    lines.append("biases during the motion minus the static ones: F "
                 + " ".join(f"{v:+.4f}" for v in result.bias_offset[:3]) + " N, T "
                 + " ".join(f"{v:+.5f}" for v in result.bias_offset[3:]) + " N·m (fitted beside the inertia); "
                 f"regressor condition number {result.condition_number:.3g}; {result.rows} robot samples fitted")
    lines.append(f"held-out motion ({result.held_out_rows} robot samples, the last part of the excitation), "
                 "compensated wrench RMS (max):")
    for name, rms, worst in (("static model ", result.held_out_rms_static, result.held_out_max_static),
                             ("dynamic model", result.held_out_rms_dynamic, result.held_out_max_dynamic)):
        lines.append(f"  {name}  F " + " ".join(f"{v:.4f}" for v in rms[:3]) + " N, T "
                     + " ".join(f"{v:.5f}" for v in rms[3:]) + " N·m  (max F "
                     + f"{worst[:3].max():.4f} N, T {worst[3:].max():.5f} N·m)")
    return "\n".join(lines) + "\n"
