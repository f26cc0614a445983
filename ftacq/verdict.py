"""The verdict on a calibration: PASS, WARN or FAIL against stated tolerances, with the reasons in plain words.

A verdict is the worst of its findings, one per check (thresholds are the module constants below; docs/verdict.md
explains them):

- **validation** — the held-out poses (never fitted) compensated with the calibration should read zero within
  what the sensor noise and the calibration's own 1σ predict. The error of held-out pose i is e_i (6,) with
  predicted covariance C_i = diag(se_i² + τ²) + σ_θ² G_i G_iᵀ + J_i Σ J_iᵀ (measured standard error, the fit's
  extra scatter, the robot's orientation error, the parameters' covariance propagated through the model,
  eqs 10-11). Σ_i e_iᵀ C_i⁻¹ e_i is χ² with 6M degrees of freedom when the calibration is right: its
  upper-tail probability p decides (WARN below :data:`VALIDATION_WARN_P`, FAIL below :data:`VALIDATION_FAIL_P`);
  one pose alone beyond the Bonferroni-corrected :data:`VALIDATION_POSE_P` is a WARN. validation.png draws
  each pose's d² against that one-pose limit (the test itself); the wrench plot shades
  ±:data:`ACCEPTANCE_BAND_SIGMAS` σ for scale.
- **drift** — the first pose measured again at the end: WARN above the configured thresholds, FAIL above
  :data:`DRIFT_FAIL_FACTOR` times them.
- **conditioning** — the pose set's scaled condition number and the parameters' 1σ against the identification's
  warning thresholds (ftacq.identification.diagnostics): WARN.
- **outliers** — poses the robust fit named disturbed: WARN for any, FAIL above :data:`OUTLIER_FAIL_FRACTION`.
- **poses** — poses planned but unreachable, or not measured (a stopped run): WARN or FAIL.

Everything here is pure (numbers in, a :class:`Verdict` out); :func:`held_out_covariance` needs an
:class:`ftacq.identification.IdentificationResult` and the held-out :class:`ftacq.posefile.PoseRecord`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from scipy import stats

PASS, WARN, FAIL = "PASS", "WARN", "FAIL"
STATUSES = (PASS, WARN, FAIL)
_RANK = {PASS: 0, WARN: 1, FAIL: 2}

VALIDATION_WARN_P = 1e-2
"""χ² test on the held-out poses: p below this (1 %) is a WARN ..."""
VALIDATION_FAIL_P = 1e-6
"""... and below this a FAIL (errors this large happen by chance less than once in a million calibrations)."""
VALIDATION_POSE_P = 1e-3
"""One held-out pose whose d² is beyond the χ²₆ quantile at this probability / M (Bonferroni) is a WARN."""
MIN_VALIDATION_POSES = 3
"""Fewer held-out poses than this: WARN (the check says little)."""
ACCEPTANCE_BAND_SIGMAS = 3.0
"""The wrench plot's scale band: ± this many predicted σ per axis (not the test: that is d², above)."""
DRIFT_FAIL_FACTOR = 3.0
"""Drift above the warning threshold is a WARN; above this many times the threshold a FAIL."""
OUTLIER_FAIL_FRACTION = 0.2
"""More than this fraction of the identification poses named disturbed is a FAIL (the set is not trustworthy)."""
MIN_EXPECTED_SIGMA = 1e-12
"""Floor of a predicted variance's square root (N, N·m), so exact synthetic data stay finite."""

CHECKS = ("validation", "drift", "conditioning", "outliers", "poses")


@dataclass(frozen=True)
class Finding:
    """The outcome of one check.

    Attributes:
        check: one of :data:`CHECKS`.
        status: PASS, WARN or FAIL.
        summary: one plain-words sentence for the technician (no method names).
        details: the method and the figures (for report.md and the details lines).
        figures: the numbers behind it (JSON-serialisable).
    """

    check: str
    status: str
    summary: str
    details: str = ""
    figures: Mapping[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"check": self.check, "status": self.status, "summary": self.summary, "details": self.details,
                "figures": _jsonable(dict(self.figures))}


