"""Live bias-drift tracking and the at-rest health check (pure numpy, fed with sample batches).

Input: batches of the wrench compensated with the calibration as it is on file (``Calibration.compensate``: the
reading minus the predicted tool weight and the file's biases), the batch's still flag (the caller decides from
the robot's joint motion) and the flange orientation. At rest and without contact that residual is the biases'
change since the file, plus the calibration's model error at this orientation, plus noise.

1. **Rest windows** (:class:`ftacq.rest_windows.RestWindows`). After the arm has been still for ``settle_s``,
   consecutive windows of ``window_s`` are summarised: mean, sample std, count, and the least-squares slope of
   each channel within the window. Motion discards the open window.
2. **Contact detector.** A window is contact (not used) when any channel's std exceeds ``std_ratio`` × the sensor's
   reference noise (the median std of recent accepted windows), or its in-window slope differs from the tracked
   drift rate by more than ``slope_sigmas`` standard errors: a hand on the tool trembles and comes and goes.
3. **Kalman filter** (:class:`DriftTracker`), per channel independently, state x = [offset b, rate ḃ, model error
   m, common model error c] (b: the biases' offset from the file's, N or N·m; ḃ per s; m, c below). Process model
   (integrated random walk; m and c constant):

       b(t+Δ) = b(t) + Δ ḃ(t) + w_b,     ḃ(t+Δ) = ḃ(t) + w_r,     m unchanged
       Q = [[q_b Δ + q_r Δ³/3, q_r Δ²/2], [q_r Δ²/2, q_r Δ]],   q_b = bias_walk²

   **Adaptive rate walk** (how warm-up drift is followed): q_r = rate_walk² + min(ḃ² + P_ḃḃ, max_rate²) / τ with τ
   = ``warmup_time_constant_s``. A strain-gauge sensor warming up drifts as A (1 − e^(−t/τ)): its rate A/τ e^(−t/τ)
   changes by its own size within τ, so a fast drift must be allowed a fast-changing rate, while a slow one keeps
   the tight base walk (and the tracker its precision). Chosen over a fixed larger walk (which would loosen the
   gate against steps at every rate) and over a timed warm-up mode (the software does not know when the sensor was
   powered on). The rate prior (``rate_prior_per_h``, 1σ 60 N/h and 2 N·m/h) lets the first still period find a
   warm-up at those rates on all six channels at once (a χ² of about 6 over 6 channels) before the gate closes.
   Measurement: a window mean z = b + m + c + v with R = std²/count (sensor noise, samples independent). m and c
   carry the calibration's model error (:func:`ftacq.bias_estimate.compensation_variance_parts`, bias terms
   excluded): c the parameters' part (one set of errors for every orientation, its prior set at the first window),
   m the per-pose part (τ, σ_θ), drawn afresh at each new orientation. Constant at one orientation, neither
   averages out over the windows taken there, so the offset's 1σ stays honest. Prior:
   b ~ N(0, σ_bias² + (rate_prior · age)²) with σ_bias the file's bias 1σ and age the time since the last
   calibration or tare (capped at ``MAX_PRIOR_AGE_S``); ḃ ~ N(0, rate_prior²).
4. **Innovation gate.** A window whose normalised innovation squared Σ_c ν_c² / S_c exceeds ``gate_chi2`` (χ², 6
   degrees of freedom) is refused: a steady push, a tool swap or a bias jump is never absorbed.
5. **Drift or step** (:mod:`ftacq.drift_or_step`). Refused windows at one orientation spanning
   ``reacquire_after_s`` are tested for continuity with the track: a line through them that joins it smoothly is
   drift faster than tracked (the filter restarts from the line: "re-acquired"); otherwise it is a **step**, kept
   refused until windows agree with the track again and are nearer it than the track plus the step (the track's
   growing uncertainty never swallows it; no second drift-or-step test while it stands).
6. **At-rest check** (:class:`ftacq.drift_health.RestCheck`). The wrench the user sees at rest (the residual minus
   the applied correction) is *off* when a channel exceeds max(``warn_sigmas`` × the 1σ the calibration, the tracker
   and the window's noise explain, ``noise_fraction`` × one sample's noise) for ``warn_after_s``: significant and
   visible. Windows the contact detector flags (a trembling hand) are not at rest and are skipped; a perfectly
   steady push held longer than ``warn_after_s`` is reported (at one pose it looks like a changed tool or a bias
   step).
7. **Trust** (:class:`ftacq.drift_health.BiasHealth`): ``--auto-tare`` subtracts the tracked offset only while it is
   trusted: no step stands against it and its 1σ now is within ``trust_noise_fraction`` × one sample's noise.
   Otherwise the correction is withdrawn (the stream is the calibration's compensation) and a notice says why.

Modules: the rest windows (step 1) :mod:`ftacq.rest_windows`; the tracker (steps 2-5) here; the drift-or-step test
:mod:`ftacq.drift_or_step`; the at-rest check and trust (steps 6-7) :mod:`ftacq.drift_health`. One set of thresholds
for all of them: :class:`DriftSettings`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ftacq.bias_estimate import compensation_variance_parts
from ftacq.calibration import Calibration
from ftacq.channels import AXES
from ftacq.drift_or_step import Judgement, judge
from ftacq.rest_windows import RestWindow, same_orientation

MAX_PRIOR_AGE_S = 3600.0
"""The prior's drift allowance counts at most this much time since the last calibration or tare, s."""
REFERENCE_NOISE_WINDOWS = 21
"""Accepted windows whose median std is the contact detector's reference noise."""
REACQUIRE_WINDOWS = 40
"""At most this many refused windows are kept for the drift-or-step test."""


