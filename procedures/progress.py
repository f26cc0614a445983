"""A procedure listener that shows progress on stderr: pose i/N, state, ETA (rich on a terminal, lines otherwise)."""

from __future__ import annotations

import sys
import time
from typing import Callable, TextIO

from procedures import events


class ProgressListener:
    """Show the run's progress. ``total`` is the number of poses the whole run measures (the plan and the
    drift-check revisit), ``done`` how many of them were measured before (a resumed run); the procedure's
    :class:`events.StateChanged` counts, when given, override both. The counts are those of the stop message:
    "pose 24/61 (E15)" is the 24th measurement of 61, while 23 are done.

    On a terminal a rich progress bar (state, pose label, pose k/N, measured/total, elapsed, ETA); otherwise one
    line per measured pose, so CI logs stay readable. The ETA is the mean time per pose measured in this session
    times the poses left (before the first pose: the plan's estimate for the poses left). Call :meth:`close`
    when the run ends.

    A recorded motion (:mod:`procedures.motion_runner`: ``motion`` names it, "excitation") counts waypoints
    reached instead of poses measured, and without a terminal prints one line per move.
    """

    def __init__(self, total: int, estimated_s: float, stream: TextIO | None = None,
                 clock_s: Callable[[], float] = time.monotonic, force_terminal: bool | None = None,
                 done: int = 0, motion: str = "") -> None:
        from rich.console import Console

        self.total = max(int(total), 1)
        self.done = int(done)
        self._done_at_start = self.done
        self._estimated_s = float(estimated_s)
        self._clock_s = clock_s
        self._start = clock_s()
        self._state = "starting"
        self._label = ""
        self._motion = motion
        self._stream = stream or sys.stderr
        self.console = Console(file=self._stream, force_terminal=force_terminal, stderr=stream is None)
        self._progress = None
        self._task = None
        if self.console.is_terminal:
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn)

            self._progress = Progress(TextColumn("[bold]{task.description:<34}"), BarColumn(),
                                      MofNCompleteColumn(), TextColumn("measured"), TimeElapsedColumn(),
                                      TextColumn("ETA {task.fields[eta]}"), console=self.console, transient=False)
            self._task = self._progress.add_task("starting", total=self.total, completed=self.done,
                                                 eta=self._format(estimated_s))
            self._progress.start()

    @staticmethod
    def _format(seconds: float) -> str:
        seconds = max(0.0, seconds)
        return f"{int(seconds // 60)}:{int(seconds % 60):02d}"

    def eta_s(self) -> float:
        """Return the estimated time left, s."""
        measured_here = self.done - self._done_at_start
        if measured_here <= 0:
            return self._estimated_s
        per_pose = (self._clock_s() - self._start) / measured_here
        return per_pose * (self.total - self.done)

    def _where(self) -> str:
        return f"{self._state} {self._label}".strip() + (
            f" ({'waypoint' if self._motion else 'pose'} {min(self.done + 1, self.total)}/{self.total})"
            if self._label else "")

    def __call__(self, event) -> None:
        if isinstance(event, (events.WrenchSamples, events.RobotState, events.SensorStatus)):
            return  # the sample stream (up to the sensor's read rate): nothing to show here
        if isinstance(event, events.StateChanged):
            self._state = event.state
            if event.total is not None:
                self.total = max(int(event.total), 1)
            if event.measured is not None:
                if self.done == self._done_at_start and not self._motion:  # nothing measured here yet: the procedure knows best
                    self._done_at_start = int(event.measured)
                self.done = int(event.measured)
            if event.index is not None:
                self._label = event.label or self._label
            else:
                self._label = ""
            if self._motion and event.state == "moving" and event.index is not None and self._progress is None:
                self.console.print(f"{self._motion}: waypoint {event.index + 1}/{self.total} {event.label}, ETA "
                                   f"{self._format(self.eta_s())}", highlight=False, soft_wrap=True)
            if event.state in ("done", "stopped", "failed"):
                self.close()
                return
        elif isinstance(event, events.PoseMeasured):
            self.done += 1
            self._label = event.label
            if self._progress is None:
                self.console.print(f"pose {self.done}/{self.total} {event.label} ({event.set_name}) measured: "
                                   f"{event.count} samples, ETA {self._format(self.eta_s())}",
                                   highlight=False, soft_wrap=True)
        elif isinstance(event, events.DriftChecked) and event.warning:
            self.console.print(f"warning: {event.warning}", style="yellow", highlight=False)
        if self._progress is not None and self._task is not None:
            self._progress.update(self._task, completed=self.done, total=self.total, description=self._where(),
                                  eta=self._format(self.eta_s()))

    def close(self) -> None:
        """Stop the live display (safe twice)."""
        if self._progress is not None:
            self._progress.stop()
            self._progress = None


__all__ = ["ProgressListener"]
