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
  :data:`DRIFT_FAIL_FACTOR` times them; WARN when that revisit failed (the calibration stands on the poses
  measured before it, but its drift is unknown).
- **conditioning** — the pose set's scaled condition number and the parameters' 1σ against the identification's
  warning thresholds (ftacq.identification.diagnostics): WARN.
- **outliers** — poses the robust fit named disturbed: WARN for any, FAIL above :data:`OUTLIER_FAIL_FRACTION`.
- **poses** — poses planned but unreachable, or not measured (a stopped run): WARN or FAIL.
- **trend** — the fit's residuals tested for a straight-line trend against the poses' times (row order without
  times; ftacq.identification.trend): the drift it implies over the recording against the drift thresholds (WARN
  above, FAIL above :data:`DRIFT_FAIL_FACTOR` times); a drift the fit modelled (``--drift linear``) is reported
  with its rate, WARN above the thresholds (the sensor was still drifting at the end).
- **fit** — whether the refinement converged: WARN when it stopped at its iteration limit with the parameters
  still moving less than :data:`UNCONVERGED_FAIL_SIGMAS` σ per re-weighting, FAIL beyond.

With many held-out poses (:data:`MISMATCH_MIN_POSES`) the validation also weighs practical significance: errors
beyond the noise that are spread over all poses are named model mismatch, with their size (RMS, N and N·m,
beyond what the noise explains) against the data's resolution and a user tolerance (``--tolerance-force``,
``--tolerance-torque``; CELL.toml ``sampling.mismatch_tolerance_*``): WARN within the tolerance, FAIL beyond.

Over 500 lines: one module holds every check so that their thresholds and wording are read in one place.

Everything here is pure (numbers in, a :class:`Verdict` out); :func:`held_out_covariance` needs an
:class:`ftacq.identification.IdentificationResult` and the held-out :class:`ftacq.posefile.PoseRecord`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from scipy.special import chdtrc, chdtri  # χ² tails: scipy.stats's own functions, without its 1 s import

from ftacq.posesets import RANDOM_SET, SPECIAL_SET, VALIDATION_SET

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

MISMATCH_MIN_POSES = 30
"""With at least this many held-out poses, errors beyond the noise are judged by their size (model mismatch)."""
UNCONVERGED_FAIL_SIGMAS = 1.0
"""A fit that stopped at its iteration limit is a FAIL when its last re-weighting still moved a parameter more
than this many σ (else a WARN)."""

CHECKS = ("validation", "drift", "conditioning", "outliers", "poses", "trend", "fit", "sensor")


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