@dataclass(frozen=True)
class DriftSettings:
    """Noise model and detector thresholds of the tracker (per channel: force in N, torque in N·m).

    Attributes:
        window_s: rest window length, s. settle_s: stillness required before the first window, s.
        rate_prior_per_h: 1σ of the drift rate before any data, N/h and N·m/h (a sensor possibly warming up).
        rate_walk_per_h: base random-walk density of the rate, (N/h)/√h, for a slow drift.
        warmup_time_constant_s: τ of the adaptive rate walk: the rate may change by its own size within τ, s.
        max_rate_per_h: the largest drift rate, N/h and N·m/h: caps the adaptive walk; a line through refused
            windows that is steeper is not drift.
        bias_walk_per_sqrt_h: random-walk density of the bias itself, N/√h (unmodelled wander).
        gate_chi2: innovation gate, χ² with 6 degrees of freedom (22.46 = 0.1 % of clean windows rejected).
        reacquire_after_s: refused windows at one orientation spanning this long are tested: drift or step, s.
        std_ratio: contact when a channel's std exceeds this × the reference noise.
        slope_sigmas: contact when a channel's in-window slope is this many standard errors off the tracked rate.
        warn_sigmas, noise_fraction, warn_after_s: the at-rest check (module docstring, step 6).
        trust_noise_fraction: --auto-tare applies the offset while its 1σ is within this × one sample's noise.
    """

    window_s: float = 0.5
    settle_s: float = 0.5
    rate_prior_per_h: tuple[float, ...] = (60.0, 60.0, 60.0, 2.0, 2.0, 2.0)
    rate_walk_per_h: tuple[float, ...] = (10.0, 10.0, 10.0, 0.3, 0.3, 0.3)
    warmup_time_constant_s: float = 600.0
    max_rate_per_h: tuple[float, ...] = (200.0, 200.0, 200.0, 7.0, 7.0, 7.0)
    bias_walk_per_sqrt_h: tuple[float, ...] = (0.005, 0.005, 0.005, 0.0002, 0.0002, 0.0002)
    gate_chi2: float = 22.46
    reacquire_after_s: float = 2.0
    std_ratio: float = 1.5
    slope_sigmas: float = 6.0
    warn_sigmas: float = 6.0
    noise_fraction: float = 1.0
    warn_after_s: float = 1.0
    trust_noise_fraction: float = 1.0

    @property
    def q_bias(self) -> np.ndarray:
        """(6,) bias random-walk variance growth, units²/s."""
        return (np.asarray(self.bias_walk_per_sqrt_h) ** 2) / 3600.0

    @property
    def q_rate(self) -> np.ndarray:
        """(6,) base rate random-walk variance growth, (units/s)²/s."""
        return (np.asarray(self.rate_walk_per_h) / 3600.0) ** 2 / 3600.0

    @property
    def rate_prior(self) -> np.ndarray:
        """(6,) 1σ of the initial rate, units/s."""
        return np.asarray(self.rate_prior_per_h) / 3600.0

    @property
    def max_rate(self) -> np.ndarray:
        """(6,) the largest drift rate, units/s."""
        return np.asarray(self.max_rate_per_h) / 3600.0


