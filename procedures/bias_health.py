"""Live calibration health for a compensated stream: stillness from the robot, the drift tracker, --auto-tare.

:class:`DriftCompensator` compensates each batch with the calibration as on file, hands the residual to a
:class:`ftacq.drift_health.BiasHealth` together with the arm's stillness (:class:`StillDetector`) and orientation, and
returns the residual minus the tracker's correction when ``auto_tare`` is on (unchanged otherwise). The notices
it causes (an at-rest warning, its clearing) and a periodic :class:`procedures.events.BiasDrift` snapshot (for the dashboard's bias
drift plot and the console) are collected by :class:`DriftCheck`, the monitor's health check. Both run in the
acquisition thread: a few numpy operations per batch, a Kalman update per 0.5 s rest window; the tracker learns from
the batches in the check, after the read is published (the update delays no message), every 10 ms of samples.

Stillness: the arm is still when every joint stayed within ``tolerance_rad`` over ``window_s`` before the batch's
samples and while they were taken, from the RTDE state stream at the samples' time (``moving.still_over``: a
monitor reading 0.3 s late would otherwise put samples of the arm still moving into a rest window); without a
live compensator, over the last ``window_s`` of the robot states read with the batches. Saturated samples are
never used.
"""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ftacq.drift_health import BiasHealth, HealthNotice
from ftacq.so3 import rotation_of_rotvec
from procedures.events import BiasDrift, Notice

if TYPE_CHECKING:
    from procedures.monitor import Compensator

STILL_TOLERANCE_RAD = 2e-4
"""Largest joint excursion (rad, about 0.01°) over the still window that still counts as still (encoder jitter)."""
STILL_WINDOW_S = 0.25
"""Joint angles must stay within STILL_TOLERANCE_RAD for this long, s."""
DRIFT_EVENT_PERIOD_S = 1.0
"""A BiasDrift snapshot is published at most this often, s (sample clock)."""
TRACK_PERIOD_S = 0.01
"""The drift tracker learns from the compensated samples in batches spanning at least this much sample time, s (the
monitor's read period without --ros2; with it the monitor reads every burst, ~2 ms, and a feed's fixed cost, ~60 µs,
was a tenth of a read). Rest windows last 0.5 s: the tracker's updates come this much later at most."""


class StillDetector:
    """Decides from the joint angles whether the arm is still (module docstring)."""

    def __init__(self, tolerance_rad: float = STILL_TOLERANCE_RAD, window_s: float = STILL_WINDOW_S) -> None:
        self.tolerance_rad = float(tolerance_rad)
        self.window_s = float(window_s)
        self._history: collections.deque = collections.deque()

    def update(self, time_s: float, joint_positions_rad: np.ndarray | None) -> bool:
        """Add the joint angles read at ``time_s`` (s); return True when the arm has been still for ``window_s``."""
        if joint_positions_rad is None:
            self._history.clear()
            return False
        q = np.asarray(joint_positions_rad, dtype=float)
        self._history.append((float(time_s), q))
        while len(self._history) > 2 and self._history[1][0] <= time_s - self.window_s:
            self._history.popleft()
        if self._history[0][0] > time_s - self.window_s:
            return False  # not enough history yet
        angles = np.array([item[1] for item in self._history])
        return bool(np.all(angles.max(axis=0) - angles.min(axis=0) <= self.tolerance_rad))