@dataclass(frozen=True)
class Verdict:
    """PASS, WARN or FAIL (the worst finding) and the findings behind it."""

    status: str
    findings: tuple[Finding, ...]

    @property
    def reasons(self) -> list[str]:
        """The plain-words summaries of the findings that are not PASS, worst first."""
        bad = sorted((f for f in self.findings if f.status != PASS), key=lambda f: -_RANK[f.status])
        return [f.summary for f in bad]

    def finding(self, check: str) -> Finding | None:
        """Return the finding of one check, or None when it was not made."""
        return next((f for f in self.findings if f.check == check), None)

    def headline(self) -> str:
        """One line: the status and the main reason."""
        reasons = self.reasons
        if self.status == PASS:
            return "PASS: the calibration meets every tolerance"
        return f"{self.status}: {reasons[0]}" + (f" (and {len(reasons) - 1} more)" if len(reasons) > 1 else "")

    def to_dict(self) -> dict[str, Any]:
        """The verdict as stored in run.json and calibration.json (key ``verdict``)."""
        return {"status": self.status, "reasons": self.reasons, "findings": [f.to_dict() for f in self.findings]}


def judge(findings: Iterable[Finding]) -> Verdict:
    """Return the verdict of these findings: the worst status (PASS when there is none)."""
    findings = tuple(findings)
    for f in findings:
        if f.status not in STATUSES:
            raise ValueError(f"finding {f.check}: status {f.status!r} is not one of {', '.join(STATUSES)}")
    status = max((f.status for f in findings), key=_RANK.__getitem__, default=PASS)
    return Verdict(status, findings)


def format_verdict(verdict: Verdict, details: bool = True) -> str:
    """Return the verdict as text: the status line, the reasons in plain words, then (optionally) one detail
    line per check with the method and the figures."""
    lines = [f"verdict: {verdict.status}"]
    for f in sorted(verdict.findings, key=lambda f: -_RANK[f.status]):
        lines.append(f"  {f.status:<4}  {f.check:<12} {f.summary}")
    if details:
        lines.append("  details:")
        for f in verdict.findings:
            if f.details:
                lines.append(f"    {f.check}: {f.details}")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------ checks