@dataclass(frozen=True)
class Observation:
    """What the tracker did with one rest window.

    Attributes:
        window: the window. accepted: used to update the estimate. reason: "" or why not ("contact: Fz std …",
            "gate: …"). nis: normalised innovation squared (6 channels). innovation: (6,) window mean − prediction.
        judgement: the drift-or-step test run after this (refused) window, or None.
    """

    window: RestWindow
    accepted: bool
    reason: str
    nis: float
    innovation: np.ndarray
    judgement: Judgement | None = None

    @property
    def reacquired(self) -> bool:
        """True when refused windows ending with this one were found to be drift and the filter restarted."""
        return self.judgement is not None and self.judgement.drift


@dataclass(frozen=True)
class Step:
    """A step the drift-or-step test found: ``size`` (6,) against the tracked drift, seen from ``time_s``. While
    it stands, a window is used only if it is nearer the track than the track plus the step (the track's growing
    uncertainty never swallows the step)."""

    time_s: float
    size: np.ndarray
    reason: str


UNKNOWN_BIAS_SIGMA = {"force_bias": 0.01, "torque_bias": 0.0005}
"""1σ assumed for a calibration file that gives none for its biases, N and N·m (a typical identification's
order of magnitude; only the tracker's prior and the at-rest threshold use it)."""


def file_bias_sigma(calibration: Calibration) -> np.ndarray:
    """(6,) the file's 1σ of [force_bias, torque_bias], N and N·m (:data:`UNKNOWN_BIAS_SIGMA` where it gives none)."""
    out = []
    for key in ("force_bias", "torque_bias"):
        value = calibration.uncertainty.get(key)
        array = np.full(3, np.nan) if value is None else np.asarray(value, dtype=float).reshape(3)
        out.append(np.where(np.isfinite(array), array, UNKNOWN_BIAS_SIGMA[key]))
    return np.concatenate(out)