def validation_finding(errors: np.ndarray, covariance: np.ndarray, labels: Sequence[str],
                       tolerance: tuple[float, float] | None = None,
                       resolution: Sequence[float] | None = None) -> Finding:
    """Judge the held-out poses' compensation errors ``errors`` (M, 6) [N, N·m] against their predicted
    covariance ``covariance`` (M, 6, 6) (see :func:`held_out_covariance`); ``labels`` name the poses.

    ``tolerance`` (N, N·m): the size of model mismatch the user accepts (per axis, RMS); with at least
    :data:`MISMATCH_MIN_POSES` poses, a χ² excess within it is a WARN naming the mismatch, beyond it a FAIL.
    ``resolution`` (6,): the data's step per channel (0 when unknown), quoted beside the mismatch."""
    errors = np.asarray(errors, dtype=float).reshape(-1, 6)
    m = len(errors)
    if m == 0:
        return Finding("validation", WARN, "no held-out poses: the calibration was not checked on poses it was "
                                           "not fitted to", "no V poses measured")
    covariance = np.asarray(covariance, dtype=float).reshape(m, 6, 6)
    covariance = covariance + np.eye(6) * MIN_EXPECTED_SIGMA**2
    d2 = np.einsum("na,na->n", errors, np.linalg.solve(covariance, errors[:, :, None])[:, :, 0])
    total, dof = float(d2.sum()), 6 * m
    p = float(chdtrc(dof, total))
    ratio = float(np.sqrt(total / dof))
    sigma = np.sqrt(np.einsum("naa->na", covariance))
    force = np.linalg.norm(errors[:, :3], axis=1)
    torque = np.linalg.norm(errors[:, 3:], axis=1)
    worst = int(np.argmax(d2))
    pose_limit = float(chdtri(6, VALIDATION_POSE_P / m))
    beyond = [str(labels[int(i)]) for i in np.flatnonzero(d2 > pose_limit)]
    figures = {
        "poses": m, "chi2": total, "dof": dof, "p_value": p, "error_ratio": ratio, "pose_d2": d2.tolist(),
        "pose_d2_limit": pose_limit, "labels": [str(x) for x in labels], "errors": errors.tolist(),
        "band_sigmas": ACCEPTANCE_BAND_SIGMAS, "expected_sigma": sigma.tolist(),
        "max_force_error_n": float(force.max()), "max_torque_error_nm": float(torque.max()),
        "max_expected_force_sigma_n": float(np.max(np.linalg.norm(sigma[:, :3], axis=1))),
    }
    size = (f"largest |F| {force.max():.3g} N, |T| {torque.max():.3g} N·m")
    # what the noise does not explain, per axis (RMS over the poses), as one force and one torque figure
    excess = np.sqrt(np.maximum(np.mean(errors**2, axis=0) - np.mean(sigma**2, axis=0), 0.0))
    excess_force, excess_torque = float(np.max(excess[:3])), float(np.max(excess[3:]))
    figures["mismatch_rms_per_axis"] = excess.tolist()
    figures["mismatch_force_n"], figures["mismatch_torque_nm"] = excess_force, excess_torque
    if tolerance is not None:
        figures["tolerance_force_n"], figures["tolerance_torque_nm"] = float(tolerance[0]), float(tolerance[1])
    resolution_text = "the data's resolution not visible in the values"
    if resolution is not None and np.any(np.asarray(resolution) > 0):
        res = np.asarray(resolution, dtype=float)
        figures["resolution"] = res.tolist()
        resolution_text = f"data resolution {np.max(res[:3]):.2g} N, {np.max(res[3:]):.2g} N·m"
    details = (f"χ² = {total:.1f} on {dof} degrees of freedom (p = {p:.2g}); RMS normalised error {ratio:.2f}; "
               f"worst pose {labels[worst]} at d² = {d2[worst]:.1f} (one-pose limit {pose_limit:.1f}); the "
               f"expected error per axis combines the measured noise of each mean, the fit's extra scatter, the "
               f"robot's orientation error and the calibration's parameter covariance")
    if p < VALIDATION_WARN_P and m >= MISMATCH_MIN_POSES and tolerance is not None:
        within = excess_force <= tolerance[0] and excess_torque <= tolerance[1]
        status = WARN if within else FAIL
        summary = (f"model mismatch: the {m} held-out poses read {ratio:.2f}× the expected error; what the noise "
                   f"does not explain is {excess_force:.3g} N and {excess_torque:.3g} N·m RMS per axis ("
                   f"{resolution_text}; tolerance {tolerance[0]:g} N, {tolerance[1]:g} N·m): "
                   + ("within the tolerance, the calibration is usable to that accuracy" if within else
                      "beyond the tolerance: the model does not describe this tool or these data (a cable, a "
                      "loose or flexible part, a frame or unit mix-up)"))
        details += (f"; model mismatch {excess_force:.4g} N, {excess_torque:.4g} N·m RMS per axis beyond the "
                    f"expected error (statistically clear with {m} poses: p = {p:.2g})")
    elif p < VALIDATION_FAIL_P:
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