def validation_finding(errors: np.ndarray, covariance: np.ndarray, labels: Sequence[str]) -> Finding:
    """Judge the held-out poses' compensation errors ``errors`` (M, 6) [N, N·m] against their predicted
    covariance ``covariance`` (M, 6, 6) (see :func:`held_out_covariance`); ``labels`` name the poses."""
    errors = np.asarray(errors, dtype=float).reshape(-1, 6)
    m = len(errors)
    if m == 0:
        return Finding("validation", WARN, "no held-out poses: the calibration was not checked on poses it was "
                                           "not fitted to", "no V poses measured")
    covariance = np.asarray(covariance, dtype=float).reshape(m, 6, 6)
    covariance = covariance + np.eye(6) * MIN_EXPECTED_SIGMA**2
    d2 = np.einsum("na,na->n", errors, np.linalg.solve(covariance, errors[:, :, None])[:, :, 0])
    total, dof = float(d2.sum()), 6 * m
    p = float(stats.chi2.sf(total, dof))
    ratio = float(np.sqrt(total / dof))
    sigma = np.sqrt(np.einsum("naa->na", covariance))
    force = np.linalg.norm(errors[:, :3], axis=1)
    torque = np.linalg.norm(errors[:, 3:], axis=1)
    worst = int(np.argmax(d2))
    pose_limit = float(stats.chi2.isf(VALIDATION_POSE_P / m, 6))
    beyond = [str(labels[int(i)]) for i in np.flatnonzero(d2 > pose_limit)]
    figures = {
        "poses": m, "chi2": total, "dof": dof, "p_value": p, "error_ratio": ratio, "pose_d2": d2.tolist(),
        "pose_d2_limit": pose_limit, "labels": [str(x) for x in labels],
        "band_sigmas": ACCEPTANCE_BAND_SIGMAS, "expected_sigma": sigma.tolist(),
        "max_force_error_n": float(force.max()), "max_torque_error_nm": float(torque.max()),
        "max_expected_force_sigma_n": float(np.max(np.linalg.norm(sigma[:, :3], axis=1))),
    }
    size = (f"largest |F| {force.max():.3g} N, |T| {torque.max():.3g} N·m")
    details = (f"χ² = {total:.1f} on {dof} degrees of freedom (p = {p:.2g}); RMS normalised error {ratio:.2f}; "
               f"worst pose {labels[worst]} at d² = {d2[worst]:.1f} (one-pose limit {pose_limit:.1f}); the "
               f"expected error per axis combines the measured noise of each mean, the fit's extra scatter, the "
               f"robot's orientation error and the calibration's parameter covariance")
    if p < VALIDATION_FAIL_P:
        status = FAIL
        summary = (f"the {m} held-out poses disagree with the calibration: their errors are {ratio:.1f}× what the "
                   f"sensor noise and the calibration's uncertainty allow ({size}, at {labels[worst]}); the tool, "
                   "its load or the sensor changed during the run, or something touched the tool")
    elif beyond:
        status = WARN
        summary = (f"held-out pose{'s' if len(beyond) > 1 else ''} {', '.join(beyond)} read"
                   f"{'' if len(beyond) > 1 else 's'} more than the noise allows ({size}): touched, or still moving?")
    elif p < VALIDATION_WARN_P:
        status = WARN
        summary = (f"the {m} held-out poses agree with the calibration only loosely: errors {ratio:.1f}× the "
                   f"expected size ({size})")
    elif m < MIN_VALIDATION_POSES:
        status = WARN
        summary = f"only {m} held-out pose{'s' if m > 1 else ''}: too few to check the calibration well ({size})"
    else:
        status = PASS
        summary = (f"the {m} held-out poses read zero within the sensor noise after compensation (errors "
                   f"{ratio:.2f}× the expected size; {size})")
    return Finding("validation", status, summary, details, figures)


def drift_finding(drift: np.ndarray, elapsed_s: float, warn_force_n: float, warn_torque_nm: float,
                  label: str = "") -> Finding:
    """Judge the bias drift ``drift`` (6,) [N, N·m] seen at the revisit of pose ``label`` after ``elapsed_s``."""
    drift = np.asarray(drift, dtype=float).reshape(6)
    force, torque = float(np.linalg.norm(drift[:3])), float(np.linalg.norm(drift[3:]))
    ratio = max(force / warn_force_n if warn_force_n > 0 else np.inf,
                torque / warn_torque_nm if warn_torque_nm > 0 else np.inf)
    figures = {"force_n": force, "torque_nm": torque, "elapsed_s": float(elapsed_s), "warn_force_n": warn_force_n,
               "warn_torque_nm": warn_torque_nm, "fail_factor": DRIFT_FAIL_FACTOR, "label": label}
    size = f"{force:.3g} N and {torque:.3g} N·m over {elapsed_s:.0f} s"
    details = (f"pose {label} measured again at the end: |ΔF| {force:.4f} N, |ΔT| {torque:.5f} N·m; warning "
               f"thresholds {warn_force_n:g} N, {warn_torque_nm:g} N·m, failure at {DRIFT_FAIL_FACTOR:g}× them")
    if ratio > DRIFT_FAIL_FACTOR:
        return Finding("drift", FAIL, f"the sensor drifted {size}, over {DRIFT_FAIL_FACTOR:g}× the allowed drift: "
                                      "let it warm up (about 30 min powered) and calibrate again", details, figures)
    if ratio > 1.0:
        return Finding("drift", WARN, f"the sensor drifted {size}, more than allowed: the biases may already be "
                                      "off; a warmed-up sensor drifts less", details, figures)
    return Finding("drift", PASS, f"the sensor's zero stayed put ({size}; allowed {warn_force_n:g} N, "
                                  f"{warn_torque_nm:g} N·m)", details, figures)