class DriftTracker:
    """Kalman filter on the biases' offset from the calibration file, its rate and the model error at the current
    orientation (module docstring, steps 2-5).

    Args:
        calibration: the calibration the residuals were compensated with.
        settings: :class:`DriftSettings`.
        age_s: time since the calibration's biases were last measured (calibration or tare), s.
    """

    def __init__(self, calibration: Calibration, settings: DriftSettings | None = None, age_s: float = 0.0) -> None:
        self.calibration = calibration
        self.settings = settings or DriftSettings()
        s = self.settings
        sigma_bias = file_bias_sigma(calibration)
        age = min(max(float(age_s), 0.0), MAX_PRIOR_AGE_S)
        self.x = np.zeros((6, 4))  # [b, ḃ, m, c] per channel (module docstring, step 3)
        self.P = np.zeros((6, 4, 4))
        self.P[:, 0, 0] = sigma_bias**2 + (s.rate_prior * age) ** 2 + s.q_bias * age
        self.P[:, 1, 1] = s.rate_prior**2
        self._common_set = False  # c's prior is set at the first window (the model 1σ there)
        self.time_s: float | None = None
        self.orientation: np.ndarray | None = None
        """The flange orientation of the last accepted window (where the model error m applies)."""
        self.accepted = 0
        self.rejected_contact = 0
        self.rejected_gate = 0
        self.reacquired = 0
        self.step: Step | None = None
        """The step standing against the track (None once windows agree with it again)."""
        self._refused: list[RestWindow] = []
        self._reference_std: list[np.ndarray] = []
        self._reference_median: np.ndarray | None = None  # of _reference_std: read every batch, changed per window
        self._model_cache: tuple[bytes, np.ndarray, np.ndarray] | None = None

    # ------------------------------------------------------------------ state

    def _propagate(self, x: np.ndarray, P: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        if dt <= 0:
            return x.copy(), P.copy()
        s = self.settings
        rate_sq = np.minimum(x[:, 1] ** 2 + P[:, 1, 1], s.max_rate**2)
        q_rate = s.q_rate + rate_sq / s.warmup_time_constant_s  # adaptive rate walk (module docstring, step 3)
        # F = I with F[0, 1] = dt (offset += dt · rate): x F^T and F P F^T + Q written out, per channel
        x_next = x.copy()
        x_next[:, 0] += dt * x[:, 1]
        P_next = P.copy()
        P_next[:, 0, :] += dt * P[:, 1, :]
        P_next[:, :, 0] += dt * P_next[:, :, 1]
        P_next[:, 0, 0] += s.q_bias * dt + q_rate * dt**3 / 3.0
        P_next[:, 0, 1] += q_rate * dt**2 / 2.0
        P_next[:, 1, 0] += q_rate * dt**2 / 2.0
        P_next[:, 1, 1] += q_rate * dt
        return x_next, P_next

    def _state_at(self, time_s: float | None) -> tuple[np.ndarray, np.ndarray]:
        if self.time_s is None or time_s is None:
            return self.x.copy(), self.P.copy()
        return self._propagate(self.x, self.P, time_s - self.time_s)

    def offset(self, time_s: float | None = None) -> np.ndarray:
        """Return the estimated bias offset (6,) from the calibration file at ``time_s`` (N, N·m)."""
        return self._state_at(time_s)[0][:, 0]

    def sigma(self, time_s: float | None = None) -> np.ndarray:
        """Return the 1σ (6,) of :meth:`offset` at ``time_s`` (the offset's variance of :meth:`_propagate`, the same
        operations on that entry only: the live monitor asks at every read)."""
        dt = 0.0 if self.time_s is None or time_s is None else time_s - self.time_s
        P = self.P
        if dt <= 0:
            return np.sqrt(P[:, 0, 0])
        s = self.settings
        q_rate = s.q_rate + np.minimum(self.x[:, 1] ** 2 + P[:, 1, 1], s.max_rate**2) / s.warmup_time_constant_s
        variance = P[:, 0, 0] + dt * P[:, 1, 0]
        variance += dt * (P[:, 0, 1] + dt * P[:, 1, 1])
        variance += s.q_bias * dt + q_rate * dt**3 / 3.0
        return np.sqrt(variance)

    def model_error(self, flange_R_base: np.ndarray | None) -> np.ndarray:
        """(6,) the estimated model error at ``flange_R_base``: the common part c, plus m where it is the last
        accepted window's orientation."""
        if self.accepted and same_orientation(flange_R_base, self.orientation):
            return self.x[:, 2] + self.x[:, 3]
        return self.x[:, 3].copy()

    @property
    def rate_per_h(self) -> np.ndarray:
        """(6,) estimated drift rate, N/h and N·m/h."""
        return self.x[:, 1] * 3600.0

    @property
    def reference_std(self) -> np.ndarray | None:
        """(6,) the sensor's per-sample noise (median std of recent accepted windows), or None before any."""
        if not self._reference_std:
            return None
        if self._reference_median is None:
            self._reference_median = np.median(np.array(self._reference_std), axis=0)
        return self._reference_median

    def model_variance(self, flange_R_base: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """The calibration's model variance at this orientation (biases excluded), (6,) each: the parameters'
        part (common to every orientation: the prior of c) and the per-pose part (the prior of m)."""
        if flange_R_base is None:
            return np.zeros(6), np.zeros(6)
        key = np.round(np.asarray(flange_R_base, dtype=float), 4).tobytes()
        if self._model_cache is None or self._model_cache[0] != key:
            self._model_cache = (key, *compensation_variance_parts(self.calibration, flange_R_base,
                                                                   include_biases=False))
        return self._model_cache[1], self._model_cache[2]

    def model_sigma(self, flange_R_base: np.ndarray | None) -> np.ndarray:
        """(6,) the calibration's model 1σ at this orientation (biases excluded), N and N·m."""
        common, own = self.model_variance(flange_R_base)
        return np.sqrt(common + own)

    # ------------------------------------------------------------------ update

    def start(self, time_s: float) -> None:
        """Date the prior (the biases as the file has them, the rate prior) at the stream's first sample ``time_s``:
        the drift before the first rest window is then allowed for. No effect once a time is set."""
        if self.time_s is None:
            self.time_s = float(time_s)

    def contact_reason(self, window: RestWindow, rate: np.ndarray | None = None) -> str:
        """Return why the window looks like contact ('' if it does not): std, or an in-window slope off the
        tracked drift ``rate`` (6,) per s."""
        s = self.settings
        reference = self.reference_std
        if reference is not None:
            ratio = window.std / np.maximum(reference, 1e-300)
            worst = int(np.argmax(ratio))
            if ratio[worst] > s.std_ratio:
                return f"contact: {AXES[worst]} std {ratio[worst]:.1f}× the sensor noise"
        if window.slope is not None and window.slope_se is not None and rate is not None:
            slope = np.abs(window.slope - rate) / np.maximum(window.slope_se, 1e-300)
        else:
            slope = np.abs(window.slope_t)
        worst = int(np.argmax(slope))
        if slope[worst] > s.slope_sigmas:
            return f"contact: {AXES[worst]} changing within the window ({slope[worst]:.0f}σ)"
        return ""

    def _with_orientation(self, x: np.ndarray, P: np.ndarray, window: RestWindow) -> tuple[np.ndarray, np.ndarray]:
        """The state with a fresh model error m (0 ± its share of the model 1σ) when the window is at another
        orientation; the common part c gets its prior at the first window."""
        if self.accepted and same_orientation(window.flange_R_base, self.orientation):
            return x, P
        x, P = x.copy(), P.copy()
        common, own = self.model_variance(window.flange_R_base)
        if not self._common_set:
            P[:, 3, 3] = common
        x[:, 2] = 0.0
        P[:, 2, :] = 0.0
        P[:, :, 2] = 0.0
        P[:, 2, 2] = own
        return x, P

    def observe(self, window: RestWindow) -> Observation:
        """Gate a rest window and, if clean, update the estimate with it (module docstring, steps 2-5)."""
        dt = 0.0 if self.time_s is None else window.mid_s - self.time_s
        x, P = self._with_orientation(*self._propagate(self.x, self.P, dt), window)
        HP = P[:, 0, :] + P[:, 2, :] + P[:, 3, :]  # H = [1, 0, 1, 1]: z = b + m + c + v
        S = HP[:, 0] + HP[:, 2] + HP[:, 3] + window.noise_variance + 1e-30
        innovation = window.mean - x[:, 0] - x[:, 2] - x[:, 3]
        nis = float(np.sum(innovation**2 / S))
        reason = self.contact_reason(window, x[:, 1] if self.accepted else None)
        if not reason and nis > self.settings.gate_chi2:
            worst = int(np.argmax(innovation**2 / S))
            unit = "N" if worst < 3 else "N·m"
            reason = (f"gate: {AXES[worst]} off by {innovation[worst]:+.4g} {unit} "
                      f"({math.sqrt(innovation[worst] ** 2 / S[worst]):.0f}σ), not drift")
        if not reason and self.step is not None and \
                nis >= float(np.sum((innovation - self.step.size) ** 2 / S)):
            reason = "gate: nearer the level after the step than the track: the step stands"
        if reason.startswith("contact"):
            self.rejected_contact += 1
            return Observation(window, False, reason, nis, innovation)
        if reason:
            self.rejected_gate += 1
            judgement = self._judge_refused(window)
            return Observation(window, False, reason, nis, innovation, judgement)
        gain = HP / S[:, None]  # (6, 4)
        self.x = x + gain * innovation[:, None]
        self.P = P - gain[:, :, None] * HP[:, None, :]
        self.P = 0.5 * (self.P + self.P.transpose(0, 2, 1))
        self._accept(window)
        return Observation(window, True, "", nis, innovation)

    def _accept(self, window: RestWindow) -> None:
        self.time_s = window.mid_s
        self.orientation = window.flange_R_base
        self._common_set = True
        self.accepted += 1
        self.step = None
        self._refused.clear()
        self._reference_std.append(window.std)
        del self._reference_std[:-REFERENCE_NOISE_WINDOWS]
        self._reference_median = None

    def _judge_refused(self, window: RestWindow) -> Judgement | None:
        """Keep the refused window; when those at its orientation (consecutive) span ``reacquire_after_s``, test
        drift or step (module docstring, step 5): re-acquire on drift, record the step otherwise."""
        s = self.settings
        if self.step is not None:
            return None  # a step stands: only windows nearer the track than the step clear it
        if self._refused and not (same_orientation(window.flange_R_base, self._refused[-1].flange_R_base)
                                  and window.start_s - self._refused[-1].end_s <= 2.0 * s.window_s):
            self._refused.clear()  # another still period: the test starts again with it
        self._refused.append(window)
        del self._refused[:-REACQUIRE_WINDOWS]
        if self.time_s is None or len(self._refused) < 3 or \
                self._refused[-1].mid_s - self._refused[0].mid_s < s.reacquire_after_s - 1e-9:
            return None
        gap = self._refused[-1].mid_s - self.time_s
        # the track's level where the windows are: b + c, plus m at the same orientation (else a fresh m's prior)
        same = self.accepted > 0 and same_orientation(window.flange_R_base, self.orientation)
        h = np.array([1.0, 0.0, 1.0 if same else 0.0, 1.0])
        g = np.array([0.0, 1.0, 0.0, 0.0])
        track_x = np.stack([self.x @ h, self.x[:, 1]], axis=1)
        track_P = np.empty((6, 2, 2))
        track_P[:, 0, 0] = np.einsum("i,cij,j->c", h, self.P, h)
        track_P[:, 0, 1] = track_P[:, 1, 0] = np.einsum("i,cij,j->c", h, self.P, g)
        track_P[:, 1, 1] = self.P[:, 1, 1]
        fresh_m = 0.0 if same else self.model_variance(window.flange_R_base)[1]
        judgement = judge([w.mid_s for w in self._refused], np.array([w.mean for w in self._refused]),
                          np.array([w.noise_variance for w in self._refused]), self.time_s, track_x, track_P,
                          np.sqrt(fresh_m), s.q_bias * gap + s.q_rate * gap**3 / 3.0, s.gate_chi2, s.max_rate)
        if judgement.drift:
            self._restart_from(judgement, window)
        else:
            self.step = Step(self._refused[0].start_s, judgement.step, judgement.reason)
        return judgement

    def _restart_from(self, judgement: Judgement, window: RestWindow) -> None:
        """Restart the filter from the line through the refused windows (drift faster than tracked)."""
        level, covariance = judgement.line.at(window.mid_s)  # of b + m + c: split by the model's prior
        common, own = self.model_variance(window.flange_R_base)
        model = common + own
        self.x = np.zeros((6, 4))
        self.x[:, 0] = level
        self.x[:, 1] = judgement.line.rate
        self.P = np.zeros((6, 4, 4))
        self.P[:, :2, :2] = covariance
        self.P[:, 0, 0] += model  # the line's level is b + m + c: b alone is known to the model 1σ
        self.P[:, 0, 2] = self.P[:, 2, 0] = -own
        self.P[:, 0, 3] = self.P[:, 3, 0] = -common
        self.P[:, 2, 2] = own
        self.P[:, 3, 3] = common
        self.reacquired += 1
        self._accept(window)


__all__ = ["DriftSettings", "DriftTracker", "Observation", "Step", "file_bias_sigma", "MAX_PRIOR_AGE_S"]