@dataclass
class DriftCompensator:
    """Compensation with the calibration on file, feeding the drift tracker (the monitor's Compensator seam).

    Args:
        health: the :class:`ftacq.drift_health.BiasHealth` (its calibration is the one compensated with; its
            ``auto_tare`` decides whether the correction is subtracted).
        still: the :class:`StillDetector`.
        moving: the live compensator: :class:`procedures.dynamic_compensation.DynamicCompensator` when the
            calibration has inertia, :class:`procedures.static_compensation.StaticCompensator` (the static model
            with the pose at the samples' time) otherwise; a batch it leaves uncompensated (None) is neither
            returned nor fed to the tracker. None: the static model with the robot's newest pose (an arm known to
            be still; tests). The tracker learns only from rest windows, where both models agree; the correction
            applies to either, at the orientation of the batch's newest sample when ``moving`` says it.
    """

    health: BiasHealth
    still: StillDetector = field(default_factory=StillDetector)
    notices: list[HealthNotice] = field(default_factory=list)
    moving: Compensator | None = None
    bias_offset: np.ndarray = field(default_factory=lambda: np.zeros(6))
    """(6,) the biases' change since the calibration compensated with (live tares: :meth:`rebase`), N and N·m."""
    still_now: bool = False
    """Whether the arm was still while the last batch's samples were taken (the tracker's rule)."""
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)
    """Held while a batch is compensated and the tracker updated: another thread reading the tracker takes it."""

    def __post_init__(self) -> None:
        self._base = self.health.tracker.calibration  # what ``moving`` (or, without it, this) compensates with
        self._rotation_of: tuple[bytes, np.ndarray] = (b"", np.eye(3))  # (rotation vector's bytes, flange_R_base)
        self._pending: list[tuple] = []  # the arguments of BiasHealth.feed of the batches not yet learnt from

    @property
    def calibration(self):
        """The calibration in force: the one compensated with, its biases as the last live tare left them."""
        return self.health.tracker.calibration

    def rebase(self, calibration) -> None:
        """Use ``calibration``'s biases from now on (a live tare: the rest of the model is unchanged): they are
        constants of both models, so subtracting their change from the residual is the same compensation. The drift
        tracker restarts from them (just measured: age 0); ``auto_tare`` is kept."""
        with self.lock:
            self._track(force=True)  # the batches compensated before the tare are the old biases' residuals
            self.bias_offset = (np.concatenate([calibration.force_bias, calibration.torque_bias])
                                - np.concatenate([self._base.force_bias, self._base.torque_bias]))
            self.health = BiasHealth(calibration, self.health.settings, age_s=0.0, auto_tare=self.health.auto_tare)

    def compensate(self, batch, robot) -> np.ndarray | None:
        """Return the contact wrench (N, 6) of ``batch`` given the robot's latest state (None without one). The
        tracker learns from it at :meth:`track` (the monitor's :class:`DriftCheck`, once the read is published: a
        rest window's update, ~1-2 ms, then delays no message), or here, before a later batch, once the batches
        waiting span :data:`TRACK_PERIOD_S`; the correction applied is the tracker's up to then."""
        with self.lock:
            self._track()
            return self._compensate(batch, robot)

    def track(self, force: bool = False) -> None:
        """Feed the drift tracker the batches compensated since it last learnt, once they span
        :data:`TRACK_PERIOD_S` (``force``: whatever they span); their notices join :attr:`notices`."""
        with self.lock:
            self._track(force)

    def _track(self, force: bool = False) -> None:
        pending = self._pending
        if not pending or (not force and pending[-1][0][-1] - pending[0][0][0] < TRACK_PERIOD_S):
            return
        self._pending = []
        start = 0
        for end in range(1, len(pending) + 1):  # one feed per run of batches alike still (or not)
            if end < len(pending) and pending[end][2] == pending[start][2]:
                continue
            run = pending[start:end]
            feed = run[0] if len(run) == 1 else (np.concatenate([item[0] for item in run]),
                                                  np.concatenate([item[1] for item in run]), run[0][2], run[-1][3])
            self.notices += self.health.feed(*feed)
            start = end

    def _compensate(self, batch, robot) -> np.ndarray | None:
        self.still_now = False
        if robot is None:
            return None
        flange_R_base = self._flange_R_base(robot.flange_pose)
        if self.moving is not None:
            residual = self.moving.compensate(batch, robot)
            if residual is None:
                return None
            at_samples = getattr(self.moving, "flange_R_base", None)  # the static one's, at the samples' time
            if at_samples is not None and len(at_samples) == len(residual):
                flange_R_base = at_samples[-1].copy()  # (kept until the tracker learns)
        else:
            residual = self._base.compensate(batch.wrench, flange_R_base)
        if np.count_nonzero(self.bias_offset):  # (.any(): numpy's reduction machinery, ~4x the cost)
            residual -= self.bias_offset
        time_s = np.asarray(batch.time_s, dtype=float)
        still_over = getattr(self.moving, "still_over", None)
        if still_over is not None:  # still while the samples were taken (the states of their time)
            still = still_over(self.still.window_s, self.still.tolerance_rad)
        else:  # the newest joint angles read with the batches (an arm known to be still; tests)
            still = self.still.update(float(time_s[-1]), getattr(robot, "joint_positions_rad", None))
        self.still_now = bool(still)
        saturated = np.asarray(batch.saturated, dtype=bool)
        if not np.count_nonzero(saturated):  # (copies: the caller owns residual; the correction comes off it in place)
            if time_s.size:
                self._pending.append((time_s.copy(), residual.copy(), bool(still), flange_R_base))
        elif still:  # a saturated sample breaks the rest window
            self._pending.append((time_s[:1].copy(), residual[:1].copy(), False, None))
        elif np.count_nonzero(saturated) < saturated.size:
            good = ~saturated
            self._pending.append((time_s[good], residual[good], bool(still), flange_R_base))
        if self.health.auto_tare:  # the tracked offset while trusted, nothing once it is not (BiasHealth.correction)
            residual -= self.health.correction(float(time_s[-1]), flange_R_base)
        return residual

    def _flange_R_base(self, flange_pose) -> np.ndarray:
        """flange_R_base (3, 3) of a UR pose (the robot's newest), kept while the pose stays the same (an arm at
        rest: the same state read batch after batch)."""
        rotvec = np.asarray(flange_pose, dtype=float)[3:6]
        key = rotvec.tobytes()
        if self._rotation_of[0] != key:
            rotation = rotation_of_rotvec(rotvec).T
            rotation.flags.writeable = False  # shared by the reads that follow
            self._rotation_of = (key, rotation)
        return self._rotation_of[1]

    def sample_flange_pose(self) -> np.ndarray | None:
        """The flange pose (N, 6) at each sample's time of the last batch, as ``moving`` says it (None when it
        does not: no ``moving``, or no robot state near the samples)."""
        pose = getattr(self.moving, "sample_flange_pose", None)
        return pose() if pose is not None else None

    def snapshot(self, time_s: float) -> BiasDrift:
        """Return the tracker's estimate now."""
        tracker = self.health.tracker
        return BiasDrift(time_s=time_s, offset=tracker.offset(time_s), sigma=tracker.sigma(time_s),
                         rate_per_h=tracker.rate_per_h, applied=self.health.applied, accepted=tracker.accepted,
                         rejected_contact=tracker.rejected_contact, rejected_gate=tracker.rejected_gate,
                         warning=self.health.check.warning)


