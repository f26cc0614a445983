"""The quick calibration's analysis (``ftacq calibrate --quick``, docs/quick.md): each still hold used from when its
wrench settled (the tool rings after a stop: :func:`ftacq.rest_windows.settled_starts`), the joint fit of every
parameter with a linear bias drift when the data ask for it (:mod:`ftacq.dynamics.drift_terms`), and the verdict on
the validation holds with what it allows for (the drift's covariance at the holds' time, a ring too small to be
seen, a warm-up's curvature). The command (``ftacq/app/commands/quick_stage.py``) and ``benchmarks/quick.py`` call
:func:`analyse_quick`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


def hold_windows(recording, purpose: str, plan) -> list[tuple[int, int]]:
    """Robot-sample windows [start, end) of the holds with this purpose that were reached."""
    return [(int(a), int(b)) for (a, b), p in zip(recording.hold_rows, plan.purposes) if p == purpose and b > a]


REST_SPEED_RAD_S = 0.005
"""A robot state is at rest when no joint moves faster than this, rad/s (a hold's window is counted in states as they
arrive: one that arrived in a burst may begin with the end of the move before it)."""
DRIFT_CURVATURE_TIME_S = 600.0
"""The shortest time constant of a sensor's warm-up drift the validation allows for, s: a straight line fitted to an
exponential drift over a span T is off at its end by about rate · T² / (12 τ), which the verdict adds to the error
it expects (what the linear drift model leaves out)."""
RING_MIN_FREQUENCY_HZ = 5.0
"""The lowest ring-down frequency of a tool the validation allows for, Hz: a ring of amplitude A left after the
settle check adds at most about A / (2π f) N·s to a hold's sum, so A / (2π f T) to its mean over T s."""


@dataclass(frozen=True)
class Rest:
    """One reached hold: its waypoint ``index``, its purpose, robot rows [start, end) (``start`` its first state at
    rest, :data:`REST_SPEED_RAD_S`), and when its wrench had settled (robot clock, s; :func:`ftacq.rest_windows.settled_starts`)."""

    index: int
    purpose: str
    start: int
    end: int
    settled_s: float


@dataclass(frozen=True)
class QuickAnalysis:
    """What :func:`analyse_quick` found: the joint fit, the drift, the holds' settling, the verdict, the rows fitted."""

    result: Any
    drift: Any
    rests: list[Rest]
    ring_allowance: np.ndarray
    verdict: Any
    rows: np.ndarray

    def settle_summary(self) -> dict:
        """The holds' settling for the calibration's metadata: each hold's delay from rest to settled (s), and the
        ring amplitude the check could miss (6,) [N, N·m]."""
        return {"settle_delay_s": [round(float(r.settled_s), 4) for r in self.rests],
                "ring_allowance": self.ring_allowance.tolist()}


def hold_rests(recording, plan) -> tuple[list[Rest], np.ndarray]:
    """Every reached hold from its first robot state at rest, and when its wrench settled there (judged from the
    samples: the tool rings after each stop); ``settled_s`` is the delay after the rest began, s; and the largest
    ring amplitude (6,) the settle check can miss."""
    from ftacq.rest_windows import settled_starts

    record = recording.record
    found = []
    for k, ((a, b), purpose) in enumerate(zip(recording.hold_rows, plan.purposes)):
        if b - a < 2:
            continue
        still = np.flatnonzero(np.max(np.abs(record.qd[a:b]), axis=1) <= REST_SPEED_RAD_S)
        if still.size < 2:
            continue
        found.append((k, purpose, a + int(still[0]), a + int(still[-1]) + 1))
    windows = [(float(record.robot_time_s[a]), float(record.robot_time_s[b - 1])) for _, _, a, b in found]
    settled, allowance = settled_starts(record.sensor_time_s, record.wrench, windows)
    rests = [Rest(k, p, a, b, float(t - w[0])) for (k, p, a, b), w, t in zip(found, windows, settled)]
    return rests, allowance