def drift_not_checked_finding(reason: str) -> Finding:
    """Judge a run whose drift-check revisit failed (``reason``: what failed and why): WARN, the drift is unknown."""
    return Finding("drift", WARN, f"the drift check failed, so the sensor's drift over the run is unknown ({reason}); "
                                  "the calibration uses every pose measured before it", f"revisit failed: {reason}",
                   {"skipped": reason})


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
    """Judge what was measured against what was asked: ``planned``/``wanted`` poses per set (ftacq.posesets:
    "A" the 24 special orientations, "E" extra, "V" held out), ``measured`` of ``total`` measurements; ``stopped`` is the
    stop message of a run that did not finish."""
    figures = {"planned": dict(planned), "wanted": dict(wanted), "measured": int(measured), "total": int(total)}
    details = "planned/asked per set: " + ", ".join(f"{s} {planned.get(s, 0)}/{wanted.get(s, 0)}" for s in wanted)
    if stopped or measured < total:
        return Finding("poses", FAIL, f"the run did not finish: {measured} of {total} poses measured"
                       + (f" ({stopped})" if stopped else "") + "; resume it to get a calibration", details, figures)
    short = []
    special, extra, held_out = SPECIAL_SET, RANDOM_SET, VALIDATION_SET
    if planned.get(special, 0) < wanted.get(special, 0):
        short.append(f"{wanted[special] - planned.get(special, 0)} of the {wanted[special]} special orientations "
                     "could not be reached")
    if wanted.get(held_out, 0) and planned.get(held_out, 0) < min(wanted[held_out], MIN_VALIDATION_POSES):
        short.append(f"only {planned.get(held_out, 0)} of {wanted[held_out]} held-out poses could be reached")
    if planned.get(extra, 0) < wanted.get(extra, 0) / 2:
        short.append(f"only {planned.get(extra, 0)} of {wanted[extra]} extra poses could be reached")
    if short:
        return Finding("poses", WARN, "; ".join(short) + " (the cell's reach or obstacles)", details, figures)
    return Finding("poses", PASS, f"all {measured} poses measured", details, figures)


def trend_finding(trend: Mapping[str, Any], drift_model: Mapping[str, Any]) -> Finding:
    """Judge the drift inside the recording: ``trend`` the residuals' trend (ftacq.identification.trend
    ``ResidualTrend.to_dict``), ``drift_model`` the calibration's ``metadata["drift_model"]``."""
    from ftacq.identification.trend import TREND_P

    warn_force, warn_torque = float(drift_model.get("warn_force_n", 0.5)), float(drift_model.get("warn_torque_nm", 0.02))
    unit = str(trend.get("unit", "row"))
    span = float(trend.get("span", 0.0))
    per = "per hour" if unit == "h" else "per 100 rows"
    per_factor = 1.0 if unit == "h" else 100.0
    over = f"{span * 60:.0f} min" if unit == "h" else f"{span:.0f} rows"
    figures = {"trend": dict(trend), "drift_model": dict(drift_model), "warn_force_n": warn_force,
               "warn_torque_nm": warn_torque, "fail_factor": DRIFT_FAIL_FACTOR, "p_limit": TREND_P}
    if drift_model.get("model") == "linear":
        rate = np.asarray(drift_model.get("bias_rate", np.zeros(6)), dtype=float)
        change = rate * span
        force, torque = float(np.linalg.norm(change[:3])), float(np.linalg.norm(change[3:]))
        rate_text = (f"{per_factor * np.linalg.norm(rate[:3]):.3g} N and {per_factor * np.linalg.norm(rate[3:]):.3g} "
                     f"N·m {per}")
        details = (f"linear bias drift fitted, {drift_model.get('chosen', '')}; time from "
                   f"{drift_model.get('source', '?')}; rates {np.round(per_factor * rate, 6).tolist()} {per}; the "
                   "calibration's biases are those at the end of the recording")
        status = WARN if (force > warn_force or torque > warn_torque) else PASS
        summary = (f"the sensor's zero drifted {rate_text} during the recording ({force:.3g} N, {torque:.3g} N·m "
                   f"over {over}); the fit modelled it and keeps the biases of the end of the run"
                   + ("; it was still drifting: let the sensor warm up, or tare before use" if status == WARN else ""))
        return Finding("trend", status, summary, details, figures)
    rate = np.asarray(trend.get("rate", np.zeros(6)), dtype=float)
    change = rate * span
    force, torque = float(np.linalg.norm(change[:3])), float(np.linalg.norm(change[3:]))
    p = float(trend.get("p_value", 1.0))
    ratio = max(force / warn_force if warn_force > 0 else np.inf, torque / warn_torque if warn_torque > 0 else np.inf)
    details = (f"straight line through the residuals against time ({drift_model.get('source', 'row order')}): "
               f"χ² = {float(trend.get('chi2', 0.0)):.1f} on 6 degrees of freedom (p = {p:.2g}, significant below "
               f"{TREND_P:g}); {force:.4g} N, {torque:.4g} N·m over {over} "
               f"({per_factor * force / max(span, 1e-300):.3g} N, {per_factor * torque / max(span, 1e-300):.3g} N·m "
               f"{per}); thresholds {warn_force:g} N, {warn_torque:g} N·m, failure at {DRIFT_FAIL_FACTOR:g}×")
    size = (f"{force:.3g} N and {torque:.3g} N·m over {over}, {per_factor * force / max(span, 1e-300):.3g} N and "
            f"{per_factor * torque / max(span, 1e-300):.3g} N·m {per}")
    if p < TREND_P and ratio > 1.0:
        status = FAIL if ratio > DRIFT_FAIL_FACTOR else WARN
        summary = (f"the residuals trend with time: the sensor's zero drifted about {size} while the poses were "
                   "recorded, and the fit bent the tool's weight to absorb part of it; identify with --drift "
                   "linear, or let the sensor warm up (about 30 min powered) and record again")
        return Finding("trend", status, summary, details, figures)
    return Finding("trend", PASS, f"no drift over the recording beyond the thresholds ({size})", details, figures)


