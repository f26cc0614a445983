"""The verdict of a calibration run: the core's checks (:mod:`ftacq.verdict`) fed from a procedure result.

Validation uses the held-out V poses as measured (their own standard errors), drift the revisit of the first pose
against the run's thresholds, poses the plan against what the configuration asked for and what was measured.
A run that stopped or failed before identification gets a FAIL that says so (and how far it got). A run whose
optional drift-check revisit failed gets a drift WARN saying what failed; the revisit then counts neither as
measured nor as due.
"""

from __future__ import annotations


from ftacq.posesets import PLANNED_SETS, RANDOM_SET, SPECIAL_SET, VALIDATION_SET
from ftacq.verdict import Verdict, drift_finding, drift_not_checked_finding, identification_findings, judge, poses_finding
from procedures.measured import DRIFT_SUFFIX, pose_record


def wanted_counts(settings) -> dict[str, int]:
    """Return the poses per set the configuration asked for (as the plan listing counts them)."""
    explicit = len(settings.explicit_poses) if getattr(settings, "explicit_poses", None) else 0
    return {SPECIAL_SET: 24 if settings.special else 0, RANDOM_SET: settings.random_count + explicit,
            VALIDATION_SET: settings.validation_count}


def held_out_record(measured: dict, plan):
    """Return the measured V poses, in plan order, as a :class:`ftacq.posefile.PoseRecord` (None if none)."""
    return pose_record([measured[label] for label, s in zip(plan.labels, plan.set_names)
                        if s == VALIDATION_SET and label in measured])


def run_verdict(result, plan, options) -> Verdict:
    """Return the verdict of a :class:`procedures.calibration_procedure.ProcedureResult` over ``plan`` run with ``options``
    (:class:`procedures.calibration_procedure.ProcedureOptions`: drift thresholds, drift check on or off)."""
    from procedures.calibration_procedure import count_measurements

    skipped = getattr(result, "drift_skipped", "")
    drift_check = options.drift_check and not skipped
    total = count_measurements(plan, (), drift_check)
    measured = sum(1 for label in result.measured if label in set(plan.labels)) + (
        1 if drift_check and any(label.endswith(DRIFT_SUFFIX) for label in result.measured) else 0)
    planned = {name: sum(1 for s in plan.set_names if s == name) for name in PLANNED_SETS}
    stopped = "" if result.status == "done" else result.message
    findings = [poses_finding(planned, wanted_counts(plan.settings), min(measured, total), total, stopped)]
    if result.identification is not None:
        findings = identification_findings(
            result.identification, held_out_record(result.measured, plan),
            (options.mismatch_tolerance_force_n, options.mismatch_tolerance_torque_nm)) + findings
    if result.drift is not None:
        d = result.drift
        findings.insert(1, drift_finding(d.drift, d.elapsed_s, options.drift_warn_force_n,
                                         options.drift_warn_torque_nm, d.label))
    elif skipped:
        findings.insert(1, drift_not_checked_finding(skipped))
    return judge(findings)


__all__ = ["run_verdict", "held_out_record", "wanted_counts"]