def validation_poses(recording, plan, lag_s: float, rests: list[Rest] | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(q (M, 6), mean wrench (M, 6), its standard error (M, 6), labels, mean sensor time (M,) s, duration (M,) s) of
    each still
    validation hold: the sensor samples within the hold's robot-time window (shifted by the lag) from when its
    wrench settled (:func:`hold_rests`) to its end."""
    from procedures.quick import VALIDATE

    record = recording.record
    if rests is None:
        rests = hold_rests(recording, plan)[0]
    qs, means, errors, labels, times, durations = [], [], [], [], [], []
    for rest in rests:
        if rest.purpose != VALIDATE or rest.end - rest.start < 20:
            continue
        a, b = rest.start, rest.end
        t0 = record.robot_time_s[a] + rest.settled_s + lag_s
        t1 = record.robot_time_s[b - 1] + lag_s
        inside = (record.sensor_time_s >= t0) & (record.sensor_time_s < t1)
        if inside.sum() < 10:
            continue
        samples = record.wrench[inside]
        qs.append(record.q[a:b].mean(axis=0))
        means.append(samples.mean(axis=0))
        errors.append(samples.std(axis=0, ddof=1) / np.sqrt(len(samples)))
        labels.append(plan.labels[rest.index])
        times.append(float(record.sensor_time_s[inside].mean()))
        durations.append(float(np.ptp(record.sensor_time_s[inside])))
    return (np.array(qs).reshape(-1, 6), np.array(means).reshape(-1, 6), np.array(errors).reshape(-1, 6),
            np.array(labels), np.array(times), np.array(durations))


def fitted_rows(recording, plan, rests: list[Rest]) -> np.ndarray:
    """(M,) the robot rows the fit uses: all but the validation holds and, in each fitted hold, the rows between the
    stop and the wrench's settling (the ring-down, which the model does not describe)."""
    from procedures.quick import VALIDATE

    record = recording.record
    rows = np.ones(len(record.robot_time_s), dtype=bool)
    for a, b in hold_windows(recording, VALIDATE, plan):
        rows[a:b] = False
    for rest in rests:
        if rest.purpose != VALIDATE:
            settled = record.robot_time_s[rest.start] + rest.settled_s
            rows[rest.start:rest.end] &= record.robot_time_s[rest.start:rest.end] >= settled
    return rows


def analyse_quick(recording, plan, robot_model, sensor_offset_m: np.ndarray, nominal_down: np.ndarray,
                  completed: bool, drift: str = "auto", metadata: dict | None = None) -> QuickAnalysis:
    """Settle, fit (with the drift when the data ask for it, ftacq/dynamics/drift_terms.py) and judge a recording."""
    from ftacq.dynamics.drift_terms import identify_with_drift

    rests, allowance = hold_rests(recording, plan)
    rows = fitted_rows(recording, plan, rests)
    result, drift_fit = identify_with_drift(recording.record, robot_model, sensor_offset_m, nominal_down, rows=rows,
                                            drift=drift, reference_s=float(recording.record.robot_time_s[-1]),
                                            metadata=metadata)
    verdict = quick_verdict(result, recording, plan, robot_model, completed, drift_fit, rests, allowance)
    return QuickAnalysis(result, drift_fit, rests, allowance, verdict, rows)


def quick_verdict(result, recording, plan, robot_model, completed: bool, drift_fit=None,
                  rests: list[Rest] | None = None, ring_allowance: np.ndarray | None = None):
    """The verdict: the validation holds compensated with the result (static model: the arm is still; the bias at
    each hold's own time when a drift was fitted), against the error expected from the standard error of each mean,
    the parameters' covariance propagated (the drift's rates included: the holds come after the fitted motion),
    and what the model leaves out: a ring-down too small to be seen (``ring_allowance``, :func:`hold_rests`) and the
    curvature of a warm-up drift (:data:`DRIFT_CURVATURE_TIME_S`) (:func:`ftacq.verdict.validation_finding`); plus
    whether the whole trajectory ran."""
    from ftacq.dynamics.drift_terms import DRIFT_COLUMNS, SECONDS_PER_HOUR
    from ftacq.kinematics import forward_kinematics
    from ftacq.verdict import FAIL, PASS, Finding, judge, validation_finding

    if rests is None:
        rests, ring_allowance = hold_rests(recording, plan)
    q, mean, standard_error, labels, times, durations = validation_poses(recording, plan, result.lag_s, rests)
    findings = []
    if len(q):
        rotations = np.array([forward_kinematics(robot_model, qi)[:3, :3].T for qi in q])  # flange_R_base
        calibration = result.calibration
        modelled = drift_fit is not None and drift_fit.modelled
        base = result.optimum.size - (DRIFT_COLUMNS if modelled else 0)
        s_h = (times - (drift_fit.reference_s if drift_fit is not None else 0.0)) / SECONDS_PER_HOUR
        errors = mean - calibration.predict(rotations)
        jac = np.zeros((len(q), 6, result.optimum.size))
        for i in range(base):
            step = 1e-6 * max(abs(result.optimum[i]), 1e-3)
            plus, minus = result.optimum.copy(), result.optimum.copy()
            plus[i] += step
            minus[i] -= step
            jac[:, :, i] = (result.parameters(plus).predict(rotations) - result.parameters(minus).predict(rotations)) \
                / (2 * step)
        extra = np.zeros((len(q), 6))
        if modelled:
            errors = errors - s_h[:, None] * drift_fit.rate
            jac[:, :, base:] = s_h[:, None, None] * np.eye(6)
        if drift_fit is not None:
            # a warm-up's curvature the line leaves out, at the end of the span (rate in /h, span in h)
            extra += (np.abs(drift_fit.rate) * drift_fit.span_h ** 2 * SECONDS_PER_HOUR
                      / (12 * DRIFT_CURVATURE_TIME_S)) ** 2
            if not modelled:  # a drift below significance, not modelled: the holds come after the fitted motion
                middle = -0.5 * drift_fit.span_h
                extra += ((s_h - middle)[:, None] ** 2) * (drift_fit.rate ** 2 + drift_fit.rate_sigma ** 2)
        if ring_allowance is not None:  # what is left of a ring-down too small to be seen, averaged over the hold
            extra += (np.asarray(ring_allowance)[None, :] / (2 * np.pi * RING_MIN_FREQUENCY_HZ)
                      / np.maximum(durations, 1e-3)[:, None]) ** 2
        covariance = np.einsum("mai,ij,mbj->mab", jac, result.covariance, jac)
        covariance += np.einsum("ma,ab->mab", standard_error ** 2 + extra, np.eye(6))
        findings.append(validation_finding(errors, covariance, list(labels)))
    else:
        findings.append(validation_finding(np.zeros((0, 6)), np.zeros((0, 6, 6)), []))
    findings.append(Finding("poses", PASS if completed else FAIL,
                            "the whole trajectory ran" if completed else "the trajectory did not finish",
                            f"condition number {result.condition_number:.3g}, {result.rows} rows fitted, lag "
                            f"{1e3 * result.lag_s:.2f} ms"))
    if drift_fit is not None:
        findings.append(drift_finding(drift_fit))
    return judge(findings)


def drift_finding(drift_fit):
    """The drift inside the motion, as a finding ("trend", as the full run's): modelled or not, and why. It never
    fails the run: the fit models what it sees, and the validation judges the result with it; a sensor still
    drifting is what ``ftacq tare`` is for (docs/drift-and-tare.md)."""
    from ftacq.verdict import PASS, Finding

    rate = drift_fit.rate
    size = (f"{np.linalg.norm(rate[:3]):.3g} N/h and {np.linalg.norm(rate[3:]):.3g} N·m/h "
            f"(± {np.linalg.norm(drift_fit.rate_sigma[:3]):.2g}, {np.linalg.norm(drift_fit.rate_sigma[3:]):.2g})")
    if drift_fit.modelled:
        summary = (f"the sensor's zero drifted {size} during the motion; the fit modelled it and keeps the biases "
                   "of the end of the run (tare before use if it keeps drifting)")
    else:
        summary = f"no drift the motion can see ({size})"
    details = f"linear bias drift: {drift_fit.chosen}"
    return Finding("trend", PASS, summary, details, {"chi2": drift_fit.chi2, "p_value": drift_fit.p_value,
                                                      "rate": rate.tolist(),
                                                      "rate_sigma": drift_fit.rate_sigma.tolist()})


__all__ = ["hold_windows", "Rest", "QuickAnalysis", "hold_rests", "validation_poses", "fitted_rows", "analyse_quick", "quick_verdict", "drift_finding", "REST_SPEED_RAD_S", "DRIFT_CURVATURE_TIME_S", "RING_MIN_FREQUENCY_HZ"]
