"""Tare while streaming: re-estimate the biases from the live stream, keep the rest of the calibration.

What ``ftacq tare`` does at the current pose (:func:`procedures.tare.tare_here`), done from the monitor's own
reads instead of a second reader of the sensor: :class:`LiveTare` is a :class:`procedures.monitor.HealthCheck`
(it sees every read in the acquisition thread). A request (:meth:`LiveTare.request`, from any thread) averages the
raw wrench over the next ``average_s`` of samples taken with the arm still (the drift tracker's stillness rule,
:mod:`procedures.bias_health`; motion, a saturated sample or a read left uncompensated starts the window again),
estimates the biases at that pose with the calibration's rotation, weight and centre of mass kept
(:func:`procedures.tare.estimate_from_poses`: paper eqs 10-13, docs/drift-and-tare.md), and re-bases the
compensation on them (:meth:`procedures.bias_health.DriftCompensator.rebase`). The reads after the one that
completed the window are compensated with the new biases. A hand on the tool is measured as bias: tare with the
tool untouched.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ftacq.bias_estimate import apply_estimate, format_bias_change
from ftacq.errors import FtacqError
from procedures import events
from procedures.bias_health import DriftCompensator
from procedures.tare import TareResult, estimate_from_poses

TARE_TIMEOUT_S = 10.0
"""Longest a live tare waits for ``average_s`` of samples with the arm still, s."""


class TareError(FtacqError):
    """A live tare that could not be made (the arm never still long enough, the stream stopped)."""


@dataclass
class TareRequest:
    """One tare asked for: wait on :meth:`wait`; ``result`` (a :class:`procedures.tare.TareResult`; the calibration
    now in force is the compensator's) or ``error`` once ``done`` is set."""

    average_s: float
    deadline_s: float
    done: threading.Event = field(default_factory=threading.Event)
    result: TareResult | None = None
    error: BaseException | None = None

    def wait(self, timeout_s: float | None = None) -> TareResult:
        """Return the result once done; raise the tare's error, or :class:`TareError` after ``timeout_s``."""
        if not self.done.wait(timeout_s):
            raise TareError(f"the tare did not finish within {timeout_s:g} s")
        if self.error is not None:
            raise self.error
        assert self.result is not None
        return self.result


class LiveTare:
    """The monitor's tare check over a :class:`~procedures.bias_health.DriftCompensator` (module docstring)."""

    def __init__(self, compensator: DriftCompensator) -> None:
        self.compensator = compensator
        self.tares = 0
        self._lock = threading.Lock()
        self._pending: list[TareRequest] = []
        self._parts: list[np.ndarray] = []
        self._start_s: float | None = None
        self._pose = np.zeros(6)
        self._serving: TareRequest | None = None

    def request(self, average_s: float, timeout_s: float = TARE_TIMEOUT_S) -> TareRequest:
        """Ask for a tare averaging ``average_s`` of still samples (any thread); it fails after ``timeout_s``."""
        if not average_s > 0:
            raise ValueError(f"average_s {average_s!r}: must be > 0")
        request = TareRequest(float(average_s), time.monotonic() + float(timeout_s))
        with self._lock:
            self._pending.append(request)
        return request

    def cancel(self, why: str) -> None:
        """Fail every pending request with ``why`` (the stream stopped)."""
        with self._lock:
            pending, self._pending = self._pending, []
        for request in pending:
            request.error = TareError(why)
            request.done.set()

    def expire(self) -> None:
        """Fail the requests past their deadline (also when no read comes: a silent sensor)."""
        now_s = time.monotonic()
        with self._lock:
            expired = [request for request in self._pending if now_s > request.deadline_s]
        for request in expired:
            self._finish(request, error=TareError(
                f"the arm was not still (and the stream compensated) for {request.average_s:g} s within the tare's "
                "time: keep the arm still and tare again"))

    def check(self, samples: events.WrenchSamples) -> list[events.StreamEvent]:
        """Add a read to the open window; complete the oldest request when the window is full."""
        self.expire()
        with self._lock:
            request = self._pending[0] if self._pending else None
        if request is not self._serving:  # a new request (or none): its window starts empty
            self._restart()
            self._serving = request
        if request is None:
            return []
        batch = samples.batch
        pose = samples.sample_flange_pose
        if pose is None:
            pose = self.compensator.sample_flange_pose()
        if (samples.compensated is None or not self.compensator.still_now or pose is None
                or np.asarray(batch.saturated).any()):
            self._restart()
            return []
        if self._start_s is None:
            self._start_s = float(batch.time_s[0])
        self._parts.append(np.asarray(batch.wrench, dtype=float))
        self._pose = np.asarray(pose, dtype=float)[-1]
        if float(batch.time_s[-1]) - self._start_s < request.average_s:
            return []
        wrench = np.concatenate(self._parts)
        self._restart()
        calibration = self.compensator.calibration
        try:
            result = estimate_from_poses(calibration, self._pose[None], wrench.mean(axis=0)[None],
                                         wrench.std(axis=0, ddof=1)[None], np.array([len(wrench)]), ("live",))
            tared = apply_estimate(calibration, result.estimate)
        except Exception as error:  # noqa: BLE001 - handed to the caller of request()
            self._finish(request, error=error)
            return []
        self.compensator.rebase(tared)
        self.tares += 1
        self._finish(request, result=result)
        change = result.estimate.change
        return [events.Notice(f"tared at the current pose ({len(wrench)} samples): biases changed by "
                              + format_bias_change(change),
                              source="tare", time_s=float(batch.time_s[-1]))]

    def _restart(self) -> None:
        self._parts = []
        self._start_s = None

    def _finish(self, request: TareRequest, result: TareResult | None = None,
                error: BaseException | None = None) -> None:
        """Hand the request its outcome (once: a request another thread already finished is left as it is)."""
        with self._lock:
            if request not in self._pending:
                return
            self._pending.remove(request)
            request.result, request.error = result, error
        request.done.set()


__all__ = ["LiveTare", "TareRequest", "TareError", "TARE_TIMEOUT_S"]