def fit_finding(diagnostics: Mapping[str, Any], noise: Mapping[str, Any] | None = None,
                tolerance: tuple[float, float] | None = None) -> Finding:
    """Judge the refinement's convergence from the identification's ``diagnostics``, and what the model leaves
    unexplained: ``noise`` is the calibration's ``metadata["noise"]`` (the extra scatter beyond the measured noise
    when the record has std/count columns, else the residual scatter), judged against ``tolerance`` (N, N·m) when
    the fit has at least :data:`MISMATCH_MIN_POSES` poses."""
    converged = bool(diagnostics.get("converged", True))
    reweightings = int(diagnostics.get("reweightings", 0) or 0)
    iterations = int(diagnostics.get("iterations", 0) or 0)
    moved = diagnostics.get("last_change_sigmas")
    moved = float("nan") if moved is None else float(moved)
    figures = {"converged": converged, "reweightings": reweightings, "iterations": iterations,
               "last_change_sigmas": moved, "max_reweightings": diagnostics.get("max_reweightings"),
               "fail_sigmas": UNCONVERGED_FAIL_SIGMAS}
    details = (f"{reweightings} robust re-weightings, {iterations} Levenberg-Marquardt iterations; the last "
               f"re-weighting moved the parameters by up to {moved:.3g} σ")
    noise = dict(noise or {})
    measured = str(noise.get("source", "")).startswith("measured")
    scatter = np.asarray(noise.get("extra_scatter" if measured else "rms_residual") or np.zeros(6), dtype=float)
    scatter = scatter if scatter.shape == (6,) else np.zeros(6)
    excess_force, excess_torque = float(np.max(scatter[:3])), float(np.max(scatter[3:]))
    poses = int(diagnostics.get("poses", 0) or 0)
    what = "beyond the measured sensor noise" if measured else (
        "of residual scatter (noise and model mismatch together: the record has no std/count columns to tell them "
        "apart)")
    size = f"{excess_force:.3g} N and {excess_torque:.3g} N·m RMS per axis {what}"
    figures.update({"mismatch_force_n": excess_force, "mismatch_torque_nm": excess_torque, "noise_measured": measured})
    if tolerance is not None:
        figures.update({"tolerance_force_n": float(tolerance[0]), "tolerance_torque_nm": float(tolerance[1])})
        resolution = np.asarray(diagnostics.get("resolution") or np.zeros(6), dtype=float)
        details += (f"; the model leaves {size}; tolerance {tolerance[0]:g} N, {tolerance[1]:g} N·m; data resolution "
                    + (f"{np.max(resolution[:3]):.2g} N, {np.max(resolution[3:]):.2g} N·m" if np.any(resolution > 0)
                       else "not visible in the values"))
    beyond = (tolerance is not None and poses >= MISMATCH_MIN_POSES
              and (excess_force > tolerance[0] or excess_torque > tolerance[1]))
    if converged:
        if beyond:
            assert tolerance is not None
            return Finding("fit", WARN, f"model mismatch: the fit leaves {size}, beyond the tolerance "
                                        f"({tolerance[0]:g} N, {tolerance[1]:g} N·m): compensation will not be "
                                        "better than that (a cable, a flexible tool, a robot's pose error)",
                           details, figures)
        return Finding("fit", PASS, f"the fit converged ({reweightings} re-weightings) and leaves {size}", details,
                       figures)
    if np.isfinite(moved) and moved <= UNCONVERGED_FAIL_SIGMAS:
        return Finding("fit", WARN, f"the fit did not converge within {reweightings} re-weightings; its parameters "
                                    f"still moved {moved:.2g} σ at the last one: close, but not final", details, figures)
    return Finding("fit", FAIL, f"the fit did not converge within {reweightings} re-weightings (the parameters still "
                                f"moved {moved:.2g} σ at the last one): do not use the result; look for poses "
                                "disturbed in many ways, or a model that does not fit the data", details, figures)


