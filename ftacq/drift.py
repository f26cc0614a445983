"""Live bias-drift tracking and the at-rest health check (pure numpy, fed with sample batches).

Input: batches of the wrench compensated with the calibration as it is on file (``Calibration.compensate``: the
reading minus the predicted tool weight and the file's biases), the batch's still flag (the caller decides from
the robot's joint motion) and the flange orientation. At rest and without contact that residual is the biases'
change since the file (plus the calibration's model error at this orientation, plus noise).

1. **Rest windows** (:class:`RestWindows`). After the arm has been still for ``settle_s``, consecutive windows of
   ``window_s`` are summarised: mean, sample std, count, and the least-squares slope of each channel within the
   window. Motion discards the open window.
2. **Contact detector.** A window is contact (not used) when any channel's std exceeds ``std_ratio`` × the sensor's
   reference noise (the median std of recent accepted windows), or its slope is more than ``slope_sigmas`` standard
   errors from zero: a hand on the tool trembles and comes and goes; drift is thousands of times slower.
3. **Kalman filter** (:class:`DriftTracker`), per channel c independently, state x = [offset b_c, rate ḃ_c] (offset
   of the bias from the file's, N or N·m; rate per s). Process model (integrated random walk, stated noise):

       b(t+Δ) = b(t) + Δ ḃ(t) + w_b,     ḃ(t+Δ) = ḃ(t) + w_r
       Q = [[q_b Δ + q_r Δ³/3, q_r Δ²/2], [q_r Δ²/2, q_r Δ]],   q_b = bias_walk², q_r = rate_walk²

   Measurement: a window mean z = b(t_mid) + v with R = std²/count (sensor noise, samples independent) + the
   calibration's model 1σ² at this orientation (:func:`ftacq.bias_estimate.compensation_sigma` without the bias
   terms: rotation, weight, centre of mass, per-pose scatter, robot orientation error). Prior: b ~ N(0, σ_bias² +
   (rate_prior · age)²) with σ_bias the file's bias 1σ and age the time since the last calibration or tare (capped at
   ``MAX_PRIOR_AGE_S``); ḃ ~ N(0, rate_prior²).
4. **Innovation gate.** A window whose normalised innovation squared Σ_c ν_c² / S_c exceeds ``gate_chi2`` (χ², 6
   degrees of freedom) is rejected: a steady push, a tool swap or a bias jump is never absorbed (the filter only
   follows what its drift model can explain). A rejected window does not move the estimate.
5. **At-rest check** (:class:`RestCheck`). The wrench the user sees at rest (the residual minus the applied
   correction) is *off* when a channel exceeds max(``warn_sigmas`` × the 1σ the calibration, the tracker and the
   window's noise explain, ``noise_fraction`` × one sample's noise) for ``warn_after_s``: significant and visible.
   Windows the contact detector flags (a trembling hand) are not at rest and are skipped; a perfectly steady push
   held longer than ``warn_after_s`` is reported (at one pose it looks like a changed tool or a bias step).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ftacq.bias_estimate import compensation_sigma
from ftacq.calibration import Calibration

CHANNELS = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
MAX_PRIOR_AGE_S = 3600.0
"""The prior's drift allowance counts at most this much time since the last calibration or tare, s."""
REFERENCE_NOISE_WINDOWS = 21
"""Accepted windows whose median std is the contact detector's reference noise."""