class DriftCheck:
    """The monitor's health check for the drift tracker: the compensator's notices (as
    :class:`procedures.events.Notice`, source "health"), and a :class:`procedures.events.BiasDrift` snapshot every
    ``period_s`` of sample time."""

    def __init__(self, compensator: DriftCompensator, period_s: float = DRIFT_EVENT_PERIOD_S) -> None:
        self.compensator = compensator
        self.period_s = float(period_s)
        self._last_s = -np.inf

    def check(self, samples) -> list:
        """Return the notices caused since the last call, plus a BiasDrift snapshot when one is due (the tracker
        first learns from the reads' samples: :meth:`DriftCompensator.track`, every TRACK_PERIOD_S)."""
        self.compensator.track()
        out: list = [Notice(n.text, level=n.level, source="health", time_s=n.time_s)
                     for n in self.compensator.notices]
        self.compensator.notices.clear()
        now_s = float(samples.batch.time_s[-1])
        if now_s - self._last_s >= self.period_s and self.compensator.health.observations:
            self.compensator.track(force=True)
            out.append(self.compensator.snapshot(now_s))
            self._last_s = now_s
        return out


__all__ = ["StillDetector", "DriftCompensator", "DriftCheck", "STILL_TOLERANCE_RAD", "STILL_WINDOW_S", "TRACK_PERIOD_S"]