def identification_findings(result: Any, held_out: Any | None = None,
                            tolerance: tuple[float, float] | None = None) -> list[Finding]:
    """Return the validation, conditioning, outlier, trend and fit findings of an identification.

    ``result`` is the :class:`ftacq.identification.IdentificationResult`; ``held_out`` the held-out poses
    (:class:`ftacq.posefile.PoseRecord`, never fitted; None or empty: the validation finding says so);
    ``tolerance`` (N, N·m) the model mismatch the user accepts (default: CELL.toml
    ``sampling.mismatch_tolerance_force_n`` / ``mismatch_tolerance_torque_nm``).
    """
    if tolerance is None:
        from ftacq.settings import SamplingConfig

        tolerance = (SamplingConfig.mismatch_tolerance_force_n, SamplingConfig.mismatch_tolerance_torque_nm)
    from ftacq.identification.diagnostics import parameter_warnings

    cal = result.calibration
    if held_out is not None and len(held_out):
        errors = held_out_errors(result, held_out)
        validation = validation_finding(errors, held_out_covariance(result, held_out), list(held_out.labels),
                                        tolerance, result.diagnostics.get("resolution"))
    else:
        validation = validation_finding(np.zeros((0, 6)), np.zeros((0, 6, 6)), [])
    diag = result.diagnostics
    from ftacq.identification.diagnostics import _PARAMETER_TEXT

    weakest = ", ".join(_PARAMETER_TEXT.get(str(x), str(x)) for x in diag.get("weakest_parameters", []))
    condition = float(diag.get("condition_number", float("nan")))
    weak = parameter_warnings(cal.uncertainty, cal.mass_kg, {"condition_number": condition, "weakest_text": weakest})
    findings = [validation, conditioning_finding(condition, weak, weakest),
                outlier_finding(list(result.outliers), len(result.labels))]
    if "trend" in diag:
        findings.append(trend_finding(diag["trend"], cal.metadata.get("drift_model", {})))
    fit = fit_finding(diag, cal.metadata.get("noise", {}), tolerance)
    check = cal.metadata.get("sensor_check")
    if check:  # the sensor's own gains (ftacq.sensor_check)
        from ftacq.sensor_check import explained_fit, sensor_finding

        findings += [explained_fit(fit, check, tolerance), sensor_finding(check, tolerance=tolerance)]
    else:
        findings.append(fit)
    return findings


def held_out_errors(result: Any, record: Any) -> np.ndarray:
    """Return the compensation error (M, 6) of held-out poses; with a modelled bias drift, the biases at each
    pose's time (the calibration holds those of the end of the recording)."""
    from ftacq.identification.trend import bias_drift_at

    cal = result.calibration
    errors = np.asarray(cal.compensate(record.wrench, record.flange_R_base), dtype=float).reshape(-1, 6)
    return errors - bias_drift_at(cal, record)


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
    drift_model = cal.metadata.get("drift_model", {})
    drift_time = None
    if sigma is not None and len(sigma) == 21 and drift_model.get("model") == "linear":
        from ftacq.identification.trend import pose_times

        params = ModelParameters(params.sensor_rotation, params.gravity_base, params.force_bias,
                                 params.center_of_mass, params.torque_bias, np.asarray(drift_model["bias_rate"]))
        drift_time = pose_times(record, drift_model).drift_time
    if sigma is not None:
        j = jacobian(params, rotations, drift_time)
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
           "drift_finding", "drift_not_checked_finding", "conditioning_finding", "outlier_finding", "poses_finding",
           "held_out_covariance", "identification_findings", "trend_finding", "fit_finding", "held_out_errors",
           "ACCEPTANCE_BAND_SIGMAS"]