@dataclass(frozen=True)
class DriftSettings:
    """Noise model and detector thresholds of the tracker (per channel: force in N, torque in N·m).

    Attributes:
        window_s: rest window length, s. settle_s: stillness required before the first window, s.
        rate_prior_per_h: 1σ of the drift rate before any data, N/h and N·m/h.
        rate_walk_per_h: random-walk density of the rate, (N/h)/√h: how fast the drift rate itself may change
            (a thermal step with amplitude A and time constant τ changes it by about A/τ per τ).
        bias_walk_per_sqrt_h: random-walk density of the bias itself, N/√h (unmodelled wander).
        gate_chi2: innovation gate, χ² with 6 degrees of freedom (22.46 = 0.1 % of clean windows rejected).
        std_ratio: contact when a channel's std exceeds this × the reference noise.
        slope_sigmas: contact when a channel's in-window slope exceeds this many standard errors.
        warn_sigmas, noise_fraction, warn_after_s: the at-rest check (module docstring, step 5).
    """

    window_s: float = 0.5
    settle_s: float = 0.5
    rate_prior_per_h: tuple[float, ...] = (3.0, 3.0, 3.0, 0.1, 0.1, 0.1)
    rate_walk_per_h: tuple[float, ...] = (10.0, 10.0, 10.0, 0.3, 0.3, 0.3)
    bias_walk_per_sqrt_h: tuple[float, ...] = (0.005, 0.005, 0.005, 0.0002, 0.0002, 0.0002)
    gate_chi2: float = 22.46
    std_ratio: float = 1.5
    slope_sigmas: float = 6.0
    warn_sigmas: float = 6.0
    noise_fraction: float = 1.0
    warn_after_s: float = 1.0

    @property
    def q_bias(self) -> np.ndarray:
        """(6,) bias random-walk variance growth, units²/s."""
        return (np.asarray(self.bias_walk_per_sqrt_h) ** 2) / 3600.0

    @property
    def q_rate(self) -> np.ndarray:
        """(6,) rate random-walk variance growth, (units/s)²/s."""
        return (np.asarray(self.rate_walk_per_h) / 3600.0) ** 2 / 3600.0

    @property
    def rate_prior(self) -> np.ndarray:
        """(6,) 1σ of the initial rate, units/s."""
        return np.asarray(self.rate_prior_per_h) / 3600.0


@dataclass(frozen=True)
class RestWindow:
    """One window of samples at rest (residuals: compensated with the file's calibration).

    Attributes:
        start_s, end_s: first and last sample time, s. count: samples. mean, std: (6,) N and N·m.
        slope_t: (6,) in-window slope over its standard error. flange_R_base: (3, 3) orientation (or None).
    """

    start_s: float
    end_s: float
    count: int
    mean: np.ndarray
    std: np.ndarray
    slope_t: np.ndarray
    flange_R_base: np.ndarray | None

    @property
    def mid_s(self) -> float:
        return 0.5 * (self.start_s + self.end_s)


def summarise_window(time_s: np.ndarray, values: np.ndarray, flange_R_base: np.ndarray | None) -> RestWindow:
    """Return the :class:`RestWindow` of samples (N,) s and (N, 6)."""
    t = time_s - time_s.mean()
    mean = values.mean(axis=0)
    centred = values - mean
    std = centred.std(axis=0, ddof=1) if len(values) > 1 else np.zeros(6)
    sxx = float(t @ t)
    if sxx > 0 and len(values) > 2:
        slope = (t @ centred) / sxx
        residual = centred - np.outer(t, slope)
        slope_se = np.sqrt(np.maximum((residual**2).sum(axis=0) / (len(values) - 2), 1e-300) / sxx)
        slope_t = slope / slope_se
    else:
        slope_t = np.zeros(6)
    return RestWindow(float(time_s[0]), float(time_s[-1]), int(len(values)), mean, std, slope_t, flange_R_base)


