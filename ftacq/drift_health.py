"""The at-rest check and --auto-tare's trust, over the drift tracker (what ``ftacq monitor`` runs per batch).

Steps 6 and 7 of :mod:`ftacq.drift`: :class:`RestCheck` decides when the compensated wrench at rest is off (beyond
what the calibration, the tracker and the window's noise explain, and visible), :class:`BiasHealth` chains rest
windows (:mod:`ftacq.rest_windows`) → tracker (:class:`ftacq.drift.DriftTracker`) → at-rest check → trust, and
says what changed as :class:`HealthNotice` lines.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ftacq.calibration import Calibration
from ftacq.channels import AXES
from ftacq.drift import DriftSettings, DriftTracker, Observation, file_bias_sigma
from ftacq.rest_windows import RestWindow, RestWindows


@dataclass(frozen=True)
class RestVerdict:
    """The at-rest check of one window: ``off`` channels, the residual the user sees and the thresholds."""

    time_s: float
    residual: np.ndarray
    threshold: np.ndarray
    off: bool


class RestCheck:
    """Decides when the compensated wrench at rest is off (:mod:`ftacq.drift`, step 6); reports state changes."""

    def __init__(self, calibration: Calibration, settings: DriftSettings | None = None) -> None:
        self.settings = settings or DriftSettings()
        self.calibration = calibration
        self.sigma_bias = file_bias_sigma(calibration)
        self.off_since_s: float | None = None
        self.warning = False

    def check(self, window: RestWindow, applied: np.ndarray, tracker: DriftTracker) -> tuple[RestVerdict, bool]:
        """Return (verdict of this window, True when the warning state changed)."""
        s = self.settings
        residual = window.mean - applied
        explained = np.sqrt(self.sigma_bias**2 + tracker.model_sigma(window.flange_R_base) ** 2
                            + window.std**2 / max(window.count, 1) + tracker.sigma(window.mid_s) ** 2)
        noise = tracker.reference_std if tracker.reference_std is not None else window.std
        threshold = np.maximum(s.warn_sigmas * explained, s.noise_fraction * noise)
        off = bool(np.any(np.abs(residual) > threshold))
        if not off:
            self.off_since_s = None
            state = False
        else:
            self.off_since_s = window.start_s if self.off_since_s is None else self.off_since_s
            state = True if window.end_s - self.off_since_s >= s.warn_after_s - 1e-9 else self.warning
        changed = state != self.warning
        self.warning = state
        return RestVerdict(window.end_s, residual, threshold, off), changed


@dataclass
class HealthNotice:
    """A line for the console and the dashboard log: ``level`` "INFO" or "WARN", ``time_s`` (sample clock)."""

    time_s: float
    level: str
    text: str
    data: dict[str, Any] = field(default_factory=dict)


class BiasHealth:
    """Rest windows → drift tracker → at-rest check → trust, for a live stream (what ``ftacq monitor`` runs).

    ``feed`` takes each batch's residual (compensated with the file's calibration), its still flag and orientation,
    and returns notices (state changes only). ``correction(t)`` is what ``--auto-tare`` subtracts: the tracked
    offset while it is trusted (:mod:`ftacq.drift`, step 7), zeros otherwise and without ``auto_tare``.
    """

    def __init__(self, calibration: Calibration, settings: DriftSettings | None = None, age_s: float = 0.0,
                 auto_tare: bool = False) -> None:
        self.settings = settings or DriftSettings()
        self.tracker = DriftTracker(calibration, self.settings, age_s)
        self.check = RestCheck(calibration, self.settings)
        self.windows = RestWindows(self.settings.window_s, self.settings.settle_s)
        self.auto_tare = auto_tare
        self.observations = 0
        self.last: Observation | None = None
        self.last_applied = np.zeros(6)
        self.trusted = False
        """Whether the tracked offset is trusted now (applied with ``auto_tare``)."""
        self.distrust_reason = "no rest window accepted yet"
        self._applied_before = False

    def correction(self, time_s: float | None = None, flange_R_base: np.ndarray | None = None) -> np.ndarray:
        """(6,) the offset subtracted from the residual: with ``auto_tare`` and while trusted, the tracked offset
        at ``time_s`` (plus the model error found at ``flange_R_base`` when that is where the tracker last
        learnt); zeros otherwise."""
        if not (self.auto_tare and self.trusted):
            return np.zeros(6)
        return self.tracker.offset(time_s) + self.tracker.model_error(flange_R_base)

    @property
    def applied(self) -> bool:
        """True when the correction is being subtracted (``auto_tare`` and trusted)."""
        return self.auto_tare and self.trusted

    def feed(self, time_s: np.ndarray, residual: np.ndarray, still: bool,
             flange_R_base: np.ndarray | None = None) -> list[HealthNotice]:
        """Process one batch; return the notices it caused."""
        notices: list[HealthNotice] = []
        if len(time_s):
            self.tracker.start(float(time_s[0]))
        step_told = self.tracker.step is not None
        for window in self.windows.feed(time_s, residual, still, flange_R_base):
            applied = self.correction(window.mid_s, window.flange_R_base)  # what was subtracted live
            self.last_applied = applied
            observation = self.tracker.observe(window)
            self.observations += 1
            self.last = observation
            if observation.reacquired and observation.judgement is not None:
                notices.append(self._reacquired_notice(observation))
            elif observation.judgement is not None and self.tracker.step is not None and not step_told:
                notices.append(self._step_notice(window.end_s))
            step_told = self.tracker.step is not None
            notices += self._update_trust(window.end_s)
            if observation.reason.startswith("contact"):
                self.check.off_since_s = None  # a hand on the tool: not "at rest"; persistence starts again after it
                continue
            verdict, changed = self.check.check(window, applied, self.tracker)
            if changed:
                notices.append(self._notice(verdict, observation))
        if len(time_s):
            notices += self._update_trust(float(time_s[-1]))
        return notices

    def _update_trust(self, time_s: float) -> list[HealthNotice]:
        """Decide whether the offset is trusted at ``time_s`` (:mod:`ftacq.drift`, step 7); a notice on a change
        (with ``auto_tare`` only: without it nothing is applied either way)."""
        tracker = self.tracker
        reason = ""
        noise = tracker.reference_std
        if tracker.step is not None:
            reason = ("a step stands against the tracked drift (" + _step_text(tracker.step.size) + ")")
        elif not tracker.accepted or noise is None:
            reason = "no rest window accepted yet"
        else:
            sigma = tracker.sigma(time_s)
            bound = self.settings.trust_noise_fraction * noise
            if np.any(sigma > bound):
                worst = int(np.argmax(sigma / np.maximum(bound, 1e-300)))
                unit = "N" if worst < 3 else "N·m"
                reason = (f"the offset is no longer known well enough ({AXES[worst]} 1σ {sigma[worst]:.3g} {unit}"
                          f" > one sample's noise {bound[worst]:.3g} {unit}, {time_s - (tracker.time_s or 0.0):.0f} s "
                          "since the last rest window used)")
        trusted = not reason
        if trusted == self.trusted:
            self.distrust_reason = reason
            return []
        self.trusted, self.distrust_reason = trusted, reason
        if not self.auto_tare or (not trusted and not tracker.accepted):
            return []
        if trusted:
            again, self._applied_before = (" again" if self._applied_before else ""), True
            return [HealthNotice(time_s, "INFO", f"auto-tare: applying the tracked offset{again} ("
                                 + _offset_text(tracker.offset(time_s)) + ")")]
        return [HealthNotice(time_s, "WARN" if tracker.step is not None else "INFO",
                             f"auto-tare suspended: {reason}; the stream is the calibration's compensation without "
                             "the tracked offset until rest windows agree with the track again",
                             {"reason": reason})]

    def _reacquired_notice(self, observation: Observation) -> HealthNotice:
        assert observation.judgement is not None
        tracker = self.tracker
        return HealthNotice(observation.window.end_s, "INFO",
                            "drift faster than tracked: the rest "
                            f"windows refused by the gate {observation.judgement.reason}: re-acquired (drift, not a "
                            "step); rate now F [" + ", ".join(f"{r:+.1f}" for r in tracker.rate_per_h[:3])
                            + "] N/h, T [" + ", ".join(f"{r:+.3f}" for r in tracker.rate_per_h[3:]) + "] N·m/h")

    def _step_notice(self, time_s: float) -> HealthNotice:
        step = self.tracker.step
        assert step is not None
        return HealthNotice(time_s, "WARN",
                            f"a step, not drift: {_step_text(step.size)} against the tracked drift, seen for "
                            f"{time_s - step.time_s:.1f} s ({step.reason}): a push held on the tool, a changed tool or a bias "
                            "step (a box bias or power cycle); not absorbed"
                            + ("; the tracked offset is no longer applied" if self.auto_tare else ""),
                            {"step": step.size.tolist()})

    def _notice(self, verdict: RestVerdict, observation: Observation) -> HealthNotice:
        if not self.check.warning:
            return HealthNotice(verdict.time_s, "INFO", "compensated wrench at rest is back within its threshold")
        worst = int(np.argmax(np.abs(verdict.residual) / verdict.threshold))
        unit = "N" if worst < 3 else "N·m"
        force = float(np.linalg.norm(verdict.residual[:3]))
        torque = float(np.linalg.norm(verdict.residual[3:]))
        if observation.accepted and not self.applied:
            why = ("the biases drifted since the calibration (tracked, the drift model explains it): run "
                   "`ftacq tare` or monitor with --auto-tare")
        elif self.tracker.step is not None:
            why = (f"a step, not drift ({_step_text(self.tracker.step.size)}; {self.tracker.step.reason}): a push "
                   "held on the tool, a changed tool or a bias step (a box bias or power cycle); if nothing touches "
                   "the tool, check that the calibration belongs to this tool and run `ftacq tare`")
        else:
            why = ("not the tracked drift: a push on the tool, a changed tool, a bias step (a box bias or power "
                   f"cycle), or drift faster than tracked (told apart after {self.settings.reacquire_after_s:g} s at "
                   "rest); if nothing touches the tool, check that the calibration belongs to this tool and run "
                   "`ftacq tare`")
        text = (f"compensated wrench at rest is off: |F| {force:.3f} N, |T| {torque:.4f} N·m "
                f"({AXES[worst]} {verdict.residual[worst]:+.4g} {unit}, threshold {verdict.threshold[worst]:.3g} "
                f"{unit}): {why}")
        return HealthNotice(verdict.time_s, "WARN", text,
                            {"residual": verdict.residual.tolist(), "threshold": verdict.threshold.tolist()})


def _step_text(size: np.ndarray) -> str:
    return f"a jump of |F| {float(np.linalg.norm(size[:3])):.3g} N, |T| {float(np.linalg.norm(size[3:])):.3g} N·m"


def _offset_text(offset: np.ndarray) -> str:
    return f"|F| {float(np.linalg.norm(offset[:3])):.3g} N, |T| {float(np.linalg.norm(offset[3:])):.3g} N·m"



__all__ = ["BiasHealth", "HealthNotice", "RestCheck", "RestVerdict"]