def conditioning_finding(condition_number: float, weak_warnings: Sequence[str], weakest: str = "") -> Finding:
    """Judge how well the pose set determines the parameters: ``weak_warnings`` are the identification's
    warnings about weakly determined parameters (ftacq.identification.diagnostics.parameter_warnings)."""
    from ftacq.identification.diagnostics import WEAK_CONDITION

    figures = {"condition_number": float(condition_number), "weak_condition": WEAK_CONDITION,
               "warnings": list(weak_warnings)}
    details = (f"scaled condition number of the Fisher matrix JᵀWJ {condition_number:.3g} (warning above "
               f"{WEAK_CONDITION:.0e})" + (f"; weakest combination: {weakest}" if weakest else ""))
    if weak_warnings:
        return Finding("conditioning", WARN, "the poses pin some parameters down poorly: "
                       + "; ".join(weak_warnings), details, figures)
    return Finding("conditioning", PASS, "the poses tilt the tool enough to determine every parameter", details,
                   figures)


def outlier_finding(outliers: Sequence[str], n_poses: int) -> Finding:
    """Judge the poses the robust fit named disturbed (``outliers`` labels of ``n_poses``)."""
    k = len(outliers)
    figures = {"outliers": list(outliers), "poses": int(n_poses), "fail_fraction": OUTLIER_FAIL_FRACTION}
    details = ("robust re-weighted fit; a pose is an outlier when its d² exceeds the χ²₆ limit corrected for the "
               f"number of poses; {k} of {n_poses}")
    if k == 0:
        return Finding("outliers", PASS, "no pose looked disturbed", details, figures)
    names = ", ".join(outliers[:8]) + (" …" if k > 8 else "")
    if k > OUTLIER_FAIL_FRACTION * n_poses:
        return Finding("outliers", FAIL, f"{k} of {n_poses} poses looked disturbed ({names}): too many to trust the "
                                         "rest; check for contact, a loose cable or a moving tool", details, figures)
    return Finding("outliers", WARN, f"{k} of {n_poses} poses looked disturbed (contact or motion while "
                                     f"measuring) and were left out: {names}", details, figures)


def poses_finding(planned: Mapping[str, int], wanted: Mapping[str, int], measured: int, total: int,
                  stopped: str = "") -> Finding:
    """Judge what was measured against what was asked: ``planned``/``wanted`` poses per set ("A" the 24
    special orientations, "E" extra, "V" held out), ``measured`` of ``total`` measurements; ``stopped`` is the
    stop message of a run that did not finish."""
    figures = {"planned": dict(planned), "wanted": dict(wanted), "measured": int(measured), "total": int(total)}
    details = "planned/asked per set: " + ", ".join(f"{s} {planned.get(s, 0)}/{wanted.get(s, 0)}" for s in wanted)
    if stopped or measured < total:
        return Finding("poses", FAIL, f"the run did not finish: {measured} of {total} poses measured"
                       + (f" ({stopped})" if stopped else "") + "; resume it to get a calibration", details, figures)
    short = []
    if planned.get("A", 0) < wanted.get("A", 0):
        short.append(f"{wanted['A'] - planned.get('A', 0)} of the {wanted['A']} special orientations could not be "
                     "reached")
    if wanted.get("V", 0) and planned.get("V", 0) < min(wanted["V"], MIN_VALIDATION_POSES):
        short.append(f"only {planned.get('V', 0)} of {wanted['V']} held-out poses could be reached")
    if planned.get("E", 0) < wanted.get("E", 0) / 2:
        short.append(f"only {planned.get('E', 0)} of {wanted['E']} extra poses could be reached")
    if short:
        return Finding("poses", WARN, "; ".join(short) + " (the cell's reach or obstacles)", details, figures)
    return Finding("poses", PASS, f"all {measured} poses measured", details, figures)