class RestWindows:
    """Cuts batches of residual samples into rest windows (module docstring, step 1)."""

    def __init__(self, window_s: float, settle_s: float) -> None:
        self.window_s = float(window_s)
        self.settle_s = float(settle_s)
        self._still_since: float | None = None
        self._times: list[np.ndarray] = []
        self._values: list[np.ndarray] = []

    @property
    def still_since_s(self) -> float | None:
        """When the current stillness began (s), or None while moving."""
        return self._still_since

    def feed(self, time_s: np.ndarray, values: np.ndarray, still: bool,
             flange_R_base: np.ndarray | None = None) -> list[RestWindow]:
        """Add a batch (all samples share ``still``); return the windows it completed."""
        if len(time_s) == 0:
            return []
        if not still:
            self._still_since = None
            self._times.clear()
            self._values.clear()
            return []
        if self._still_since is None:
            self._still_since = float(time_s[0])
        start = self._still_since + self.settle_s
        keep = time_s >= start
        if not keep.any():
            return []
        self._times.append(np.asarray(time_s[keep], dtype=float))
        self._values.append(np.asarray(values[keep], dtype=float))
        out = []
        while self._times and self._times[-1][-1] - self._times[0][0] >= self.window_s:
            times = np.concatenate(self._times)
            vals = np.concatenate(self._values)
            end = int(np.searchsorted(times, times[0] + self.window_s, side="left"))  # [start, start + window)
            out.append(summarise_window(times[:end], vals[:end], flange_R_base))
            self._times, self._values = ([times[end:]], [vals[end:]]) if end < len(times) else ([], [])
        return out


@dataclass(frozen=True)
class Observation:
    """What the tracker did with one rest window.

    Attributes:
        window: the window. accepted: used to update the estimate. reason: "" or why not ("contact: Fz std …",
            "gate: …"). nis: normalised innovation squared (6 channels). innovation: (6,) window mean − prediction.
    """

    window: RestWindow
    accepted: bool
    reason: str
    nis: float
    innovation: np.ndarray


