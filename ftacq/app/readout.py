"""The live readout of ``ftacq monitor``: one line on stderr about twice a second, and the run's last line.

A :data:`procedures.events.Listener`: it sums the samples of :class:`~procedures.events.WrenchSamples` events and
prints at every :class:`~procedures.events.SensorStatus` (the monitor publishes one every 0.5 s of sensor
time). Rates are samples divided by the span of their receive times (host monotonic clock), the same clock as
:meth:`format_summary`, so the live and final figures agree. On a terminal the line is rewritten in place;
otherwise one line per update.
"""

from __future__ import annotations

import sys
from typing import TextIO

import numpy as np

from procedures import events


class LiveReadout:
    """Prints ``rate, |F| and |T| (mean over the last update's samples; compensated when known), lost`` and, for a
    sensor with its own clock, how well the samples' times are known."""

    def __init__(self, stream: TextIO | None = None, is_terminal: bool | None = None) -> None:
        self.stream = stream or sys.stderr
        self.in_place = self.stream.isatty() if is_terminal is None else is_terminal
        self.lines: list[str] = []
        self._count = 0
        self._sum = np.zeros(6)
        self._compensated = True
        self._last_time_s: float | None = None
        self._width = 0

    def __call__(self, event: events.Event) -> None:
        if isinstance(event, events.WrenchSamples):
            wrench = event.compensated if event.compensated is not None else event.batch.wrench
            self._compensated = self._compensated and event.compensated is not None
            self._sum += wrench.sum(axis=0)
            self._count += len(event)
        elif isinstance(event, events.SensorStatus):
            self._print(event)
        elif isinstance(event, events.Notice) and event.source == "health":
            self.notice(f"{event.level.lower()}: {event.text}" if event.level != "INFO" else event.text)

    def notice(self, text: str) -> None:
        """Print a health line on its own (ending the in-place readout line first)."""
        if self.in_place and self._width:
            self.stream.write("\n")
            self._width = 0
        self.stream.write(f"ftacq monitor: {text}\n")
        self.stream.flush()

    def _print(self, status: events.SensorStatus) -> None:
        if self._last_time_s is None:  # the first status starts the first window
            self._last_time_s, self._count, self._sum = status.time_s, 0, np.zeros(6)
            return
        span_s = status.time_s - self._last_time_s
        if span_s <= 0 or self._count == 0:
            return
        mean = self._sum / self._count
        kind = "compensated" if self._compensated else "raw"
        line = (f"{self._count / span_s:6.0f} Hz  |F| {np.linalg.norm(mean[:3]):7.2f} N  "
                f"|T| {np.linalg.norm(mean[3:]):6.3f} N·m ({kind})  lost {status.health.lost}"
                + (f"  dropped for the viewer {status.dropped}" if status.dropped else "")
                + (f"  sample times ±{1e3 * status.clock_uncertainty_s:.2f} ms"
                   if status.clock_uncertainty_s < float("inf") else ""))
        self.lines.append(line)
        if self.in_place:
            self.stream.write("\r" + line.ljust(self._width))
            self._width = len(line)
        else:
            self.stream.write(line + "\n")
        self.stream.flush()
        self._last_time_s, self._count, self._sum, self._compensated = status.time_s, 0, np.zeros(6), True

    def close(self) -> None:
        """End the in-place line (safe twice)."""
        if self.in_place and self._width:
            self.stream.write("\n")
            self.stream.flush()
            self._width = 0


def format_summary(summary) -> str:
    """Return the run's last line from a :class:`procedures.monitor.MonitorSummary`: samples / seconds = rate,
    all three on the samples' receive clock."""
    text = (f"ftacq monitor: {summary.samples} samples received over {summary.span_s:.4f} s "
            f"(first to last sample, host monotonic clock) = {summary.rate_hz:.0f} Hz; {summary.lost} lost "
            f"({getattr(summary, 'socket_drops', 0)} dropped at this host's socket, "
            f"{getattr(summary, 'ring_overflows', 0)} by the reader falling behind), "
            f"{summary.timeouts} read timeouts, {summary.dropped_samples} dropped for the viewer")
    if summary.listener_error:
        text += f", dashboard failed: {summary.listener_error}"
    if summary.warnings:
        text += f", {len(summary.warnings)} warnings"
    uncertainty = getattr(summary, "clock_uncertainty_s", float("inf"))
    if uncertainty < float("inf"):
        text += (f"; sensor clock {1e6 * summary.clock_rate_error:+.1f} ppm from the host's, sample times known to "
                 f"{1e3 * uncertainty:.3f} ms")
    if summary.record_path:
        text += f"; recorded {summary.record_path}"
    if summary.interrupted:
        text += "; stopped by Ctrl-C"
    return text


__all__ = ["LiveReadout", "format_summary"]