def identification_findings(result: Any, held_out: Any | None = None) -> list[Finding]:
    """Return the validation, conditioning and outlier findings of an identification.

    ``result`` is the :class:`ftacq.identification.IdentificationResult`; ``held_out`` the held-out poses
    (:class:`ftacq.posefile.PoseRecord`, never fitted; None or empty: the validation finding says so).
    """
    from ftacq.identification.diagnostics import parameter_warnings

    cal = result.calibration
    if held_out is not None and len(held_out):
        errors = np.asarray(cal.compensate(held_out.wrench, held_out.flange_R_base), dtype=float).reshape(-1, 6)
        validation = validation_finding(errors, held_out_covariance(result, held_out), list(held_out.labels))
    else:
        validation = validation_finding(np.zeros((0, 6)), np.zeros((0, 6, 6)), [])
    diag = result.diagnostics
    from ftacq.identification.diagnostics import _PARAMETER_TEXT

    weakest = ", ".join(_PARAMETER_TEXT.get(str(x), str(x)) for x in diag.get("weakest_parameters", []))
    condition = float(diag.get("condition_number", float("nan")))
    weak = parameter_warnings(cal.uncertainty, cal.mass_kg, {"condition_number": condition, "weakest_text": weakest})
    return [validation, conditioning_finding(condition, weak, weakest),
            outlier_finding(list(result.outliers), len(result.labels))]


# ------------------------------------------------------------------------------------------------ noise


def held_out_covariance(result: Any, record: Any) -> np.ndarray:
    """Return the predicted covariance (M, 6, 6) of the compensation error at held-out poses.

    ``result`` is the :class:`ftacq.identification.IdentificationResult`, ``record`` the held-out poses
    (:class:`ftacq.posefile.PoseRecord`). C_i = diag(se_i² + τ²) + σ_θ² G_i G_iᵀ + J_i Σ J_iᵀ, with se the
    pose's measured standard error (std/√count) when known (else the fit's typical per-channel noise), τ the
    fit's extra scatter, σ_θ the robot's orientation error, G its sensitivity (pose_error.py), J the model's
    Jacobian (refine.py) and Σ the parameters' covariance.
    """
    from ftacq.identification.pose_error import orientation_sensitivity
    from ftacq.identification.refine import ModelParameters, gravity_in_sensor, jacobian

    cal = result.calibration
    rotations = np.asarray(record.flange_R_base, dtype=float)
    m = len(rotations)
    noise = dict(cal.metadata.get("noise", {}))
    standard_error = record.standard_error
    measured_noise = str(noise.get("source", "")).startswith("measured")
    if standard_error is not None and measured_noise:
        scatter = np.asarray(noise.get("extra_scatter", np.zeros(6)), dtype=float)
        variance = standard_error**2 + scatter**2
    else:  # the fit's own noise per channel, as it used it (relative weights or residual scale)
        variance = np.tile(np.median(np.asarray(result.noise, dtype=float) ** 2, axis=0), (m, 1))
    out = np.zeros((m, 6, 6))
    index = np.arange(6)
    out[:, index, index] = variance
    params = ModelParameters(np.array(cal.sensor_rotation), np.array(cal.gravity_base), np.array(cal.force_bias),
                             np.array(cal.center_of_mass), np.array(cal.torque_bias))
    orientation_rad = np.radians(float(noise.get("orientation_error_deg", 0.0)))
    if orientation_rad > 0.0:
        g = orientation_sensitivity(gravity_in_sensor(params, rotations), params.center_of_mass)
        out += orientation_rad**2 * (g @ g.transpose(0, 2, 1))
    sigma = getattr(result, "parameter_covariance", None)
    if sigma is not None:
        j = jacobian(params, rotations)
        out += j @ np.asarray(sigma, dtype=float) @ j.transpose(0, 2, 1)
    return out


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


__all__ = ["PASS", "WARN", "FAIL", "Finding", "Verdict", "judge", "format_verdict", "validation_finding",
           "drift_finding", "conditioning_finding", "outlier_finding", "poses_finding", "held_out_covariance",
           "identification_findings",
           "ACCEPTANCE_BAND_SIGMAS"]