class DriftTracker:
    """Kalman filter on the biases' offset from the calibration file and its rate (module docstring, steps 2-4).

    Args:
        calibration: the calibration the residuals were compensated with.
        settings: :class:`DriftSettings`.
        age_s: time since the calibration's biases were last measured (calibration or tare), s.
    """

    def __init__(self, calibration: Calibration, settings: DriftSettings | None = None, age_s: float = 0.0) -> None:
        self.calibration = calibration
        self.settings = settings or DriftSettings()
        s = self.settings
        sigma_bias = np.concatenate([_sigma(calibration, "force_bias"), _sigma(calibration, "torque_bias")])
        age = min(max(float(age_s), 0.0), MAX_PRIOR_AGE_S)
        self.x = np.zeros((6, 2))
        self.P = np.zeros((6, 2, 2))
        self.P[:, 0, 0] = sigma_bias**2 + (s.rate_prior * age) ** 2 + s.q_bias * age
        self.P[:, 1, 1] = s.rate_prior**2
        self.time_s: float | None = None
        self.accepted = 0
        self.rejected_contact = 0
        self.rejected_gate = 0
        self._reference_std: list[np.ndarray] = []
        self._model_sigma_cache: tuple[bytes, np.ndarray] | None = None

    # ------------------------------------------------------------------ state

    def _propagate(self, x: np.ndarray, P: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        if dt <= 0:
            return x.copy(), P.copy()
        s = self.settings
        F = np.array([[1.0, dt], [0.0, 1.0]])
        Q = np.zeros((6, 2, 2))
        Q[:, 0, 0] = s.q_bias * dt + s.q_rate * dt**3 / 3.0
        Q[:, 0, 1] = Q[:, 1, 0] = s.q_rate * dt**2 / 2.0
        Q[:, 1, 1] = s.q_rate * dt
        return x @ F.T, F @ P @ F.T + Q

    def offset(self, time_s: float | None = None) -> np.ndarray:
        """Return the estimated bias offset (6,) from the calibration file at ``time_s`` (N, N·m)."""
        if self.time_s is None or time_s is None:
            return self.x[:, 0].copy()
        x, _ = self._propagate(self.x, self.P, time_s - self.time_s)
        return x[:, 0]

    def sigma(self, time_s: float | None = None) -> np.ndarray:
        """Return the 1σ (6,) of :meth:`offset` at ``time_s``."""
        if self.time_s is None or time_s is None:
            return np.sqrt(self.P[:, 0, 0])
        _, P = self._propagate(self.x, self.P, time_s - self.time_s)
        return np.sqrt(P[:, 0, 0])

    @property
    def rate_per_h(self) -> np.ndarray:
        """(6,) estimated drift rate, N/h and N·m/h."""
        return self.x[:, 1] * 3600.0

    @property
    def reference_std(self) -> np.ndarray | None:
        """(6,) the sensor's per-sample noise (median std of recent accepted windows), or None before any."""
        if not self._reference_std:
            return None
        return np.median(np.array(self._reference_std), axis=0)

    def model_sigma(self, flange_R_base: np.ndarray | None) -> np.ndarray:
        """(6,) the calibration's model 1σ at this orientation (biases excluded), N and N·m."""
        if flange_R_base is None:
            return np.zeros(6)
        key = np.round(np.asarray(flange_R_base, dtype=float), 4).tobytes()
        if self._model_sigma_cache is None or self._model_sigma_cache[0] != key:
            self._model_sigma_cache = (key, compensation_sigma(self.calibration, flange_R_base,
                                                               include_biases=False))
        return self._model_sigma_cache[1]

    # ------------------------------------------------------------------ update

    def contact_reason(self, window: RestWindow) -> str:
        """Return why the window looks like contact ('' if it does not): std or in-window slope."""
        s = self.settings
        reference = self.reference_std
        if reference is not None:
            ratio = window.std / np.maximum(reference, 1e-300)
            worst = int(np.argmax(ratio))
            if ratio[worst] > s.std_ratio:
                return f"contact: {CHANNELS[worst]} std {ratio[worst]:.1f}× the sensor noise"
        slope = np.abs(window.slope_t)
        worst = int(np.argmax(slope))
        if slope[worst] > s.slope_sigmas:
            return f"contact: {CHANNELS[worst]} changing within the window ({slope[worst]:.0f}σ)"
        return ""

    def observe(self, window: RestWindow) -> Observation:
        """Gate a rest window and, if clean, update the estimate with it (module docstring, steps 2-4)."""
        dt = 0.0 if self.time_s is None else window.mid_s - self.time_s
        x, P = self._propagate(self.x, self.P, dt)
        measurement_var = window.std**2 / max(window.count, 1) + self.model_sigma(window.flange_R_base) ** 2
        S = P[:, 0, 0] + measurement_var + 1e-30
        innovation = window.mean - x[:, 0]
        nis = float(np.sum(innovation**2 / S))
        reason = self.contact_reason(window)
        if not reason and nis > self.settings.gate_chi2:
            worst = int(np.argmax(innovation**2 / S))
            unit = "N" if worst < 3 else "N·m"
            reason = (f"gate: {CHANNELS[worst]} off by {innovation[worst]:+.4g} {unit} "
                      f"({math.sqrt(innovation[worst] ** 2 / S[worst]):.0f}σ), not drift")
        if reason:
            if reason.startswith("contact"):
                self.rejected_contact += 1
            else:
                self.rejected_gate += 1
            return Observation(window, False, reason, nis, innovation)
        gain = P[:, :, 0] / S[:, None]  # (6, 2)
        self.x = x + gain * innovation[:, None]
        self.P = P - gain[:, :, None] * P[:, 0, :][:, None, :]
        self.P = 0.5 * (self.P + self.P.transpose(0, 2, 1))
        self.time_s = window.mid_s
        self.accepted += 1
        self._reference_std.append(window.std)
        del self._reference_std[:-REFERENCE_NOISE_WINDOWS]
        return Observation(window, True, "", nis, innovation)


UNKNOWN_BIAS_SIGMA = {"force_bias": 0.01, "torque_bias": 0.0005}
"""1σ assumed for a calibration file that gives none for its biases, N and N·m (a typical identification's
order of magnitude; only the tracker's prior and the at-rest threshold use it)."""


def _sigma(calibration: Calibration, key: str) -> np.ndarray:
    value = calibration.uncertainty.get(key)
    if value is None:
        return np.full(3, UNKNOWN_BIAS_SIGMA[key])
    array = np.asarray(value, dtype=float).reshape(3)
    return np.where(np.isfinite(array), array, UNKNOWN_BIAS_SIGMA[key])


@dataclass(frozen=True)
class RestVerdict:
    """The at-rest check of one window: ``off`` channels, the residual the user sees and the thresholds."""

    time_s: float
    residual: np.ndarray
    threshold: np.ndarray
    off: bool


class RestCheck:
    """Decides when the compensated wrench at rest is off (module docstring, step 5); reports state changes."""

    def __init__(self, calibration: Calibration, settings: DriftSettings | None = None) -> None:
        self.settings = settings or DriftSettings()
        self.calibration = calibration
        self.sigma_bias = np.concatenate([_sigma(calibration, "force_bias"), _sigma(calibration, "torque_bias")])
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
    """Rest windows → drift tracker → at-rest check, for a live stream (what ``ftacq monitor`` runs).

    ``feed`` takes each batch's residual (compensated with the file's calibration), its still flag and orientation,
    and returns notices (state changes only). ``correction(t)`` is what ``--auto-tare`` subtracts (zeros without it).
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
        self.last_verdict: RestVerdict | None = None
        self.last_applied = np.zeros(6)

    def correction(self, time_s: float | None = None) -> np.ndarray:
        """(6,) the offset subtracted from the residual (the tracker's estimate with --auto-tare, else zeros)."""
        return self.tracker.offset(time_s) if self.auto_tare else np.zeros(6)

    def feed(self, time_s: np.ndarray, residual: np.ndarray, still: bool,
             flange_R_base: np.ndarray | None = None) -> list[HealthNotice]:
        """Process one batch; return the notices it caused."""
        notices: list[HealthNotice] = []
        for window in self.windows.feed(time_s, residual, still, flange_R_base):
            applied = self.correction(window.mid_s)  # the prediction from earlier windows: what was subtracted live
            self.last_applied = applied
            observation = self.tracker.observe(window)
            self.observations += 1
            self.last = observation
            if observation.reason.startswith("contact"):
                self.check.off_since_s = None  # a hand on the tool: not "at rest"; persistence starts again after it
                continue
            verdict, changed = self.check.check(window, applied, self.tracker)
            self.last_verdict = verdict
            if changed:
                notices.append(self._notice(verdict, observation))
        return notices

    def _notice(self, verdict: RestVerdict, observation: Observation) -> HealthNotice:
        if not self.check.warning:
            return HealthNotice(verdict.time_s, "INFO", "compensated wrench at rest is back within its threshold")
        worst = int(np.argmax(np.abs(verdict.residual) / verdict.threshold))
        unit = "N" if worst < 3 else "N·m"
        force = float(np.linalg.norm(verdict.residual[:3]))
        torque = float(np.linalg.norm(verdict.residual[3:]))
        drift_explains = observation.accepted and not self.auto_tare
        if drift_explains:
            why = ("the biases drifted since the calibration (tracked, the drift model explains it): run "
                   "`ftacq tare` or monitor with --auto-tare")
        else:
            why = ("not drift: a push on the tool, a changed tool or a bias step (a box bias or power cycle); if "
                   "nothing touches the tool, check that the calibration belongs to this tool and run `ftacq tare`")
        text = (f"compensated wrench at rest is off: |F| {force:.3f} N, |T| {torque:.4f} N·m "
                f"({CHANNELS[worst]} {verdict.residual[worst]:+.4g} {unit}, threshold {verdict.threshold[worst]:.3g} "
                f"{unit}): {why}")
        return HealthNotice(verdict.time_s, "WARN", text,
                            {"residual": verdict.residual.tolist(), "threshold": verdict.threshold.tolist()})


__all__ = ["DriftSettings", "RestWindow", "RestWindows", "DriftTracker", "Observation", "RestCheck", "RestVerdict",
           "BiasHealth", "HealthNotice", "summarise_window"]
